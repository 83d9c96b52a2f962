//! A small RGB canvas: lines, rectangles and text, saved as PNG. Enough for plots and contact
//! sheets without a plotting dependency.

use std::path::Path;

use anyhow::{Context, Result};

use super::font::glyph;

/// An RGB8 image being drawn on.
pub struct Canvas {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGB bytes.
    pub pixels: Vec<u8>,
}

impl Canvas {
    /// A canvas filled with `bg`.
    pub fn new(width: u32, height: u32, bg: [u8; 3]) -> Self {
        let pixels = bg
            .iter()
            .copied()
            .cycle()
            .take((width * height * 3) as usize)
            .collect();
        Self {
            width,
            height,
            pixels,
        }
    }

    /// Sets one pixel (ignored outside the canvas).
    pub fn put(&mut self, x: i32, y: i32, c: [u8; 3]) {
        if x < 0 || y < 0 || x >= self.width as i32 || y >= self.height as i32 {
            return;
        }
        let i = ((y as u32 * self.width + x as u32) * 3) as usize;
        self.pixels[i..i + 3].copy_from_slice(&c);
    }

    /// A one-pixel line (Bresenham).
    pub fn line(&mut self, x0: i32, y0: i32, x1: i32, y1: i32, c: [u8; 3]) {
        let (mut x, mut y) = (x0, y0);
        let dx = (x1 - x0).abs();
        let dy = -(y1 - y0).abs();
        let sx = if x0 < x1 { 1 } else { -1 };
        let sy = if y0 < y1 { 1 } else { -1 };
        let mut err = dx + dy;
        let mut guard = 0;
        loop {
            self.put(x, y, c);
            if (x == x1 && y == y1) || guard > 100_000 {
                break;
            }
            guard += 1;
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// A filled rectangle.
    pub fn fill_rect(&mut self, x: i32, y: i32, w: i32, h: i32, c: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.put(xx, yy, c);
            }
        }
    }

    /// A rectangle outline.
    pub fn rect_outline(&mut self, x: i32, y: i32, w: i32, h: i32, c: [u8; 3]) {
        self.line(x, y, x + w, y, c);
        self.line(x, y + h, x + w, y + h, c);
        self.line(x, y, x, y + h, c);
        self.line(x + w, y, x + w, y + h, c);
    }

    /// Text in the built-in 3×5 font, scaled by `scale`.
    pub fn text(&mut self, x: i32, y: i32, s: &str, c: [u8; 3], scale: i32) {
        let mut cx = x;
        for ch in s.chars() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..3 {
                    if bits & (0b100 >> col) != 0 {
                        self.fill_rect(cx + col * scale, y + row as i32 * scale, scale, scale, c);
                    }
                }
            }
            cx += 4 * scale;
        }
    }

    /// Copies an RGB image (`w`×`h`, f32 in [0,1]) with its top-left corner at (x, y).
    pub fn blit_f32(&mut self, x: i32, y: i32, w: u32, h: u32, rgb: &[f32]) {
        for yy in 0..h {
            for xx in 0..w {
                let i = ((yy * w + xx) * 3) as usize;
                let px = [
                    (rgb[i].clamp(0.0, 1.0) * 255.0).round() as u8,
                    (rgb[i + 1].clamp(0.0, 1.0) * 255.0).round() as u8,
                    (rgb[i + 2].clamp(0.0, 1.0) * 255.0).round() as u8,
                ];
                self.put(x + xx as i32, y + yy as i32, px);
            }
        }
    }

    /// Writes the canvas as PNG.
    pub fn save(&self, path: &Path) -> Result<()> {
        let img = image::RgbImage::from_raw(self.width, self.height, self.pixels.clone())
            .context("canvas size")?;
        img.save(path)
            .with_context(|| format!("writing {}", path.display()))
    }
}
