//! Small labels on images people look at (contact sheets, the heat map's
//! colour bar): an 8 x 8 bitmap font (font8x8), scaled by whole pixels,
//! on a solid box so it reads over any background. Never used on dataset
//! frames.

use font8x8::legacy::BASIC_LEGACY;

/// Glyph cell side, pixels at scale 1.
pub const GLYPH_PX: u32 = 8;

/// An image buffer to draw into: row-major, `channels` bytes a pixel (3 or
/// 4; a fourth channel is set opaque).
pub struct Canvas<'a> {
    pub data: &'a mut [u8],
    pub width: u32,
    pub height: u32,
    pub channels: usize,
}

impl Canvas<'_> {
    fn put(&mut self, x: i64, y: i64, rgb: [u8; 3]) {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return;
        }
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        self.data[i..i + 3].copy_from_slice(&rgb);
        if self.channels == 4 {
            self.data[i + 3] = 255;
        }
    }
}

/// Width and height of `text` drawn at `scale`, with its one-pixel (times
/// scale) padding box.
pub fn label_size(text: &str, scale: u32) -> (u32, u32) {
    let chars = text.chars().count() as u32;
    ((chars * GLYPH_PX + 2) * scale, (GLYPH_PX + 2) * scale)
}

/// Draws `text` (ASCII; anything else as `?`) with its box's top-left corner
/// at (x, y): `fg` letters on a `bg` box. Clipped to the canvas.
pub fn draw_label(canvas: &mut Canvas<'_>, x: i64, y: i64, text: &str, scale: u32, fg: [u8; 3], bg: [u8; 3]) {
    let (w, h) = label_size(text, scale);
    for dy in 0..h as i64 {
        for dx in 0..w as i64 {
            canvas.put(x + dx, y + dy, bg);
        }
    }
    let s = scale as i64;
    for (k, c) in text.chars().enumerate() {
        let glyph = BASIC_LEGACY[if c.is_ascii() { c as usize } else { b'?' as usize }];
        let left = x + s + k as i64 * GLYPH_PX as i64 * s;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 1 {
                    for (py, px) in (0..s).flat_map(|a| (0..s).map(move |b| (a, b))) {
                        canvas.put(left + col * s + px, y + s + row as i64 * s + py, fg);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_sets_exactly_its_glyph_pixels_on_its_box() {
        let (w, h) = (40u32, 20u32);
        let mut data = vec![0u8; (w * h * 3) as usize];
        let mut canvas = Canvas { data: &mut data, width: w, height: h, channels: 3 };
        draw_label(&mut canvas, 2, 3, "17", 1, [255, 255, 255], [10, 10, 10]);
        let lit = data.chunks(3).filter(|p| p == &[255, 255, 255]).count();
        let glyph_bits: u32 =
            ['1', '7'].iter().map(|&c| BASIC_LEGACY[c as usize].iter().map(|r| r.count_ones()).sum::<u32>()).sum();
        assert!(glyph_bits > 10);
        assert_eq!(lit as u32, glyph_bits);
        let boxed = data.chunks(3).filter(|p| p == &[10, 10, 10]).count() as u32;
        assert_eq!(boxed + glyph_bits, 18 * 10, "the box is (2 x 8 + 2) x (8 + 2) pixels");
        // At scale 2 every glyph pixel is 2 x 2; labels clip at the edge without panicking.
        let mut data = vec![0u8; (w * h * 4) as usize];
        let mut canvas = Canvas { data: &mut data, width: w, height: h, channels: 4 };
        draw_label(&mut canvas, 30, 15, "17", 2, [255, 255, 255], [10, 10, 10]);
        draw_label(&mut canvas, 0, 0, "1", 2, [255, 255, 255], [10, 10, 10]);
        let lit = data.chunks(4).filter(|p| p[..3] == [255, 255, 255]).count() as u32;
        let one: u32 = BASIC_LEGACY['1' as usize].iter().map(|r| r.count_ones()).sum();
        assert!(lit >= 4 * one);
    }
}
