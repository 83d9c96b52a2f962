//! Between image files, RGB buffers and tensors.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::prelude::*;

/// An RGB image as f32 in [0, 1], row-major, 3 values per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// `height·width·3` values.
    pub data: Vec<f32>,
}

impl RgbImage {
    /// Reads a PNG or JPEG through [`ins_scene::data::plain_image::load_rgb`] (alpha composited on
    /// white); errors name the file.
    pub fn load(path: &Path) -> Result<Self> {
        let img = ins_scene::data::plain_image::load_rgb(path, None)?;
        Ok(Self {
            width: img.width as usize,
            height: img.height as usize,
            data: img.to_f32(),
        })
    }

    /// Resized (Lanczos) to `width`×`height`.
    pub fn resized(&self, width: usize, height: usize) -> Self {
        if width == self.width && height == self.height {
            return self.clone();
        }
        let buf =
            image::Rgb32FImage::from_raw(self.width as u32, self.height as u32, self.data.clone())
                .expect("buffer matches its size");
        let out = image::imageops::resize(
            &buf,
            width as u32,
            height as u32,
            image::imageops::FilterType::Lanczos3,
        );
        Self {
            width,
            height,
            data: out
                .into_raw()
                .into_iter()
                .map(|v| v.clamp(0.0, 1.0))
                .collect(),
        }
    }

    /// Resized so that the longer side is `max_side` (aspect kept).
    pub fn fit_within(&self, max_side: usize) -> Self {
        let scale = max_side as f64 / self.width.max(self.height) as f64;
        let w = ((self.width as f64 * scale).round() as usize).max(1);
        let h = ((self.height as f64 * scale).round() as usize).max(1);
        self.resized(w, h)
    }

    /// `[1, 3, H, W]` tensor.
    pub fn to_tensor(&self, device: &Device) -> Tensor<4> {
        Tensor::<1>::from_data(
            TensorData::new(self.data.clone(), [self.data.len()]),
            device,
        )
        .reshape([1, self.height, self.width, 3])
        .permute([0, 3, 1, 2])
    }

    /// From an `[H, W, 3]` tensor.
    pub fn from_hwc(t: Tensor<3>) -> Result<Self> {
        let [h, w, c] = t.dims();
        if c != 3 {
            bail!("expected 3 channels, got {c}");
        }
        let data = t
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("reading tensor: {e:?}"))?;
        Ok(Self {
            width: w,
            height: h,
            data,
        })
    }

    /// Saves as PNG (or any format the extension names), atomically: a killed process leaves
    /// the old file or the new one, never half of one.
    pub fn save(&self, path: &Path) -> Result<()> {
        let img = self.to_rgb8()?;
        let format = image::ImageFormat::from_path(path)
            .with_context(|| format!("{}: unknown image extension", path.display()))?;
        ins_io::write_atomic_with(path, |tmp| {
            img.save_with_format(tmp, format)
                .with_context(|| format!("writing {}", path.display()))
        })
    }

    /// 8 bits per channel, rounded.
    fn to_rgb8(&self) -> Result<image::RgbImage> {
        let bytes: Vec<u8> = self
            .data
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        image::RgbImage::from_raw(self.width as u32, self.height as u32, bytes)
            .context("image size")
    }

    /// The picture as PNG bytes (8 bits per channel, as [`RgbImage::save`] writes it).
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let img = self.to_rgb8()?;
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png)
            .context("encoding a PNG")?;
        Ok(out.into_inner())
    }

    /// Images stacked top to bottom (narrower ones padded with white on the right).
    pub fn vstack(images: &[RgbImage]) -> Self {
        let width = images.iter().map(|i| i.width).max().unwrap_or(0);
        let height: usize = images.iter().map(|i| i.height).sum();
        let mut data = vec![1.0f32; width * height * 3];
        let mut y0 = 0;
        for img in images {
            for y in 0..img.height {
                let src = &img.data[y * img.width * 3..(y + 1) * img.width * 3];
                let dst = ((y0 + y) * width) * 3;
                data[dst..dst + img.width * 3].copy_from_slice(src);
            }
            y0 += img.height;
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Side-by-side strip of images of the same height.
    pub fn hstack(images: &[RgbImage]) -> Self {
        let height = images.iter().map(|i| i.height).max().unwrap_or(0);
        let width: usize = images.iter().map(|i| i.width).sum();
        let mut data = vec![1.0f32; width * height * 3];
        let mut x0 = 0;
        for img in images {
            for y in 0..img.height {
                let src = &img.data[y * img.width * 3..(y + 1) * img.width * 3];
                let dst = (y * width + x0) * 3;
                data[dst..dst + img.width * 3].copy_from_slice(src);
            }
            x0 += img.width;
        }
        Self {
            width,
            height,
            data,
        }
    }
}

/// A colour for `t ∈ [0, 1]` on the turbo colour map (Mikhailov 2019, polynomial fit):
/// blue near, red far, readable in print and by most colour-blind readers.
pub fn turbo(t: f32) -> [f32; 3] {
    let t = t.clamp(0.0, 1.0) as f64;
    let poly = |c: [f64; 6]| {
        (c[0] + t * (c[1] + t * (c[2] + t * (c[3] + t * (c[4] + t * c[5]))))).clamp(0.0, 1.0) as f32
    };
    [
        poly([
            0.135_721_38,
            4.615_392_6,
            -42.660_322_57,
            132.131_082_34,
            -152.942_393_97,
            59.286_379_16,
        ]),
        poly([
            0.091_402_61,
            2.194_188_39,
            4.842_966_58,
            -14.185_033_33,
            4.277_298_57,
            2.829_566_04,
        ]),
        poly([
            0.106_673_3,
            12.641_946_08,
            -60.582_048_36,
            110.362_767_71,
            -89.903_109_12,
            27.348_249_81,
        ]),
    ]
}

/// The depth of the pixels that see a surface (`None` elsewhere, shown white) as a picture,
/// colour-mapped over the range most of them span: the 2nd to the 98th percentile, so a few
/// far pixels (a contracted background, a floater) do not squeeze the rest into one colour.
pub fn surface_depth_image(depth: &[Option<f32>], width: usize, height: usize) -> RgbImage {
    let mut seen: Vec<f32> = depth.iter().flatten().copied().collect();
    seen.sort_by(f32::total_cmp);
    let at = |q: f64| seen[((seen.len() - 1) as f64 * q).round() as usize];
    let (lo, hi) = if seen.is_empty() {
        (0.0, 1.0)
    } else {
        (at(DEPTH_RANGE.0), at(DEPTH_RANGE.1))
    };
    let opacity: Vec<f32> = depth
        .iter()
        .map(|d| if d.is_some() { 1.0 } else { 0.0 })
        .collect();
    let d: Vec<f32> = depth.iter().map(|d| d.unwrap_or(0.0)).collect();
    depth_image(&d, &opacity, width, height, lo, hi)
}

/// The share of surface pixels below which, and above which, depth pictures clip their colours.
pub const DEPTH_RANGE: (f64, f64) = (0.02, 0.98);

/// A depth map as a picture: `depth` divided by `opacity` where the opacity is above 0.5,
/// mapped from `[near, far]` onto the turbo colours; transparent pixels are white.
pub fn depth_image(
    depth: &[f32],
    opacity: &[f32],
    width: usize,
    height: usize,
    near: f32,
    far: f32,
) -> RgbImage {
    let mut data = Vec::with_capacity(width * height * 3);
    let span = (far - near).max(1e-6);
    for (d, o) in depth.iter().zip(opacity) {
        if *o > 0.5 {
            data.extend(turbo((d / o - near) / span));
        } else {
            data.extend([1.0, 1.0, 1.0]);
        }
    }
    RgbImage {
        width,
        height,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_pictures_spread_their_colours_over_what_most_pixels_show() {
        // 98 pixels at depths 1 to 2, two far ones (a contracted background), one empty.
        let mut depth: Vec<Option<f32>> = (0..98).map(|i| Some(1.0 + i as f32 / 97.0)).collect();
        depth.extend([Some(100.0), Some(100.0), None]);
        let img = surface_depth_image(&depth, depth.len(), 1);
        let px = |i: usize| [img.data[3 * i], img.data[3 * i + 1], img.data[3 * i + 2]];
        assert_eq!(
            px(0),
            turbo(0.0),
            "the nearest pixel takes the first colour"
        );
        assert_eq!(px(97), turbo(1.0), "the bulk's farthest takes the last");
        assert_eq!(
            px(98),
            turbo(1.0),
            "a far outlier is clipped, not given the range"
        );
        // Over the range of all pixels the bulk would sit within the first hundredth of the
        // colours; here its middle pixel takes the middle colour.
        let far = |a: [f32; 3], b: [f32; 3]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        let mid = px(48);
        assert!(
            far(mid, turbo(0.5)) < 0.15,
            "{mid:?} against {:?}",
            turbo(0.5)
        );
        assert!(
            far(mid, turbo(0.0)) > 0.3 && far(mid, turbo(1.0)) > 0.3,
            "{mid:?}"
        );
        assert_eq!(px(100), [1.0, 1.0, 1.0], "no surface: white");
    }
}
