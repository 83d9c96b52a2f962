//! The analytic scene's true surface as points, the reference a reconstructed mesh is scored
//! against (`eval mesh`): its foreground's outer surface sampled evenly, then only what the
//! cameras see, as DTU's ground truth covers what its scanner saw.

use crate::camera::Camera;
use crate::geometry::Vec3;

use super::analytic::{AnalyticScene, Shape};

/// How far off the surface (local units) a point may be probed to tell an outer face from one
/// buried in another box, or a visible point from a hidden one.
const PROBE: f32 = 1e-4;

impl AnalyticScene {
    /// Points about `spacing` apart over the foreground's outer surface, in the local frame:
    /// each box's faces on a grid and each sphere on a Fibonacci lattice, less the parts inside
    /// another object (the faces where boxes meet).
    pub fn foreground_surface(&self, spacing: f32) -> Vec<Vec3> {
        let spacing = spacing.max(1e-4);
        let mut candidates: Vec<(Vec3, Vec3)> = Vec::new();
        for o in self.objects.iter().filter(|o| o.foreground) {
            match o.shape {
                Shape::Box { min, max } => {
                    for axis in 0..3 {
                        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                        // Rounded up, less a hair: 0.2 / 0.02 in f32 is not to be 11 steps.
                        let steps = |k: usize| {
                            (((max[k] - min[k]) / spacing - 1e-3).ceil() as usize).max(1)
                        };
                        let (nu, nv) = (steps(u), steps(v));
                        for (side, plane) in [(-1.0f32, min[axis]), (1.0, max[axis])] {
                            let mut normal = Vec3::ZERO;
                            normal[axis] = side;
                            for i in 0..nu {
                                for j in 0..nv {
                                    let mut p = Vec3::ZERO;
                                    p[axis] = plane;
                                    p[u] =
                                        min[u] + (i as f32 + 0.5) / nu as f32 * (max[u] - min[u]);
                                    p[v] =
                                        min[v] + (j as f32 + 0.5) / nv as f32 * (max[v] - min[v]);
                                    candidates.push((p, normal));
                                }
                            }
                        }
                    }
                }
                Shape::Sphere { center, radius } => {
                    let area = 4.0 * std::f32::consts::PI * radius * radius;
                    let n = ((area / (spacing * spacing)).ceil() as usize).max(8);
                    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
                    for i in 0..n {
                        let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                        let r = (1.0 - z * z).max(0.0).sqrt();
                        let a = golden * i as f32;
                        let normal = Vec3::new(r * a.cos(), r * a.sin(), z);
                        candidates.push((center + normal * radius, normal));
                    }
                }
                Shape::Plane { .. } => {}
            }
        }
        candidates
            .into_iter()
            .filter(|&(p, n)| self.foreground_distance(p + n * PROBE) > 0.0)
            .map(|(p, _)| p)
            .collect()
    }

    /// Those of `points` (world frame) that at least one of `cameras` sees: in its frame, and
    /// the first thing its ray towards the point meets.
    pub fn seen_by(&self, points: &[Vec3], cameras: &[Camera]) -> Vec<Vec3> {
        let tolerance = PROBE * 10.0 * self.to_world.scale;
        points
            .iter()
            .copied()
            .filter(|&p| {
                cameras.iter().any(|c| {
                    if !c.project(p).is_some_and(|px| c.in_frame(px)) {
                        return false;
                    }
                    let eye = c.origin();
                    let to = p - eye;
                    let d = to.length();
                    self.trace(eye, to / d)
                        .is_some_and(|hit| hit.t > d - tolerance)
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_notched_blocks_surface_lies_on_its_outer_faces() {
        let scene = AnalyticScene::notched_block();
        let points = scene.foreground_surface(0.02);
        assert!(
            points
                .iter()
                .all(|&p| scene.foreground_distance(p).abs() < 1e-5)
        );
        // Its area: the 1×1×0.7 bounding box's 4.8 less nothing (the notch takes a corner's
        // three faces, 0.6×0.5 + 0.6×0.5 + 0.6×0.6, and adds three of the same): 0.02² each.
        let area = points.len() as f32 * 0.02 * 0.02;
        assert!(
            (area - 4.8).abs() < 0.1,
            "{area} from {} points",
            points.len()
        );
        // Nothing where the walls stand on the slab (z = −0.35 under the walls).
        assert!(
            !points
                .iter()
                .any(|p| (p.z + 0.35).abs() < 1e-6 && (p.x < -0.1 || p.y < -0.1))
        );
        // The notch's floor and its two inner walls are there.
        let [lo, hi] = AnalyticScene::NOTCH;
        let inside = |p: &Vec3| (0..3).all(|k| p[k] >= lo[k] - 1e-6 && p[k] <= hi[k] + 1e-6);
        assert!(points.iter().filter(|p| inside(p)).count() as f32 * 0.0004 > 0.9);
    }
}
