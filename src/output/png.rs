//! PNG encoding tuned for flat-coloured synthetic frames: fdeflate's fast
//! mode, with the Paeth filter for RGB frames (same cost whatever the weather)
//! and adaptive filtering for masks. See docs/performance.md ("PNG settings") for the
//! comparison that led here.

use std::io::Write;

/// Pixel layout of an image to encode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    Rgb8,
    Gray8,
    /// 16-bit grey, big-endian bytes (as PNG stores them).
    Gray16,
}

/// Encoder settings, exposed so the benchmark can compare them.
#[derive(Debug, Clone, Copy)]
pub struct PngSettings {
    pub compression: png::DeflateCompression,
    pub filter: png::Filter,
}

impl PngSettings {
    /// RGB frames: Paeth costs the same on clear and rainy frames, within 2 %
    /// of adaptive filtering's size.
    pub fn rgb() -> PngSettings {
        PngSettings { compression: png::DeflateCompression::FdeflateUltraFast, filter: png::Filter::Paeth }
    }

    /// Masks: mostly zero rows, where adaptive filtering is both smallest and fastest.
    pub fn mask() -> PngSettings {
        PngSettings { compression: png::DeflateCompression::FdeflateUltraFast, filter: png::Filter::Adaptive }
    }

    /// The settings for a pixel format.
    pub fn for_format(format: PixelFormat) -> PngSettings {
        match format {
            PixelFormat::Rgb8 => PngSettings::rgb(),
            PixelFormat::Gray8 | PixelFormat::Gray16 => PngSettings::mask(),
        }
    }
}

/// Encodes `data` (row-major) as a PNG into `out`.
pub fn encode_png<W: Write>(
    out: W,
    width: u32,
    height: u32,
    format: PixelFormat,
    data: &[u8],
    settings: PngSettings,
) -> Result<(), png::EncodingError> {
    let mut encoder = png::Encoder::new(out, width, height);
    encoder.set_color(match format {
        PixelFormat::Rgb8 => png::ColorType::Rgb,
        PixelFormat::Gray8 | PixelFormat::Gray16 => png::ColorType::Grayscale,
    });
    encoder.set_depth(if format == PixelFormat::Gray16 { png::BitDepth::Sixteen } else { png::BitDepth::Eight });
    encoder.set_deflate_compression(settings.compression);
    encoder.set_filter(settings.filter);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(data)?;
    writer.finish()
}

/// Decodes an 8-bit greyscale PNG (an instance mask) of the expected size.
pub fn decode_gray8(data: &[u8], width: u32, height: u32) -> Result<Vec<u8>, String> {
    decode_8bit(data, width, height, png::ColorType::Grayscale)
}

/// Decodes an 8-bit PNG of colour type `colour` (RGB frames, grey masks)
/// and the expected size; anything else is an error saying what it is.
pub fn decode_8bit(data: &[u8], width: u32, height: u32, colour: png::ColorType) -> Result<Vec<u8>, String> {
    let decoder = png::Decoder::new(std::io::Cursor::new(data));
    let mut reader = decoder.read_info().map_err(|e| format!("cannot decode: {e}"))?;
    let info = reader.info();
    if (info.width, info.height) != (width, height)
        || info.color_type != colour
        || info.bit_depth != png::BitDepth::Eight
    {
        return Err(format!(
            "{}x{} {:?} {:?}; expected {width}x{height} 8-bit {colour:?}",
            info.width, info.height, info.color_type, info.bit_depth
        ));
    }
    let mut buf = vec![0; reader.output_buffer_size().ok_or("image too large")?];
    reader.next_frame(&mut buf).map_err(|e| format!("cannot decode: {e}"))?;
    Ok(buf)
}
