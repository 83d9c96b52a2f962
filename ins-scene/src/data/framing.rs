//! Choosing the scene frame of a real capture: where its centre is, how large it is, which way
//! is up, how far rays go, and whether it is forward-facing (rendered in NDC, as LLFF) or taken
//! around its subject (rendered in a box that holds the subject and the background the sparse
//! points show, instant-ngp's enlarged `aabb_scale` box).
//!
//! The LLFF loader and the COLMAP / transforms.json loaders share the forward-facing frame, so a
//! forward-facing capture read from COLMAP lands in the same frame as its `poses_bounds.npy`.

use crate::stats::percentile;
use glam::{DMat3, DQuat, DVec3};

use super::scene::View;
use crate::geometry::{Bounds, Contraction, Similarity, Vec3};

/// A camera-to-world pose `[R | t]` in f64, OpenGL axes.
pub type Pose = [[f64; 4]; 3];

/// Cameras whose viewing directions all lie within this angle of their mean are
/// forward-facing (LLFF captures stay within ~15°; turntables and DTU's arc go well past it).
pub const FORWARD_FACING_MAX_ANGLE_DEG: f64 = 30.0;
/// Object-centred captures are scaled so their cameras sit this far from the centre on
/// average: the NeRF-synthetic geometry (lego's cameras are at radius 4.03).
pub const CAMERA_RADIUS: f64 = 4.0;
/// Half side of the box that holds the subject at `aabb_scale` 1 (the NeRF-synthetic box).
pub const UNIT_HALF_EXTENT: f64 = 1.5;
/// Share of the sparse points the chosen box must hold.
pub const POINT_COVERAGE: f64 = 0.95;
/// The `aabb_scale` of an object-centred capture without sparse points or a stated one: a box
/// of half side 6, the cameras (at radius 4) inside it (see [`object_centred`]).
pub const DEFAULT_AABB_SCALE: u32 = 4;
/// How far rays of a contracted scene run, in contraction radii: the contracted distance left
/// beyond is 1/1000 of the radius.
pub const CONTRACTED_FAR: f32 = 1000.0;

/// The frame a capture was put in, and how its rays are bounded.
#[derive(Clone, Debug)]
pub struct Framing {
    /// Map from the capture's world frame to the scene frame.
    pub to_scene: Similarity,
    /// The cameras in the scene frame.
    pub poses: Vec<[[f32; 4]; 3]>,
    /// Rendered in NDC (LLFF style).
    pub forward_facing: bool,
    /// Per-view depth bounds in the scene frame (forward-facing), from the sparse points.
    pub depth_ranges: Vec<Option<(f32, f32)>>,
    /// Object-centred: the box's `aabb_scale` (half side `1.5 · aabb_scale`).
    pub aabb_scale: Option<u32>,
    /// Object-centred with background past the cameras: the contraction.
    pub contraction: Option<Contraction>,
}

fn column(p: &Pose, c: usize) -> DVec3 {
    DVec3::new(p[0][c], p[1][c], p[2][c])
}

/// Whether the cameras look the same way, within [`FORWARD_FACING_MAX_ANGLE_DEG`].
pub fn is_forward_facing(poses: &[Pose]) -> bool {
    let fwd: Vec<DVec3> = poses
        .iter()
        .map(|p| -column(p, 2).normalize_or_zero())
        .collect();
    let mean = fwd.iter().sum::<DVec3>().normalize_or_zero();
    let cos_max = FORWARD_FACING_MAX_ANGLE_DEG.to_radians().cos();
    mean != DVec3::ZERO && fwd.iter().all(|f| f.dot(mean) >= cos_max)
}

/// NeRF's `poses_avg`: mean centre, summed back and up axes, re-orthonormalized.
pub fn average_pose(poses: &[Pose]) -> Pose {
    let n = poses.len().max(1) as f64;
    let center = poses.iter().map(|p| column(p, 3)).sum::<DVec3>() / n;
    let back = poses.iter().map(|p| column(p, 2)).sum::<DVec3>();
    let up = poses.iter().map(|p| column(p, 1)).sum::<DVec3>();
    let z = back.normalize_or_zero();
    let x = up.cross(z).normalize_or_zero();
    let y = z.cross(x).normalize_or_zero();
    let mut out = [[0.0; 4]; 3];
    for r in 0..3 {
        out[r] = [x[r], y[r], z[r], center[r]];
    }
    out
}

/// NeRF's `load_llff_data` frame: positions and depth bounds rescaled so the nearest bound
/// becomes `1 / bd_factor`, then poses recentred on their average pose. Returns the framing
/// and the scale applied (the bounds multiply by it). `bounds` must be positive.
pub fn forward_facing(poses: &[Pose], bounds: &[(f64, f64)], bd_factor: f64) -> (Framing, f64) {
    let min_bd = bounds.iter().map(|b| b.0).fold(f64::INFINITY, f64::min);
    let sc = 1.0 / (min_bd * bd_factor);
    let scaled: Vec<Pose> = poses
        .iter()
        .map(|p| p.map(|r| [r[0], r[1], r[2], r[3] * sc]))
        .collect();
    let avg = average_pose(&scaled);
    let rot_t = DMat3::from_cols(column(&avg, 0), column(&avg, 1), column(&avg, 2)).transpose();
    let c = column(&avg, 3);
    let to_scene = Similarity {
        scale: sc as f32,
        rotation: rot_t.as_mat3(),
        translation: (-(rot_t * c)).as_vec3(),
    };
    let poses = scaled
        .iter()
        .map(|p| transform_pose(p, rot_t, -(rot_t * c), 1.0))
        .collect();
    let depth_ranges = bounds
        .iter()
        .map(|&(n, f)| Some(((n * sc) as f32, (f * sc) as f32)))
        .collect();
    (
        Framing {
            to_scene,
            poses,
            forward_facing: true,
            depth_ranges,
            aabb_scale: None,
            contraction: None,
        },
        sc,
    )
}

/// `c2w ↦ [R·Rc | s·R·t + shift]`: a pose moved by the similarity `p ↦ s·R p + shift`.
fn transform_pose(p: &Pose, r: DMat3, shift: DVec3, s: f64) -> [[f32; 4]; 3] {
    let rc = DMat3::from_cols(column(p, 0), column(p, 1), column(p, 2));
    let rot = r * rc;
    let t = s * (r * column(p, 3)) + shift;
    let mut out = [[0.0f32; 4]; 3];
    for (row, o) in out.iter_mut().enumerate() {
        *o = [
            rot.col(0)[row] as f32,
            rot.col(1)[row] as f32,
            rot.col(2)[row] as f32,
            t[row] as f32,
        ];
    }
    out
}

/// The point closest to every camera's optical axis (least squares): what an object-centred
/// capture looks at. `None` when the axes are near parallel.
pub fn focus_point(poses: &[Pose]) -> Option<DVec3> {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for p in poses {
        let d = column(p, 2).normalize_or_zero();
        let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * column(p, 3);
    }
    let det = a.determinant();
    let scale = (poses.len() as f64).powi(3);
    (det.is_finite() && det.abs() > 1e-6 * scale).then(|| a.inverse() * b)
}

/// Per-view z-depth bounds from the sparse points each view sees (LLFF's `imgs2poses`: the
/// 0.1 and 99.9 percentiles), falling back to all points in front of the view; `None` for a view
/// with no point in front of it.
pub fn depth_bounds(
    poses: &[Pose],
    points: &[DVec3],
    visible: &[Vec<usize>],
) -> Vec<Option<(f64, f64)>> {
    poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let o = column(p, 3);
            let fwd = -column(p, 2).normalize_or_zero();
            let depth = |&j: &usize| points.get(j).map(|q| (*q - o).dot(fwd));
            let mut z: Vec<f64> = visible
                .get(i)
                .map(|v| v.iter().filter_map(depth).filter(|&z| z > 0.0).collect())
                .unwrap_or_default();
            if z.len() < 8 {
                z = (0..points.len())
                    .filter_map(|j| depth(&j))
                    .filter(|&z| z > 0.0)
                    .collect();
            }
            if z.is_empty() {
                return None;
            }
            z.sort_by(f64::total_cmp);
            Some((percentile(&z, 0.001), percentile(&z, 0.999)))
        })
        .collect()
}

/// The frame of an object-centred capture: centred on the [`focus_point`] (the cameras' mean
/// position when their axes do not meet), the cameras' mean up turned to +z, scaled so the
/// cameras sit at [`CAMERA_RADIUS`] on average. Its extent: a stated `aabb_scale` is kept as
/// instant-ngp's box; sparse points that stay well inside the cameras' sphere (an object on a
/// table, before a backdrop SfM finds nothing on) get the smallest power-of-two box holding
/// [`POINT_COVERAGE`] of them, and the NeRF trainer learns the backdrop as one colour; points
/// that reach the cameras or pass them (a room, a street) contract space beyond the cameras'
/// radius ([`Contraction`]), as mip-NeRF 360 does; with no points to tell, the box of
/// [`DEFAULT_AABB_SCALE`] holds the cameras and some room past them (on a room capture as good
/// as the contraction, on a plain backdrop far better: see docs/measurements.md).
pub fn object_centred(poses: &[Pose], points: &[DVec3], aabb_scale: Option<u32>) -> Framing {
    let n = poses.len().max(1) as f64;
    let mean = poses.iter().map(|p| column(p, 3)).sum::<DVec3>() / n;
    let centre = focus_point(poses).unwrap_or(mean);
    let up = poses
        .iter()
        .map(|p| column(p, 1))
        .sum::<DVec3>()
        .normalize_or(DVec3::Z);
    let r = DMat3::from_quat(DQuat::from_rotation_arc(up, DVec3::Z));
    let radius = poses
        .iter()
        .map(|p| (column(p, 3) - centre).length())
        .sum::<f64>()
        / n;
    let s = if radius > 1e-12 {
        CAMERA_RADIUS / radius
    } else {
        1.0
    };
    let shift = -s * (r * centre);
    let stated = aabb_scale.is_some();
    let aabb_scale = aabb_scale.unwrap_or_else(|| {
        if points.is_empty() {
            return DEFAULT_AABB_SCALE;
        }
        let mut extent: Vec<f64> = points
            .iter()
            .map(|q| (s * (r * *q) + shift).abs().max_element())
            .collect();
        extent.sort_by(f64::total_cmp);
        aabb_scale_holding(percentile(&extent, POINT_COVERAGE))
    });
    let past_cameras =
        !points.is_empty() && f64::from(aabb_scale) * UNIT_HALF_EXTENT >= CAMERA_RADIUS;
    Framing {
        to_scene: Similarity {
            scale: s as f32,
            rotation: r.as_mat3(),
            translation: shift.as_vec3(),
        },
        poses: poses
            .iter()
            .map(|p| transform_pose(p, r, shift, s))
            .collect(),
        forward_facing: false,
        depth_ranges: vec![None; poses.len()],
        aabb_scale: Some(aabb_scale),
        contraction: (!stated && past_cameras).then_some(Contraction {
            radius: CAMERA_RADIUS as f32,
        }),
    }
}

/// The smallest power-of-two `aabb_scale` (up to 64) whose box has half side `half` or more.
pub fn aabb_scale_holding(half: f64) -> u32 {
    let need = half / UNIT_HALF_EXTENT;
    let mut k = 1u32;
    while (k as f64) < need && k < 64 {
        k *= 2;
    }
    k
}

/// Share of the views a point must be in frame of to count as kept in view: most, not all, so
/// that a few close-ups do not cut the subject.
pub const SHARED_VIEW_SHARE: f32 = 0.9;
/// Cells per side of the grid [`shared_view_half_extent`] searches.
pub const SHARED_VIEW_RESOLUTION: usize = 64;

/// Half side of the smallest origin-centred box holding every point that
/// [`SHARED_VIEW_SHARE`] of the views keep in frame, searched on a grid over the box of half
/// side `reach`; `None` when no point is (cameras looking outwards, a walk-through). A capture
/// that shows its whole subject in each photo holds it there: for lego's hemisphere of 40°
/// views at 4 units, a region of half side about 1.2 (the object's own box is 1.5).
pub fn shared_view_half_extent(views: &[View], reach: f32) -> Option<f32> {
    use rayon::prelude::*;
    let n = SHARED_VIEW_RESOLUTION;
    let cell = 2.0 * reach / n as f32;
    let need = ((views.len() as f32 * SHARED_VIEW_SHARE).ceil() as usize).max(1);
    (0..n * n * n)
        .into_par_iter()
        .filter_map(|i| {
            let idx = Vec3::new((i % n) as f32, ((i / n) % n) as f32, (i / (n * n)) as f32);
            let p = Vec3::splat(-reach) + (idx + 0.5) * cell;
            let seen = views
                .iter()
                .filter(|v| v.camera.project(p).is_some_and(|q| v.camera.in_frame(q)))
                .count();
            (seen >= need).then(|| p.abs().max_element() + 0.5 * cell)
        })
        .reduce_with(f32::max)
}

/// The box of an object-centred framing: half side `1.5 · aabb_scale` around the origin.
pub fn aabb_bounds(aabb_scale: u32) -> Bounds {
    let h = (UNIT_HALF_EXTENT * aabb_scale as f64) as f32;
    Bounds::Aabb {
        min: Vec3::splat(-h),
        max: Vec3::splat(h),
    }
}

/// Box around every view's frustum between its near and far depth bounds: the region the
/// views actually see.
pub fn frustum_bounds(views: &[View]) -> Bounds {
    let mut min = Vec3::INFINITY;
    let mut max = Vec3::NEG_INFINITY;
    for v in views {
        let c = &v.camera;
        let (near, far) = v.depth_range.unwrap_or((1.0, 1.0));
        for depth in [near, far] {
            for (x, y) in [
                (0.0, 0.0),
                (c.width as f32, 0.0),
                (0.0, c.height as f32),
                (c.width as f32, c.height as f32),
            ] {
                let p = c.origin() + c.rotation() * c.direction_camera(x, y) * depth;
                min = min.min(p);
                max = max.max(p);
            }
        }
    }
    Bounds::Aabb { min, max }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::pose_look_at;

    fn f64_pose(p: [[f32; 4]; 3]) -> Pose {
        p.map(|r| r.map(f64::from))
    }

    fn ring(n: usize, radius: f32, centre: Vec3) -> Vec<Pose> {
        (0..n)
            .map(|i| {
                let a = i as f32 / n as f32 * std::f32::consts::TAU;
                let eye = centre + Vec3::new(radius * a.cos(), radius * a.sin(), 0.5 * radius);
                f64_pose(pose_look_at(eye, centre, Vec3::Z))
            })
            .collect()
    }

    #[test]
    fn a_turntable_is_centred_scaled_and_not_forward_facing() {
        let centre = Vec3::new(3.0, -2.0, 1.0);
        let poses = ring(12, 10.0, centre);
        assert!(!is_forward_facing(&poses));
        let f = focus_point(&poses).unwrap();
        assert!((f.as_vec3() - centre).length() < 1e-4, "{f}");
        let framing = object_centred(&poses, &[], None);
        let r = framing
            .poses
            .iter()
            .map(|p| Vec3::new(p[0][3], p[1][3], p[2][3]).length())
            .sum::<f32>()
            / 12.0;
        assert!((r - CAMERA_RADIUS as f32).abs() < 1e-4, "{r}");
        assert_eq!(framing.aabb_scale, Some(DEFAULT_AABB_SCALE));
        // The map takes the capture's centre to the origin.
        assert!(framing.to_scene.apply_point(centre).length() < 1e-4);
    }

    #[test]
    fn forward_facing_cameras_are_detected() {
        let poses: Vec<Pose> = (0..9)
            .map(|i| {
                let eye = Vec3::new((i % 3) as f32 * 0.2, (i / 3) as f32 * 0.2, 0.0);
                f64_pose(pose_look_at(eye, eye + Vec3::new(0.05, 0.0, -1.0), Vec3::Y))
            })
            .collect();
        assert!(is_forward_facing(&poses));
        assert!(focus_point(&poses).is_none() || is_forward_facing(&poses));
    }

    /// Views of 32×24 pixels with a 40° horizontal field of view from `eyes`, looking at
    /// `target(eye)`.
    fn views(eyes: &[Vec3], target: impl Fn(Vec3) -> Vec3) -> Vec<View> {
        let focal = 16.0 / (20f32).to_radians().tan();
        eyes.iter()
            .map(|&eye| View {
                camera: crate::camera::Camera::look_at(32, 24, focal, eye, target(eye), Vec3::Z),
                image: crate::data::images::Image::from_f32(32, 24, &[0.5; 32 * 24 * 3]),
                mask: None,
                path: "v.png".into(),
                mask_path: None,
                depth_range: None,
            })
            .collect()
    }

    #[test]
    fn the_photos_share_the_region_around_what_they_look_at() {
        let eyes: Vec<Vec3> = ring(16, 4.0, Vec3::ZERO)
            .iter()
            .map(|p| Vec3::new(p[0][3] as f32, p[1][3] as f32, p[2][3] as f32))
            .collect();
        let inward = shared_view_half_extent(&views(&eyes, |_| Vec3::ZERO), 6.0).unwrap();
        // 40° across, the cameras 4.5 away: 1.6 either side of the centre, less towards them.
        assert!((0.8..1.8).contains(&inward), "{inward}");
        // Looking outwards (a walk around a room's walls), no point is in most photos.
        assert_eq!(
            shared_view_half_extent(&views(&eyes, |e| 2.0 * e), 6.0),
            None
        );
    }

    #[test]
    fn boxes_come_in_powers_of_two() {
        let k: Vec<u32> = [0.1, 1.5, 1.51, 3.0, 6.0, 6.1, 1e6]
            .into_iter()
            .map(aabb_scale_holding)
            .collect();
        assert_eq!(k, [1, 1, 2, 2, 4, 8, 64]);
    }

    #[test]
    fn the_box_grows_to_hold_the_points() {
        let poses = ring(8, 4.0, Vec3::ZERO);
        let near: Vec<DVec3> = (0..100).map(|i| DVec3::splat(i as f64 * 0.01)).collect();
        let object = object_centred(&poses, &near, None);
        assert_eq!(object.aabb_scale, Some(1));
        assert_eq!(
            object.contraction, None,
            "an object inside the cameras gets a box"
        );
        let far: Vec<DVec3> = (0..100)
            .map(|i| DVec3::new(5.0 + i as f64 * 0.01, 0.0, 0.0))
            .collect();
        let room = object_centred(&poses, &far, None);
        assert_eq!(room.aabb_scale, Some(4));
        assert!(
            room.contraction.is_some(),
            "points past the cameras are contracted"
        );
        let unknown = object_centred(&poses, &[], None);
        assert_eq!(unknown.aabb_scale, Some(DEFAULT_AABB_SCALE));
        assert_eq!(
            unknown.contraction, None,
            "without points, a box holding the cameras"
        );
        let stated = object_centred(&poses, &far, Some(2));
        assert_eq!(stated.aabb_scale, Some(2));
        assert_eq!(stated.contraction, None);
    }
}
