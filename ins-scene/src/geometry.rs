//! Vector maths on `glam` (points, directions, rotations, quaternions), plus the scene's
//! bounding volume and the similarity that maps a dataset's frame to the scene frame.

use glam::{DMat3, DVec3};
pub use glam::{Mat3, Quat, Vec3};
use serde::Serialize;

/// Inverse of a row-major 3×3 f64 matrix; `None` when it is (numerically) singular relative to
/// its largest entry.
pub fn inverse3_f64(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let m = DMat3::from_cols_array_2d(a).transpose();
    let scale_ref = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    let det = m.determinant();
    if !det.is_finite() || det.abs() <= 1e-12 * scale_ref.powi(3) {
        return None;
    }
    Some(m.inverse().transpose().to_cols_array_2d())
}

/// A row-major `[[f32; 3]; 3]` as a matrix.
pub fn mat3_from_rows(rows: [[f32; 3]; 3]) -> Mat3 {
    Mat3::from_cols_array_2d(&rows).transpose()
}

/// A matrix as row-major `[[f32; 3]; 3]`.
pub fn mat3_rows(m: Mat3) -> [[f32; 3]; 3] {
    m.transpose().to_cols_array_2d()
}

/// Largest deviation of `mᵀm` from the identity: 0 for a rotation (or reflection).
pub fn orthonormality_error(m: Mat3) -> f32 {
    let p = m.transpose() * m - Mat3::IDENTITY;
    p.to_cols_array().iter().fold(0.0f32, |e, v| e.max(v.abs()))
}

/// The region of space that holds the scene: rays are clipped to it and contact sheets draw it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Bounds {
    /// A sphere (DTU / IDR: the unit sphere given by `scale_mat`).
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
    },
    /// An axis-aligned box (Blender scenes; the viewed region of LLFF scenes).
    Aabb {
        /// Minimum corner.
        min: Vec3,
        /// Maximum corner.
        max: Vec3,
    },
}

impl Bounds {
    /// Centre of the volume.
    pub fn center(&self) -> Vec3 {
        match *self {
            Bounds::Sphere { center, .. } => center,
            Bounds::Aabb { min, max } => 0.5 * (min + max),
        }
    }

    /// The axis-aligned box that encloses the volume.
    pub fn aabb(&self) -> (Vec3, Vec3) {
        match *self {
            Bounds::Sphere { center, radius } => {
                (center - Vec3::splat(radius), center + Vec3::splat(radius))
            }
            Bounds::Aabb { min, max } => (min, max),
        }
    }

    /// Whether `p` lies inside (or on) the volume.
    pub fn contains(&self, p: Vec3) -> bool {
        match *self {
            Bounds::Sphere { center, radius } => (p - center).length() <= radius,
            Bounds::Aabb { min, max } => p.cmpge(min).all() && p.cmple(max).all(),
        }
    }

    /// Parameter interval `[t0, t1]` (t0 may be negative when the origin is inside) where the
    /// ray `o + t·d` is inside the volume, or `None` when it misses. `d` need not be unit.
    pub fn intersect(&self, o: Vec3, d: Vec3) -> Option<(f32, f32)> {
        match *self {
            Bounds::Sphere { center, radius } => {
                let oc = o - center;
                let a = d.dot(d);
                let b = oc.dot(d);
                let c = oc.dot(oc) - radius * radius;
                let disc = b * b - a * c;
                if a <= 0.0 || disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                Some(((-b - s) / a, (-b + s) / a))
            }
            Bounds::Aabb { min, max } => {
                let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
                for i in 0..3 {
                    if d[i].abs() < 1e-12 {
                        if o[i] < min[i] || o[i] > max[i] {
                            return None;
                        }
                    } else {
                        let (a, b) = ((min[i] - o[i]) / d[i], (max[i] - o[i]) / d[i]);
                        t0 = t0.max(a.min(b));
                        t1 = t1.min(a.max(b));
                    }
                }
                (t0 <= t1).then_some((t0, t1))
            }
        }
    }

    /// Line segments that outline the volume, for drawing: the 12 edges of a box, or three
    /// great circles (48 segments each) of a sphere.
    pub fn outline(&self) -> Vec<(Vec3, Vec3)> {
        match *self {
            Bounds::Aabb { min, max } => {
                let corner = |i: usize| {
                    Vec3::new(
                        if i & 1 == 0 { min.x } else { max.x },
                        if i & 2 == 0 { min.y } else { max.y },
                        if i & 4 == 0 { min.z } else { max.z },
                    )
                };
                let mut edges = Vec::with_capacity(12);
                for i in 0..8usize {
                    for bit in [1usize, 2, 4] {
                        if i & bit == 0 {
                            edges.push((corner(i), corner(i | bit)));
                        }
                    }
                }
                edges
            }
            Bounds::Sphere { center, radius } => {
                let n = 48;
                let mut edges = Vec::with_capacity(3 * n);
                for axis in 0..3 {
                    let point = |k: usize| {
                        let a = k as f32 / n as f32 * std::f32::consts::TAU;
                        let (s, c) = a.sin_cos();
                        let mut p = Vec3::ZERO;
                        p[(axis + 1) % 3] = c * radius;
                        p[(axis + 2) % 3] = s * radius;
                        center + p
                    };
                    for k in 0..n {
                        edges.push((point(k), point(k + 1)));
                    }
                }
                edges
            }
        }
    }
}

/// Scene contraction for unbounded captures (mip-NeRF 360's, with the max norm as nerfacto and
/// Zip-NeRF use, so the contracted space is a cube a grid fills): points within `radius` (max
/// norm) stay where they are; a point at max norm `n > radius` moves to
/// `(2 − radius/n) · radius · p/n`, so all of space fits in the cube of half side `2·radius`
/// and the far background gets a share of the grid that shrinks with distance.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Contraction {
    /// Half side of the cube left as it is (the scene frame's units).
    pub radius: f32,
}

impl Contraction {
    /// The contracted point.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        let n = p.abs().max_element();
        if n <= self.radius {
            return p;
        }
        p * ((2.0 - self.radius / n) * self.radius / n)
    }

    /// How much longer a step at `p` is than at the centre for the contracted spacing of
    /// samples to stay even: `(n / radius)²` beyond the radius (the contraction's radial
    /// derivative is `(radius / n)²`), 1 inside.
    pub fn step_scale(&self, p: Vec3) -> f32 {
        let n = p.abs().max_element() / self.radius;
        if n <= 1.0 { 1.0 } else { n * n }
    }

    /// Half side of the cube that holds all contracted space.
    pub fn extent(&self) -> f32 {
        2.0 * self.radius
    }
}

/// A similarity transform `p ↦ scale · R p + t` (rotation, uniform scale, translation).
///
/// Loaders that move the data into a normalized frame (LLFF recentring and rescaling, DTU's
/// `scale_mat`) record the map from the dataset's own world frame to the scene frame here, so
/// points known in the source frame can be checked against the scene's rays.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Similarity {
    /// Uniform scale: a distance `d` in the source frame is `scale · d` in the scene frame.
    pub scale: f32,
    /// Rotation.
    pub rotation: Mat3,
    /// Translation.
    pub translation: Vec3,
}

impl Similarity {
    /// The identity map.
    pub fn identity() -> Self {
        Similarity {
            scale: 1.0,
            rotation: Mat3::IDENTITY,
            translation: Vec3::ZERO,
        }
    }

    /// Maps a point.
    pub fn apply_point(&self, p: Vec3) -> Vec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Maps a direction (rotation only, no scale).
    pub fn apply_direction(&self, d: Vec3) -> Vec3 {
        self.rotation * d
    }

    /// The map back: `inverse().apply_point(apply_point(p)) == p`.
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.transpose();
        Similarity {
            scale: 1.0 / self.scale,
            rotation,
            translation: -(rotation * self.translation) / self.scale,
        }
    }

    /// Builds one from a 3×4 affine matrix `[A | t]` whose `A` is a scaled rotation; `None`
    /// when `A` is singular or not a similarity (tolerance 1e-3 relative).
    pub fn from_affine(m: &[[f64; 4]; 3]) -> Option<Self> {
        let a = DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        );
        let det = a.determinant();
        if !det.is_finite() || det <= 0.0 {
            return None;
        }
        let s = det.cbrt();
        let rot = (a * (1.0 / s)).as_mat3();
        if orthonormality_error(rot) > 1e-3 {
            return None;
        }
        Some(Similarity {
            scale: s as f32,
            rotation: rot,
            translation: Vec3::new(m[0][3] as f32, m[1][3] as f32, m[2][3] as f32),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_similarity_and_its_inverse_undo_each_other() {
        let m = [
            [0.0, -2.0, 0.0, 1.0],
            [2.0, 0.0, 0.0, -3.0],
            [0.0, 0.0, 2.0, 0.5],
        ];
        let s = Similarity::from_affine(&m).unwrap();
        let p = Vec3::new(0.3, -1.2, 4.0);
        let back = s.inverse().apply_point(s.apply_point(p));
        assert!((back - p).length() < 1e-5, "{back}");
        assert!((s.inverse().scale - 0.5).abs() < 1e-6);
    }

    #[test]
    #[allow(clippy::needless_range_loop)] // matrix entries by row and column
    fn f64_inverse_and_singular_matrices() {
        let a = [[2.0, 0.0, 1.0], [0.0, 3.0, 0.0], [1.0, 0.0, 1.0]];
        let inv = inverse3_f64(&a).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let v: f64 = (0..3).map(|k| a[i][k] * inv[k][j]).sum();
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(inverse3_f64(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]).is_none());
    }

    #[test]
    fn similarity_round_trip() {
        let r = Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let rows = mat3_rows(r * 2.5);
        let m = [
            [rows[0][0] as f64, rows[0][1] as f64, rows[0][2] as f64, 1.0],
            [
                rows[1][0] as f64,
                rows[1][1] as f64,
                rows[1][2] as f64,
                -2.0,
            ],
            [rows[2][0] as f64, rows[2][1] as f64, rows[2][2] as f64, 0.5],
        ];
        let s = Similarity::from_affine(&m).unwrap();
        assert!((s.scale - 2.5).abs() < 1e-5);
        let p = Vec3::new(0.3, -0.2, 1.0);
        let want = 2.5 * (r * p) + Vec3::new(1.0, -2.0, 0.5);
        assert!((s.apply_point(p) - want).length() < 1e-5);
    }

    #[test]
    fn contraction_keeps_the_inside_and_folds_everything_into_the_cube() {
        let c = Contraction { radius: 2.0 };
        let inside = Vec3::new(1.5, -2.0, 0.3);
        assert_eq!(c.apply(inside), inside);
        for p in [
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(-1e6, 5.0, 2.0),
            Vec3::splat(40.0),
        ] {
            let q = c.apply(p);
            assert!(q.abs().max_element() < c.extent(), "{p} → {q}");
            // Direction kept, and farther points stay farther.
            assert!(q.normalize().dot(p.normalize()) > 0.9999);
            assert!(c.apply(p * 2.0).abs().max_element() > q.abs().max_element());
        }
        // Continuous at the radius, and the step scale matches the radial derivative.
        let edge = Vec3::new(2.0, 0.5, 0.0);
        assert!((c.apply(edge * 1.0001) - edge).length() < 1e-3);
        let p = Vec3::new(6.0, 1.0, 0.0);
        let h = 1e-2;
        let deriv = (c.apply(p + Vec3::X * h).x - c.apply(p).x) / h;
        assert!((deriv * c.step_scale(p) - 1.0).abs() < 1e-2, "{deriv}");
    }

    #[test]
    fn ray_volume_intersections() {
        let sphere = Bounds::Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
        };
        let (t0, t1) = sphere
            .intersect(Vec3::new(0.0, 0.0, 3.0), Vec3::NEG_Z)
            .unwrap();
        assert!((t0 - 2.0).abs() < 1e-6 && (t1 - 4.0).abs() < 1e-6);
        let aabb = Bounds::Aabb {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        assert!(
            aabb.intersect(Vec3::new(0.0, 3.0, 3.0), Vec3::NEG_Z)
                .is_none()
        );
        assert_eq!(aabb.outline().len(), 12);
    }
}
