//! View consistency of a frame sequence along a camera path: each frame `t` warped into frame
//! `t + k` by the known geometry, the masked RMSE between them, per pair and on average. The
//! peers' protocol (short range k = 1, long range k = 7) with geometry in place of optical flow.

use serde::Serialize;

use super::warp::{GeoFrame, mean_defined, warp_forward};
use ins_scene::camera::Camera;
use ins_scene::geometry::Vec3;

/// Relative depth tolerance of the occlusion test.
pub const DEPTH_TOLERANCE: f32 = 0.02;

/// The geometry of a path: its cameras and the surface point each pixel of each frame sees.
#[derive(Debug, Clone)]
pub struct PathGeometry {
    /// One camera per frame.
    pub cameras: Vec<Camera>,
    /// Per frame, per pixel (row major).
    pub points: Vec<Vec<Option<Vec3>>>,
}

/// The score of one pair `(t, t + k)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairScore {
    /// Source frame.
    pub from: usize,
    /// Target frame.
    pub to: usize,
    /// Masked RMSE in `[0, 1]` colour units; `None` when no pixel survives the masks.
    pub rmse: Option<f64>,
    /// Pixels compared.
    pub pixels: usize,
}

impl PathGeometry {
    /// Scores `frames` (one `h·w·3` image per camera) at range `k`: every pair `(t, t + k)`.
    /// The warps depend only on the geometry, so different frame sets (stylized, per-view 2D,
    /// unstylized) are compared on exactly the same pixels.
    pub fn pair_scores(&self, frames: &[&[f32]], k: usize) -> Vec<PairScore> {
        assert_eq!(frames.len(), self.cameras.len(), "one frame per camera");
        let n = frames.len();
        (0..n.saturating_sub(k))
            .map(|t| {
                let frame = |i: usize| GeoFrame {
                    camera: &self.cameras[i],
                    rgb: frames[i],
                    points: &self.points[i],
                };
                let w = warp_forward(frame(t), frame(t + k), DEPTH_TOLERANCE);
                PairScore {
                    from: t,
                    to: t + k,
                    rmse: w.masked_rmse(frames[t + k]),
                    pixels: w.valid_count(),
                }
            })
            .collect()
    }
}

/// Mean RMSE of pair scores (pairs with no comparable pixel left out).
pub fn mean_rmse(scores: &[PairScore]) -> Option<f64> {
    mean_defined(scores.iter().map(|s| s.rmse))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ins_scene::paths::turntable;

    #[test]
    fn a_consistent_sequence_scores_below_a_flickering_one() {
        let scene = crate::eval::warp::tests::smooth_tabletop();
        let template = Camera::from_fov_x(64, 64, 0.7, [[1.0, 0.0, 0.0, 0.0]; 3]);
        let cameras = turntable(Vec3::ZERO, Vec3::Z, 3.5, 0.5, 0.0, 40, &template);
        let renders: Vec<_> = cameras.iter().map(|c| scene.render(c)).collect();
        let points = cameras
            .iter()
            .zip(&renders)
            .map(|(c, r)| {
                (0..r.depth.len())
                    .map(|i| {
                        let (o, d) = c.pixel_ray(i as u32 % r.width, i as u32 / r.width);
                        r.depth[i].is_finite().then(|| o + d * r.depth[i])
                    })
                    .collect()
            })
            .collect();
        let geo = PathGeometry { cameras, points };
        let clean: Vec<&[f32]> = renders.iter().map(|r| r.rgb.as_slice()).collect();
        // Flicker: every other frame brightened, as a per-frame stylization might.
        let flicker_data: Vec<Vec<f32>> = renders
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let gain = if i % 2 == 0 { 1.0 } else { 1.3 };
                r.rgb.iter().map(|v| (v * gain).min(1.0)).collect()
            })
            .collect();
        let flicker: Vec<&[f32]> = flicker_data.iter().map(|v| v.as_slice()).collect();
        for k in [1, 7] {
            let a = geo.pair_scores(&clean, k);
            assert_eq!(a.len(), 40 - k);
            assert!(a.iter().all(|s| s.pixels > 0));
            let b = geo.pair_scores(&flicker, k);
            let (ma, mb) = (mean_rmse(&a).unwrap(), mean_rmse(&b).unwrap());
            assert!(ma < 0.02, "k={k}: clean {ma}");
            // Both ranges are odd, so every pair mixes a plain and a brightened frame.
            assert!(mb > 2.0 * ma, "k={k}: flicker {mb} vs clean {ma}");
        }
    }
}
