//! Render paths: a turntable around 360° scenes, the LLFF spiral for forward-facing scenes, and
//! smooth interpolation between given cameras.

use super::camera::{Camera, pose_from_back_up, pose_look_at};
use super::geometry::{Mat3, Quat, Vec3, mat3_rows};
use crate::data::Scene;

/// `n` cameras on a circle around `center`: distance `radius`, elevation `elevation` (radians,
/// above the plane perpendicular to `up`), all looking at `center`, starting at azimuth
/// `start` (radians, measured in that plane). Intrinsics and image size come from `template`.
pub fn turntable(
    center: Vec3,
    up: Vec3,
    radius: f32,
    elevation: f32,
    start: f32,
    n: usize,
    template: &Camera,
) -> Vec<Camera> {
    let up = up.normalize_or_zero();
    let (e1, e2) = plane_basis(up);
    (0..n)
        .map(|k| {
            let az = start + k as f32 / n as f32 * std::f32::consts::TAU;
            let horizontal = e1 * az.cos() + e2 * az.sin();
            let dir = horizontal * elevation.cos() + up * elevation.sin();
            let eye = center + dir * radius;
            Camera {
                c2w: pose_look_at(eye, center, up),
                ..template.pinhole()
            }
        })
        .collect()
}

/// The scene's up direction: the mean up vector of its training cameras (zero without any).
pub fn scene_up(scene: &Scene) -> Vec3 {
    scene
        .split(crate::data::Split::Train)
        .iter()
        .map(|&i| scene.views[i].camera.up())
        .sum::<Vec3>()
        .normalize_or_zero()
}

/// How a scene's training cameras circle it: around the bounding volume's centre, their mean up
/// vector, mean distance and mean elevation (radians), and the first camera's azimuth (radians,
/// in [`plane_basis`]`(up)`).
#[derive(Clone, Copy, Debug)]
pub struct SceneOrbit {
    pub center: Vec3,
    pub up: Vec3,
    pub radius: f32,
    pub elevation: f32,
    pub start: f32,
}

/// The orbit of `scene`'s training cameras and the first of them; `None` without any.
pub fn scene_orbit(scene: &Scene) -> Option<(SceneOrbit, &Camera)> {
    let cams: Vec<&Camera> = scene
        .split(crate::data::Split::Train)
        .iter()
        .map(|&i| &scene.views[i].camera)
        .collect();
    let first = *cams.first()?;
    let center = scene.bounds.center();
    let up = scene_up(scene);
    let mut radius = 0.0;
    let mut elevation = 0.0;
    for c in &cams {
        let v = c.origin() - center;
        radius += v.length();
        elevation += v.normalize_or_zero().dot(up).clamp(-1.0, 1.0).asin();
    }
    radius /= cams.len() as f32;
    elevation /= cams.len() as f32;
    let (e1, e2) = plane_basis(up);
    let v = first.origin() - center;
    let start = v.dot(e2).atan2(v.dot(e1));
    let orbit = SceneOrbit {
        center,
        up,
        radius,
        elevation,
        start,
    };
    Some((orbit, first))
}

/// A turntable fitted to a scene's training cameras ([`scene_orbit`]). `None` when the scene
/// has no training views.
pub fn turntable_for_scene(scene: &Scene, n: usize) -> Option<Vec<Camera>> {
    let (o, first) = scene_orbit(scene)?;
    Some(turntable(
        o.center,
        o.up,
        o.radius,
        o.elevation,
        o.start,
        n,
        first,
    ))
}

/// The path a scene is shown along by default ([`default_kind`]) with `n` frames; `None`
/// without views.
pub fn default_path(scene: &Scene, n: usize) -> Option<Vec<Camera>> {
    match default_kind(scene) {
        "spiral" => spiral_for_scene(scene, n),
        _ => turntable_for_scene(scene, n),
    }
}

/// The LLFF / NeRF spiral (`render_path_spiral`) around the average of `cameras`: `rots` turns
/// over `n` frames; the cameras circle with radii given by the 90th percentile of the absolute
/// camera positions, bob along the viewing axis at half the rate, and all look at the point at
/// the "mean focus depth" `1 / (0.25/(0.9·min_depth) + 0.75/(5·max_depth))` in front of the
/// average camera. `min_depth`/`max_depth` are the scene's depth bounds in the same frame.
pub fn spiral(
    cameras: &[Camera],
    min_depth: f32,
    max_depth: f32,
    n: usize,
    rots: f32,
) -> Vec<Camera> {
    let Some(template) = cameras.first() else {
        return Vec::new();
    };
    let up = cameras
        .iter()
        .map(|c| c.up())
        .sum::<Vec3>()
        .normalize_or_zero();
    let (center, rot, rads, focus) = spiral_geometry(cameras, min_depth, max_depth);
    (0..n)
        .map(|k| {
            let theta = k as f32 / n as f32 * std::f32::consts::TAU * rots;
            let local = Vec3::new(
                theta.cos() * rads[0],
                -theta.sin() * rads[1],
                -(theta * 0.5).sin() * rads[2],
            );
            let c = center + rot * local;
            let back = (c - focus).normalize_or_zero();
            Camera {
                c2w: pose_from_back_up(back, up, c),
                ..template.pinhole()
            }
        })
        .collect()
}

/// The spiral's frame: the average camera's centre and rotation, the radii (90th percentile of
/// the absolute camera positions along each axis) and the focus point.
fn spiral_geometry(
    cameras: &[Camera],
    min_depth: f32,
    max_depth: f32,
) -> (Vec3, Mat3, [f32; 3], Vec3) {
    let avg = average_pose(cameras);
    let close = min_depth * 0.9;
    let inf = max_depth * 5.0;
    let dt = 0.75;
    let focal = 1.0 / ((1.0 - dt) / close + dt / inf);
    let rads: [f32; 3] = std::array::from_fn(|k| {
        percentile(cameras.iter().map(|c| c.origin()[k].abs()).collect(), 90.0)
    });
    let rot = super::geometry::mat3_from_rows(avg.map(|r| [r[0], r[1], r[2]]));
    let center = Vec3::new(avg[0][3], avg[1][3], avg[2][3]);
    let focus = center + rot * Vec3::new(0.0, 0.0, -focal);
    (center, rot, rads, focus)
}

/// The spiral frame of a scene (all its views, its depth range), as [`spiral_for_scene`] uses
/// it; `None` without views.
pub fn spiral_frame(scene: &Scene) -> Option<(Vec3, Mat3, [f32; 3], Vec3)> {
    let cams: Vec<Camera> = scene.views.iter().map(|v| v.camera.clone()).collect();
    if cams.is_empty() {
        return None;
    }
    let (lo, hi) = depth_range(scene);
    Some(spiral_geometry(&cams, lo, hi))
}

fn depth_range(scene: &Scene) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for v in &scene.views {
        let (a, b) = v.depth_range.unwrap_or((scene.near, scene.far));
        lo = lo.min(a);
        hi = hi.max(b);
    }
    (lo, hi)
}

/// The LLFF spiral for a scene (all its views, its per-view depth bounds), two turns; `None`
/// when the scene has no views.
pub fn spiral_for_scene(scene: &Scene, n: usize) -> Option<Vec<Camera>> {
    let cams: Vec<Camera> = scene.views.iter().map(|v| v.camera.clone()).collect();
    if cams.is_empty() {
        return None;
    }
    let (lo, hi) = depth_range(scene);
    Some(spiral(&cams, lo, hi, n, 2.0))
}

/// The path a scene is shown along when none is asked for: `"spiral"` for forward-facing
/// scenes (LLFF, forward captures), `"turntable"` for the others.
pub fn default_kind(scene: &Scene) -> &'static str {
    if scene.forward_facing {
        "spiral"
    } else {
        "turntable"
    }
}

/// The LLFF `poses_avg`: centre = mean position, back axis = normalized sum of back axes, up =
/// sum of up axes, re-orthonormalized.
pub fn average_pose(cameras: &[Camera]) -> [[f32; 4]; 3] {
    let n = cameras.len().max(1) as f32;
    let center = cameras.iter().map(|c| c.origin()).sum::<Vec3>() / n;
    let back = -cameras.iter().map(|c| c.forward()).sum::<Vec3>();
    let up = cameras.iter().map(|c| c.up()).sum::<Vec3>();
    pose_from_back_up(back, up, center)
}

/// Smooth path through key cameras: `per_segment` frames from each key to the next (the key
/// itself, then rotation by slerp, position and intrinsics linearly), then the last key.
pub fn interpolate(keys: &[Camera], per_segment: usize) -> Vec<Camera> {
    let mut out = Vec::new();
    for pair in keys.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        let (qa, qb) = (
            Quat::from_mat3(&a.rotation()).normalize(),
            Quat::from_mat3(&b.rotation()).normalize(),
        );
        out.push(a.pinhole());
        for k in 1..per_segment.max(1) {
            let t = k as f32 / per_segment.max(1) as f32;
            let r = mat3_rows(Mat3::from_quat(qa.slerp(qb, t)));
            let p = a.origin().lerp(b.origin(), t);
            let mix = |x: f32, y: f32| x + (y - x) * t;
            out.push(Camera {
                width: a.width,
                height: a.height,
                fx: mix(a.fx, b.fx),
                fy: mix(a.fy, b.fy),
                cx: mix(a.cx, b.cx),
                cy: mix(a.cy, b.cy),
                skew: mix(a.skew, b.skew),
                c2w: [
                    [r[0][0], r[0][1], r[0][2], p[0]],
                    [r[1][0], r[1][1], r[1][2], p[1]],
                    [r[2][0], r[2][1], r[2][2], p[2]],
                ],
                distortion: Default::default(),
            });
        }
    }
    if let Some(last) = keys.last() {
        out.push(last.pinhole());
    }
    out
}

/// Two unit vectors spanning the plane perpendicular to unit vector `up`.
pub fn plane_basis(up: Vec3) -> (Vec3, Vec3) {
    let helper = if up.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let e1 = up.cross(helper).normalize_or_zero();
    let e2 = up.cross(e1);
    (e1, e2)
}

/// Percentile with linear interpolation (NumPy's default).
fn percentile(mut v: Vec<f32>, q: f32) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let pos = q / 100.0 * (v.len() - 1) as f32;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f32)
}
