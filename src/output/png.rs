//! PNG encoding tuned for flat-coloured synthetic frames: fdeflate's fast
//! mode with adaptive (per-row) filtering. See README ("PNG settings") for the comparison
//! that led here.

use std::io::Write;

/// Pixel layout of an image to encode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    Rgb8,
    Gray8,
}

/// Encoder settings, exposed so the benchmark can compare them.
#[derive(Debug, Clone, Copy)]
pub struct PngSettings {
    pub compression: png::DeflateCompression,
    pub filter: png::Filter,
}

impl Default for PngSettings {
    fn default() -> Self {
        PngSettings { compression: png::DeflateCompression::FdeflateUltraFast, filter: png::Filter::Adaptive }
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
        PixelFormat::Gray8 => png::ColorType::Grayscale,
    });
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_deflate_compression(settings.compression);
    encoder.set_filter(settings.filter);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(data)?;
    writer.finish()
}
