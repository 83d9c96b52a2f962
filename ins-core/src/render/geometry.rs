//! Small fixed-size vector, matrix and quaternion helpers, and the scene's bounding volume.
//!
//! Plain `[f32; 3]` arrays keep the data layer independent of any tensor backend: a batch of
//! them flattens to the `[n, 3]` layout a tensor wants with `as_flattened()`.

use serde::Serialize;

/// A point or direction in 3D.
pub type Vec3 = [f32; 3];
/// A 3×3 matrix, row major.
pub type Mat3 = [[f32; 3]; 3];

/// `a + b`.
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · s`.
pub fn scale(a: Vec3, s: f32) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Dot product.
pub fn dot(a: Vec3, b: Vec3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Cross product.
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Euclidean length.
pub fn norm(a: Vec3) -> f32 {
    dot(a, a).sqrt()
}

/// `a / |a|`; the zero vector stays zero rather than becoming NaN.
pub fn normalize(a: Vec3) -> Vec3 {
    let n = norm(a);
    if n > 0.0 { scale(a, 1.0 / n) } else { a }
}

/// `a + (b − a) · t`.
pub fn lerp(a: Vec3, b: Vec3, t: f32) -> Vec3 {
    add(a, scale(sub(b, a), t))
}

/// `m · v`.
pub fn mat3_mul_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `a · b`.
pub fn mat3_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

/// Transpose.
pub fn transpose(m: &Mat3) -> Mat3 {
    [
        [m[0][0], m[1][0], m[2][0]],
        [m[0][1], m[1][1], m[2][1]],
        [m[0][2], m[1][2], m[2][2]],
    ]
}

/// Determinant.
pub fn det3(m: &Mat3) -> f32 {
    dot(m[0], cross(m[1], m[2]))
}

/// Inverse, computed in f64; `None` when (numerically) singular.
pub fn inverse3(m: &Mat3) -> Option<Mat3> {
    let a: [[f64; 3]; 3] = m.map(|r| r.map(f64::from));
    let inv = inverse3_f64(&a)?;
    Some(inv.map(|r| r.map(|v| v as f32)))
}

/// Inverse of a 3×3 f64 matrix; `None` when singular.
pub fn inverse3_f64(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c =
        |r0: usize, c0: usize, r1: usize, c1: usize| a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0];
    let cof = [
        [c(1, 1, 2, 2), -c(1, 0, 2, 2), c(1, 0, 2, 1)],
        [-c(0, 1, 2, 2), c(0, 0, 2, 2), -c(0, 0, 2, 1)],
        [c(0, 1, 1, 2), -c(0, 0, 1, 2), c(0, 0, 1, 1)],
    ];
    let det = a[0][0] * cof[0][0] + a[0][1] * cof[0][1] + a[0][2] * cof[0][2];
    let scale_ref = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !det.is_finite() || det.abs() <= 1e-12 * scale_ref.powi(3) {
        return None;
    }
    let mut inv = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            inv[i][j] = cof[j][i] / det;
        }
    }
    Some(inv)
}

/// Largest deviation of `mᵀm` from the identity: 0 for a rotation (or reflection).
pub fn orthonormality_error(m: &Mat3) -> f32 {
    let p = mat3_mul(&transpose(m), m);
    let mut e = 0.0f32;
    for (i, row) in p.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            e = e.max((v - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    e
}

/// Unit quaternion `[w, x, y, z]` of a rotation matrix (Shepperd's method, stable near 180°).
pub fn quat_from_mat3(m: &Mat3) -> [f32; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    q.map(|v| v / n)
}

/// Rotation matrix of a unit quaternion `[w, x, y, z]`.
pub fn mat3_from_quat(q: [f32; 4]) -> Mat3 {
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Spherical linear interpolation between unit quaternions, along the shorter arc.
pub fn slerp(a: [f32; 4], b: [f32; 4], t: f32) -> [f32; 4] {
    let mut d: f32 = (0..4).map(|i| a[i] * b[i]).sum();
    let b = if d < 0.0 {
        d = -d;
        b.map(|v| -v)
    } else {
        b
    };
    let (wa, wb) = if d > 0.9995 {
        (1.0 - t, t)
    } else {
        let th = d.clamp(-1.0, 1.0).acos();
        let s = th.sin();
        (((1.0 - t) * th).sin() / s, (t * th).sin() / s)
    };
    let q: [f32; 4] = std::array::from_fn(|i| wa * a[i] + wb * b[i]);
    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    q.map(|v| v / n)
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
            Bounds::Aabb { min, max } => scale(add(min, max), 0.5),
        }
    }

    /// Whether `p` lies inside (or on) the volume.
    pub fn contains(&self, p: Vec3) -> bool {
        match *self {
            Bounds::Sphere { center, radius } => norm(sub(p, center)) <= radius,
            Bounds::Aabb { min, max } => (0..3).all(|i| p[i] >= min[i] && p[i] <= max[i]),
        }
    }

    /// Parameter interval `[t0, t1]` (t0 may be negative when the origin is inside) where the
    /// ray `o + t·d` is inside the volume, or `None` when it misses. `d` need not be unit.
    pub fn intersect(&self, o: Vec3, d: Vec3) -> Option<(f32, f32)> {
        match *self {
            Bounds::Sphere { center, radius } => {
                let oc = sub(o, center);
                let a = dot(d, d);
                let b = dot(oc, d);
                let c = dot(oc, oc) - radius * radius;
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
                    [
                        if i & 1 == 0 { min[0] } else { max[0] },
                        if i & 2 == 0 { min[1] } else { max[1] },
                        if i & 4 == 0 { min[2] } else { max[2] },
                    ]
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
                        let mut p = [0.0; 3];
                        p[(axis + 1) % 3] = c * radius;
                        p[(axis + 2) % 3] = s * radius;
                        add(center, p)
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

/// A similarity transform `p ↦ scale · R p + t` (rotation, uniform scale, translation).
///
/// Loaders that move the data into a normalized frame (LLFF recentring and rescaling, DTU's
/// `scale_mat`) record the map from the dataset's own world frame to the scene frame here, so
/// points known in the source frame can be checked against the scene's rays.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Similarity {
    /// Uniform scale: a distance `d` in the source frame is `scale · d` in the scene frame.
    pub scale: f32,
    /// Rotation, row major.
    pub rotation: Mat3,
    /// Translation.
    pub translation: Vec3,
}

impl Similarity {
    /// The identity map.
    pub fn identity() -> Self {
        Similarity {
            scale: 1.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    }

    /// Maps a point.
    pub fn apply_point(&self, p: Vec3) -> Vec3 {
        add(
            scale(mat3_mul_vec(&self.rotation, p), self.scale),
            self.translation,
        )
    }

    /// Maps a direction (rotation only, no scale).
    pub fn apply_direction(&self, d: Vec3) -> Vec3 {
        mat3_mul_vec(&self.rotation, d)
    }

    /// Builds one from a 3×4 affine matrix `[A | t]` whose `A` is a scaled rotation; `None`
    /// when `A` is singular or not a similarity (tolerance 1e-3 relative).
    pub fn from_affine(m: &[[f64; 4]; 3]) -> Option<Self> {
        let a = [
            [m[0][0], m[0][1], m[0][2]],
            [m[1][0], m[1][1], m[1][2]],
            [m[2][0], m[2][1], m[2][2]],
        ];
        let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
        if !det.is_finite() || det <= 0.0 {
            return None;
        }
        let s = det.cbrt();
        let rot: Mat3 = a.map(|r| r.map(|v| (v / s) as f32));
        if orthonormality_error(&rot) > 1e-3 {
            return None;
        }
        Some(Similarity {
            scale: s as f32,
            rotation: rot,
            translation: [m[0][3] as f32, m[1][3] as f32, m[2][3] as f32],
        })
    }
}
