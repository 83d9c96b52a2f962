//! Single images for 2D fitting (SIREN): any PNG or JPEG as RGB in `[0, 1]`, optionally resized,
//! and the coordinate grid a coordinate network is fitted on.

use std::path::Path;

use super::DataError;
use super::images::{Image, read_image};

/// Reads an image as RGB (alpha composited on white), resized to `size = (width, height)` with
/// a triangle filter when given.
pub fn load_rgb(path: &Path, size: Option<(u32, u32)>) -> Result<Image, DataError> {
    let (img, _) = read_image(path)?.composite_on_white();
    Ok(match size {
        Some((w, h)) if (w, h) != (img.width, img.height) => {
            if w == 0 || h == 0 {
                return Err(DataError::Request(format!(
                    "cannot resize {} to {w}×{h}",
                    path.display()
                )));
            }
            img.resized(w, h)
        }
        _ => img,
    })
}

/// Reads an image as RGB, scaled down (never up) so its longer side is at most `max_side`,
/// keeping the aspect ratio.
pub fn load_rgb_max_side(path: &Path, max_side: u32) -> Result<Image, DataError> {
    let (img, _) = read_image(path)?.composite_on_white();
    let long = img.width.max(img.height);
    if long <= max_side || max_side == 0 {
        return Ok(img);
    }
    let s = max_side as f64 / long as f64;
    let w = ((img.width as f64 * s).round() as u32).max(1);
    let h = ((img.height as f64 * s).round() as u32).max(1);
    Ok(img.resized(w, h))
}

/// Pixel-centre coordinates in `[-1, 1]²`, row major: `x` grows to the right, `y` downward,
/// `(x, y) = (2(u + 0.5)/W − 1, 2(v + 0.5)/H − 1)`.
pub fn pixel_coordinates(width: u32, height: u32) -> Vec<[f32; 2]> {
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for v in 0..height {
        for u in 0..width {
            out.push([
                2.0 * (u as f32 + 0.5) / width as f32 - 1.0,
                2.0 * (v as f32 + 0.5) / height as f32 - 1.0,
            ]);
        }
    }
    out
}
