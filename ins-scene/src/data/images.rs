//! Images and masks stored as 8-bit, read as f32 in `[0, 1]` on demand.
//!
//! 8-bit storage keeps memory in proportion to the files: the 100 lego training views
//! (800×800) take 256 MB as RGB + mask bytes instead of 1 GB as f32.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::DataError;

/// An RGB image, 8 bits per channel, row major `(y · width + x) · 3 + c`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width · height · 3` bytes.
    pub data: Vec<u8>,
}

/// A single-channel mask (or alpha), 0 = background, 255 = foreground, row major.
#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width · height` bytes.
    pub data: Vec<u8>,
}

impl Image {
    /// An image from f32 RGB values (`h·w·3`, clamped to `[0, 1]`, rounded).
    pub fn from_f32(width: u32, height: u32, rgb: &[f32]) -> Image {
        Image {
            width,
            height,
            data: rgb.iter().map(|&v| to_u8(v)).collect(),
        }
    }

    /// Colour of pixel `(x, y)` in `[0, 1]`.
    pub fn rgb(&self, x: u32, y: u32) -> [f32; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [
            self.data[i] as f32 / 255.0,
            self.data[i + 1] as f32 / 255.0,
            self.data[i + 2] as f32 / 255.0,
        ]
    }

    /// All pixels as f32 in `[0, 1]`, `h·w·3` row major.
    pub fn to_f32(&self) -> Vec<f32> {
        self.data.iter().map(|&v| v as f32 / 255.0).collect()
    }

    /// Box-filter downscale by an integer factor (size floored, the remainder cropped), which
    /// keeps continuous pixel coordinates exactly proportional: `x ↦ x / factor`.
    pub fn downscaled(&self, factor: u32) -> Image {
        Image {
            width: self.width / factor.max(1),
            height: self.height / factor.max(1),
            data: box_downscale(&self.data, self.width, self.height, 3, factor),
        }
    }

    /// Resized to `width`×`height` with a triangle (bilinear) filter.
    pub fn resized(&self, width: u32, height: u32) -> Image {
        match ::image::RgbImage::from_raw(self.width, self.height, self.data.clone()) {
            Some(buf) => {
                let out = ::image::imageops::resize(
                    &buf,
                    width,
                    height,
                    ::image::imageops::FilterType::Triangle,
                );
                Image {
                    width,
                    height,
                    data: out.into_raw(),
                }
            }
            None => Image {
                width,
                height,
                data: vec![0; width as usize * height as usize * 3],
            },
        }
    }

    /// Writes a PNG.
    pub fn save_png(&self, path: &Path) -> Result<(), DataError> {
        ::image::save_buffer_with_format(
            path,
            &self.data,
            self.width,
            self.height,
            ::image::ExtendedColorType::Rgb8,
            ::image::ImageFormat::Png,
        )
        .map_err(|e| DataError::image(path, e.to_string()))
    }
}

impl Mask {
    /// Mask value of pixel `(x, y)` in `[0, 1]`.
    pub fn value(&self, x: u32, y: u32) -> f32 {
        self.data[y as usize * self.width as usize + x as usize] as f32 / 255.0
    }

    /// All values as f32 in `[0, 1]`, row major.
    pub fn to_f32(&self) -> Vec<f32> {
        self.data.iter().map(|&v| v as f32 / 255.0).collect()
    }

    /// Fraction of pixels with value ≥ 0.5.
    pub fn coverage(&self) -> f32 {
        self.data.iter().filter(|&&v| v >= 128).count() as f32 / self.data.len().max(1) as f32
    }

    /// Box-filter downscale by an integer factor (see [`Image::downscaled`]).
    pub fn downscaled(&self, factor: u32) -> Mask {
        Mask {
            width: self.width / factor.max(1),
            height: self.height / factor.max(1),
            data: box_downscale(&self.data, self.width, self.height, 1, factor),
        }
    }
}

/// f32 in `[0, 1]` to a rounded byte.
pub(crate) fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn box_downscale(data: &[u8], w: u32, h: u32, channels: usize, factor: u32) -> Vec<u8> {
    let f = factor.max(1) as usize;
    if f == 1 {
        return data.to_vec();
    }
    let (w, h) = (w as usize, h as usize);
    let (ow, oh) = (w / f, h / f);
    let mut out = vec![0u8; ow * oh * channels];
    let n = (f * f) as u32;
    for oy in 0..oh {
        for ox in 0..ow {
            for c in 0..channels {
                let mut sum = 0u32;
                for y in oy * f..oy * f + f {
                    let row = y * w;
                    for x in ox * f..ox * f + f {
                        sum += data[(row + x) * channels + c] as u32;
                    }
                }
                out[(oy * ow + ox) * channels + c] = ((sum + n / 2) / n) as u8;
            }
        }
    }
    out
}

/// A decoded file: its colour, and its alpha channel when it has one.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// RGB channels (not composited).
    pub image: Image,
    /// Alpha, if the file has an alpha channel.
    pub alpha: Option<Mask>,
}

impl Decoded {
    /// Composites the colour over a white background using the alpha (the NeRF-synthetic
    /// convention) and returns `(image, alpha)`; images without alpha are returned unchanged.
    pub fn composite_on_white(self) -> (Image, Option<Mask>) {
        let Decoded { mut image, alpha } = self;
        if let Some(a) = &alpha {
            for (px, &av) in image.data.chunks_exact_mut(3).zip(a.data.iter()) {
                let av = av as u32;
                for c in px.iter_mut() {
                    *c = ((*c as u32 * av + 255 * (255 - av) + 127) / 255) as u8;
                }
            }
        }
        (image, alpha)
    }
}

/// The largest decoded image accepted: 16384 px per side and 512 MiB of pixels, so a file whose
/// header lies about its size is an error, not an allocation.
pub const MAX_SIDE: u32 = 16384;
/// See [`MAX_SIDE`].
pub const MAX_DECODED_BYTES: u64 = 512 << 20;

/// Decodes an image file (format sniffed from the content) within the limits above.
fn decode(path: &Path) -> Result<::image::DynamicImage, DataError> {
    let mut reader = ::image::ImageReader::open(path)
        .map_err(|e| DataError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| DataError::io(path, e))?;
    let mut limits = ::image::Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits.max_alloc = Some(MAX_DECODED_BYTES);
    reader.limits(limits);
    reader
        .decode()
        .map_err(|e| DataError::image(path, e.to_string()))
}

/// Decodes an image file (PNG or JPEG; format sniffed from the content), keeping alpha.
pub fn read_image(path: &Path) -> Result<Decoded, DataError> {
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    if img.color().has_alpha() {
        let rgba = img.into_rgba8().into_raw();
        let mut rgb = Vec::with_capacity(w as usize * h as usize * 3);
        let mut alpha = Vec::with_capacity(w as usize * h as usize);
        for px in rgba.chunks_exact(4) {
            rgb.extend_from_slice(&px[..3]);
            alpha.push(px[3]);
        }
        Ok(Decoded {
            image: Image {
                width: w,
                height: h,
                data: rgb,
            },
            alpha: Some(Mask {
                width: w,
                height: h,
                data: alpha,
            }),
        })
    } else {
        Ok(Decoded {
            image: Image {
                width: w,
                height: h,
                data: img.into_rgb8().into_raw(),
            },
            alpha: None,
        })
    }
}

/// Decodes a mask file: its grey level (0/255 masks stay 0/255).
pub fn read_mask(path: &Path) -> Result<Mask, DataError> {
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    Ok(Mask {
        width: w,
        height: h,
        data: img.into_luma8().into_raw(),
    })
}

/// Writes an 8-bit PNG with 1, 3 or 4 channels.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    data: &[u8],
) -> Result<(), DataError> {
    let ct = match channels {
        1 => ::image::ExtendedColorType::L8,
        3 => ::image::ExtendedColorType::Rgb8,
        4 => ::image::ExtendedColorType::Rgba8,
        _ => {
            return Err(DataError::image(
                path,
                format!("cannot write {channels} channels"),
            ));
        }
    };
    ::image::save_buffer_with_format(path, data, width, height, ct, ::image::ImageFormat::Png)
        .map_err(|e| DataError::image(path, e.to_string()))
}

/// Image files (`.png`, `.jpg`, `.jpeg`, any case) directly in `dir`, sorted by name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut files = Vec::new();
    for e in entries {
        let p = e.map_err(|e| DataError::io(dir, e))?.path();
        let ext = p
            .extension()
            .and_then(|s| s.to_str())
            .map(|s| s.to_ascii_lowercase());
        if p.is_file() && matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
            files.push(p);
        }
    }
    files.sort();
    Ok(files)
}

/// Applies `f` to every path on all cores (rayon), keeping the order; the first error in path
/// order wins, so the message does not depend on scheduling. Image decoding dominates loading
/// time, and this divides it by the number of cores.
pub fn parallel_map<T: Send>(
    paths: &[PathBuf],
    f: impl Fn(&Path) -> Result<T, DataError> + Sync,
) -> Result<Vec<T>, DataError> {
    let results: Vec<Result<T, DataError>> = paths.par_iter().map(|p| f(p)).collect();
    results.into_iter().collect()
}
