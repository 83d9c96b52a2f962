//! Forward warping of a frame into another camera by known geometry, with a depth test: the
//! measure of view consistency. Where the geometry is known (a trained field's depth), a frame
//! warped into its neighbour should match it wherever both see the same surface; what differs
//! there is flicker, the thing 3D stylization is meant to remove.

use ins_scene::camera::Camera;
use ins_scene::geometry::Vec3;

/// A rendered frame with the world point each pixel sees.
#[derive(Debug, Clone, Copy)]
pub struct GeoFrame<'a> {
    /// The camera it was rendered from.
    pub camera: &'a Camera,
    /// Colours, `h·w·3`, row major.
    pub rgb: &'a [f32],
    /// Surface point seen through each pixel's centre; `None` where the pixel sees empty space.
    pub points: &'a [Option<Vec3>],
}

/// A frame warped into another camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Warped {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Warped colours, `h·w·3` (zero where not valid).
    pub rgb: Vec<f32>,
    /// Pixels that received a source pixel of the same surface the target sees there.
    pub valid: Vec<bool>,
}

impl Warped {
    /// Number of valid pixels.
    pub fn valid_count(&self) -> usize {
        self.valid.iter().filter(|v| **v).count()
    }

    /// Root-mean-square colour difference to `target` (`h·w·3`) over the valid pixels; `None`
    /// when no pixel is valid.
    pub fn masked_rmse(&self, target: &[f32]) -> Option<f64> {
        let mut sum = 0.0f64;
        let mut n = 0usize;
        for (i, _) in self.valid.iter().enumerate().filter(|(_, v)| **v) {
            for c in 0..3 {
                let d = (self.rgb[i * 3 + c] - target[i * 3 + c]) as f64;
                sum += d * d;
            }
            n += 3;
        }
        (n > 0).then(|| (sum / n as f64).sqrt())
    }
}

/// Least splat weight a target pixel must gather to count as received.
const MIN_WEIGHT: f32 = 0.25;

/// Warps `src` into the camera of `dst` by forward projection: each source pixel's surface
/// point is projected into the target image and splatted bilinearly onto the four pixels
/// around it (sub-pixel accurate, so a textured surface warps onto itself, not onto its
/// neighbour's colour). The depth test: a splat counts only on target pixels that see a surface
/// at the point's depth along the target's viewing axis, within `rel_tolerance` (relative), so
/// points hidden in the target view, or where it sees nothing, are dropped. Target pixels that
/// gather too little weight (nothing landed near them) are masked out.
pub fn warp_forward(src: GeoFrame, dst: GeoFrame, rel_tolerance: f32) -> Warped {
    let (w, h) = (dst.camera.width as usize, dst.camera.height as usize);
    let own_depth: Vec<Option<f32>> = dst
        .points
        .iter()
        .map(|q| q.and_then(|q| dst.camera.depth_of(q)))
        .collect();
    let mut acc = vec![0.0f32; w * h * 3];
    let mut weight = vec![0.0f32; w * h];
    for (i, p) in src.points.iter().enumerate() {
        let Some(p) = *p else { continue };
        let (Some(xy), Some(z)) = (dst.camera.project(p), dst.camera.depth_of(p)) else {
            continue;
        };
        // Continuous position relative to pixel centres.
        let (x, y) = (xy[0] - 0.5, xy[1] - 0.5);
        let (u0, v0) = (x.floor(), y.floor());
        let (fx, fy) = (x - u0, y - v0);
        for (du, dv, wt) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let (u, v) = (u0 as i64 + du, v0 as i64 + dv);
            if wt <= 0.0 || u < 0 || v < 0 || u >= w as i64 || v >= h as i64 {
                continue;
            }
            let j = v as usize * w + u as usize;
            match own_depth[j] {
                Some(zt) if (z - zt).abs() <= rel_tolerance * zt.abs() => {}
                _ => continue,
            }
            weight[j] += wt;
            for c in 0..3 {
                acc[j * 3 + c] += wt * src.rgb[i * 3 + c];
            }
        }
    }
    let mut valid = vec![false; w * h];
    for j in 0..w * h {
        valid[j] = weight[j] >= MIN_WEIGHT;
        for c in 0..3 {
            acc[j * 3 + c] = if valid[j] {
                acc[j * 3 + c] / weight[j]
            } else {
                0.0
            };
        }
    }
    Warped {
        width: w,
        height: h,
        rgb: acc,
        valid,
    }
}

/// Mean of the defined values, or `None` when there are none.
pub fn mean_defined(values: impl IntoIterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = values.into_iter().flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use ins_scene::data::synthetic::{AnalyticScene, Rendering, Texture};
    use ins_scene::paths::turntable;

    fn cameras(n: usize, size: u32) -> Vec<Camera> {
        let template = Camera::from_fov_x(size, size, 0.7, [[1.0, 0.0, 0.0, 0.0]; 3]);
        turntable(Vec3::ZERO, Vec3::Z, 3.5, 0.5, 0.3, n, &template)
    }

    fn points(camera: &Camera, r: &Rendering) -> Vec<Option<Vec3>> {
        (0..r.depth.len())
            .map(|i| {
                let (u, v) = ((i as u32) % r.width, (i as u32) / r.width);
                let (o, d) = camera.pixel_ray(u, v);
                r.depth[i].is_finite().then(|| o + d * r.depth[i])
            })
            .collect()
    }

    fn frame<'a>(c: &'a Camera, r: &'a Rendering, p: &'a [Option<Vec3>]) -> GeoFrame<'a> {
        GeoFrame {
            camera: c,
            rgb: &r.rgb,
            points: p,
        }
    }

    /// The tabletop scene with its checkers made plain: point-sampled checker edges alias
    /// (a warped edge pixel is off by up to a pixel's colour), shading alone varies smoothly.
    pub(crate) fn smooth_tabletop() -> AnalyticScene {
        let mut scene = AnalyticScene::tabletop(false);
        for o in &mut scene.objects {
            if let Texture::Checker { a, .. } = o.texture {
                o.texture = Texture::Solid(a);
            }
        }
        scene
    }

    /// Two views 6° apart of the smooth tabletop scene, rendered with exact depth.
    fn pair() -> (Vec<Camera>, Vec<Rendering>, Vec<Vec<Option<Vec3>>>) {
        let scene = smooth_tabletop();
        let cams = cameras(60, 96);
        let cams = vec![cams[0].clone(), cams[1].clone()];
        let renders: Vec<Rendering> = cams.iter().map(|c| scene.render(c)).collect();
        let pts = cams
            .iter()
            .zip(&renders)
            .map(|(c, r)| points(c, r))
            .collect();
        (cams, renders, pts)
    }

    #[test]
    fn true_depth_warps_onto_the_next_frame() {
        let (c, r, p) = pair();
        let w = warp_forward(frame(&c[0], &r[0], &p[0]), frame(&c[1], &r[1], &p[1]), 0.01);
        assert!(
            w.valid_count() > 1000,
            "only {} valid pixels",
            w.valid_count()
        );
        let rmse = w.masked_rmse(&r[1].rgb).unwrap();
        // Not zero: a splat averages source samples up to a pixel from the target's centre,
        // so the shading's slope (about 0.05 per pixel on these spheres) leaks in.
        assert!(rmse < 0.015, "rmse {rmse}");

        // The same frame shifted by 3 pixels no longer matches.
        let mut shifted = r[0].rgb.clone();
        let wd = r[0].width as usize;
        for (i, px) in shifted.chunks_mut(3).enumerate() {
            let (u, v) = (i % wd, i / wd);
            let su = (u + 3).min(wd - 1);
            px.copy_from_slice(&r[0].rgb[(v * wd + su) * 3..(v * wd + su) * 3 + 3]);
        }
        let bad = GeoFrame {
            rgb: &shifted,
            ..frame(&c[0], &r[0], &p[0])
        };
        let ws = warp_forward(bad, frame(&c[1], &r[1], &p[1]), 0.01);
        let rmse_shifted = ws.masked_rmse(&r[1].rgb).unwrap();
        assert!(
            rmse_shifted > 0.05 && rmse_shifted > 8.0 * rmse,
            "shifted {rmse_shifted} vs {rmse}"
        );
    }

    #[test]
    fn pixels_hidden_in_the_target_are_masked_out() {
        let scene = AnalyticScene::tabletop(false);
        let cams = cameras(8, 96);
        // A quarter turn apart: much of what the first view sees is hidden in the second.
        let (a, b) = (&cams[0], &cams[2]);
        let (ra, rb) = (scene.render(a), scene.render(b));
        let (pa, pb) = (points(a, &ra), points(b, &rb));
        let w = warp_forward(frame(a, &ra, &pa), frame(b, &rb, &pb), 0.01);
        assert!(w.valid_count() > 100);
        // Warp the object ids instead of colours: every valid pixel must receive the object the
        // target sees there (silhouette pixels may see either of two).
        let ids = |r: &Rendering| -> Vec<f32> {
            r.object
                .iter()
                .flat_map(|o| [o.map_or(-1.0, |k| k as f32), 0.0, 0.0])
                .collect()
        };
        let (ia, ib) = (ids(&ra), ids(&rb));
        let src = GeoFrame {
            rgb: &ia,
            ..frame(a, &ra, &pa)
        };
        let wi = warp_forward(src, frame(b, &rb, &pb), 0.01);
        assert_eq!(wi.valid, w.valid);
        let wd = rb.width as usize;
        let mut wrong = 0;
        for j in (0..wi.valid.len()).filter(|&j| wi.valid[j]) {
            if wi.rgb[j * 3] != ib[j * 3] && rb.is_interior((j % wd) as u32, (j / wd) as u32) {
                wrong += 1;
            }
        }
        assert_eq!(wrong, 0, "valid pixels showing an occluded object");
        // Without the depth test the hidden points would land: show there are some.
        let mut hidden = 0;
        for (i, p) in pa.iter().enumerate() {
            let Some(p) = p else { continue };
            let Some(xy) = b.project(*p) else { continue };
            if b.in_frame(xy) {
                let j = xy[1] as usize * wd + xy[0] as usize;
                if rb.object[j] != ra.object[i] && rb.is_interior(xy[0] as u32, xy[1] as u32) {
                    hidden += 1;
                }
            }
        }
        assert!(
            hidden > 100,
            "the views should occlude each other ({hidden})"
        );
        // Every valid pixel sees a surface in the target.
        assert!(w.valid.iter().zip(&pb).all(|(v, p)| !*v || p.is_some()));
    }

    #[test]
    fn no_valid_pixel_gives_no_rmse() {
        let w = Warped {
            width: 1,
            height: 1,
            rgb: vec![0.0; 3],
            valid: vec![false],
        };
        assert_eq!(w.masked_rmse(&[1.0, 1.0, 1.0]), None);
        assert_eq!(mean_defined([None, Some(1.0), Some(3.0)]), Some(2.0));
        assert_eq!(mean_defined([None]), None);
    }
}
