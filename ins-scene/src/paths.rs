//! Render paths: a turntable around 360° scenes, an arc over the side a partial capture saw
//! (DTU's, a photographed object), the LLFF spiral for forward-facing scenes, and smooth
//! interpolation between given cameras.

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
    let azimuths = (0..n).map(|k| start + k as f32 / n as f32 * std::f32::consts::TAU);
    orbit_cameras(center, up, radius, elevation, azimuths, template)
}

/// Cameras at azimuths `azimuths` (radians) of a circle around `center` (see [`turntable`]),
/// looking at it.
fn orbit_cameras(
    center: Vec3,
    up: Vec3,
    radius: f32,
    elevation: f32,
    azimuths: impl Iterator<Item = f32>,
    template: &Camera,
) -> Vec<Camera> {
    let up = up.normalize_or_zero();
    let (e1, e2) = plane_basis(up);
    azimuths
        .map(|az| {
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

/// A capture whose cameras leave a gap of at least this much azimuth (radians, 90°) unseen is
/// shown along an [`arc`] over the side it saw: a turntable would spend its frames on a side
/// no photo constrains (DTU's captures span about 100°).
pub const ARC_MIN_GAP: f32 = std::f32::consts::FRAC_PI_2;

/// The arc of azimuths `azimuths` (radians, any order and range) cover: `(start, span)` with
/// the arc from `start` counter-clockwise over `span`, the complement of the widest gap
/// between neighbours; `None` when that gap is under `min_gap` (cameras all around) or there
/// are no azimuths.
pub fn covered_arc(azimuths: &[f32], min_gap: f32) -> Option<(f32, f32)> {
    let tau = std::f32::consts::TAU;
    let mut a: Vec<f32> = azimuths.iter().map(|x| x.rem_euclid(tau)).collect();
    a.sort_by(|x, y| x.total_cmp(y));
    let (first, last) = (*a.first()?, *a.last()?);
    // The gap after each azimuth, the last one wrapping round to the first.
    let (mut gap, mut after) = (first + tau - last, last);
    for w in a.windows(2) {
        if w[1] - w[0] > gap {
            (gap, after) = (w[1] - w[0], w[0]);
        }
    }
    (gap >= min_gap).then(|| ((after + gap).rem_euclid(tau), tau - gap))
}

/// `n` cameras sweeping the arc `(start, span)` of a circle (see [`turntable`]) there and back,
/// easing at its ends, so that the path loops: azimuth `start + span·(1 − cos 2πk/n)/2`.
pub fn arc(
    center: Vec3,
    up: Vec3,
    radius: f32,
    elevation: f32,
    (start, span): (f32, f32),
    n: usize,
    template: &Camera,
) -> Vec<Camera> {
    let tau = std::f32::consts::TAU;
    let azimuths =
        (0..n).map(move |k| start + span * 0.5 * (1.0 - (tau * k as f32 / n as f32).cos()));
    orbit_cameras(center, up, radius, elevation, azimuths, template)
}

/// The azimuths (radians, in [`plane_basis`]`(orbit.up)`) of a scene's training cameras.
fn camera_azimuths(scene: &Scene, orbit: &SceneOrbit) -> Vec<f32> {
    let (e1, e2) = plane_basis(orbit.up);
    scene
        .split(crate::data::Split::Train)
        .iter()
        .map(|&i| {
            let v = scene.views[i].camera.origin() - orbit.center;
            v.dot(e2).atan2(v.dot(e1))
        })
        .collect()
}

/// The elevation (radians) of the direction `v` above the plane perpendicular to `up`.
fn elevation(v: Vec3, up: Vec3) -> f32 {
    v.normalize_or_zero().dot(up).clamp(-1.0, 1.0).asin()
}

/// The lowest and highest elevation (radians above the plane through `orbit.center`
/// perpendicular to `orbit.up`) of `scene`'s training cameras; `None` without any.
pub fn camera_elevations(scene: &Scene, orbit: &SceneOrbit) -> Option<(f32, f32)> {
    scene
        .split(crate::data::Split::Train)
        .iter()
        .map(|&i| elevation(scene.views[i].camera.origin() - orbit.center, orbit.up))
        .fold(None, |range, e| match range {
            None => Some((e, e)),
            Some((low, high)) => Some((f32::min(low, e), f32::max(high, e))),
        })
}

/// The arc of a scene's orbit its training cameras cover, where they leave a gap of at least
/// [`ARC_MIN_GAP`]: `(start, span)` radians.
pub fn capture_arc(scene: &Scene) -> Option<(f32, f32)> {
    let (orbit, _) = scene_orbit(scene)?;
    covered_arc(&camera_azimuths(scene, &orbit), ARC_MIN_GAP)
}

/// An [`arc`] over the side of a scene its training cameras saw; the turntable when they
/// surround it. `None` without training views.
pub fn arc_for_scene(scene: &Scene, n: usize) -> Option<Vec<Camera>> {
    let (o, first) = scene_orbit(scene)?;
    let Some(covered) = covered_arc(&camera_azimuths(scene, &o), ARC_MIN_GAP) else {
        return turntable_for_scene(scene, n);
    };
    Some(arc(
        o.center,
        o.up,
        o.radius,
        o.elevation,
        covered,
        n,
        &first,
    ))
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

/// The orbit of `scene`'s training cameras and the first of them, at the size a camera path
/// shares (the first view's: [`Camera::reframed`]); `None` without any.
pub fn scene_orbit(scene: &Scene) -> Option<(SceneOrbit, Camera)> {
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
        elevation += self::elevation(v, up);
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
    let (w, h) = scene.resolution();
    Some((orbit, first.reframed(w, h)))
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
        &first,
    ))
}

/// A camera path around a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// The LLFF spiral (forward-facing scenes).
    Spiral,
    /// A full circle around the scene.
    Turntable,
    /// There and back over the side the training cameras saw ([`arc_for_scene`]).
    Arc,
}

impl PathKind {
    /// The name `--path` takes.
    pub fn name(self) -> &'static str {
        match self {
            PathKind::Spiral => "spiral",
            PathKind::Turntable => "turntable",
            PathKind::Arc => "arc",
        }
    }
}

impl std::str::FromStr for PathKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "spiral" => Ok(PathKind::Spiral),
            "turntable" => Ok(PathKind::Turntable),
            "arc" => Ok(PathKind::Arc),
            other => Err(format!(
                "unknown --path {other:?} (expected spiral, turntable or arc)"
            )),
        }
    }
}

/// The `kind` path around `scene` with `n` frames (`None`: the scene's [`default_kind`]);
/// `None` without views.
pub fn path_for_scene(scene: &Scene, kind: Option<PathKind>, n: usize) -> Option<Vec<Camera>> {
    match kind.unwrap_or_else(|| default_kind(scene)) {
        PathKind::Spiral => spiral_for_scene(scene, n),
        PathKind::Turntable => turntable_for_scene(scene, n),
        PathKind::Arc => arc_for_scene(scene, n),
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
        let distances = cameras
            .iter()
            .map(|c| f64::from(c.origin()[k].abs()))
            .collect();
        crate::stats::percentile_of(distances, 0.9) as f32
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

/// The path a scene is shown along when none is asked for: the spiral for forward-facing
/// scenes (LLFF, forward captures), an arc over the side a partial capture saw (DTU), the
/// turntable for scenes photographed all around (NeRF-synthetic).
pub fn default_kind(scene: &Scene) -> PathKind {
    if scene.forward_facing {
        PathKind::Spiral
    } else if capture_arc(scene).is_some() {
        PathKind::Arc
    } else {
        PathKind::Turntable
    }
}

/// The LLFF `poses_avg`: centre = mean position, back axis = normalized sum of back axes, up =
/// sum of up axes, re-orthonormalized.
pub fn average_pose(cameras: &[Camera]) -> [[f32; 4]; 3] {
    let poses: Vec<_> = cameras
        .iter()
        .map(|c| c.c2w.map(|r| r.map(f64::from)))
        .collect();
    crate::data::framing::average_pose(&poses).map(|r| r.map(|v| v as f32))
}

/// Smooth path through key cameras: `per_segment` frames from each key to the next (the key
/// itself, then rotation by slerp, position and intrinsics linearly), then the last key. Every
/// frame has the first key's size (keys of other sizes are [`Camera::reframed`] to it).
pub fn interpolate(keys: &[Camera], per_segment: usize) -> Vec<Camera> {
    let keys: Vec<Camera> = match keys.first() {
        Some(k0) => keys
            .iter()
            .map(|k| k.reframed(k0.width, k0.height))
            .collect(),
        None => Vec::new(),
    };
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_covered_arc_is_the_complement_of_the_widest_gap() {
        let deg = |d: f32| d.to_radians();
        // Cameras from −50° to 50° (given out of order, one past the wrap): 100° covered.
        let (start, span) =
            covered_arc(&[deg(10.0), deg(-50.0), deg(50.0), deg(310.0)], ARC_MIN_GAP)
                .expect("a 260° gap");
        assert!((start - deg(310.0)).abs() < 1e-5, "{}", start.to_degrees());
        assert!((span - deg(100.0)).abs() < 1e-5, "{}", span.to_degrees());
        // All around: every gap under 90°.
        let ring: Vec<f32> = (0..8).map(|k| deg(45.0 * k as f32)).collect();
        assert_eq!(covered_arc(&ring, ARC_MIN_GAP), None);
        assert_eq!(covered_arc(&[], ARC_MIN_GAP), None);
        // One camera: a gap of 360°, an arc of nothing.
        let (_, span) = covered_arc(&[deg(30.0)], ARC_MIN_GAP).unwrap();
        assert!(span.abs() < 1e-6);
    }

    #[test]
    fn a_path_through_portrait_and_landscape_photos_shares_the_first_ones_size() {
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let landscape = Camera::new(40, 30, 35.0, 35.0, 20.5, 14.5, identity);
        let mut portrait = Camera::new(30, 40, 36.0, 36.0, 15.0, 21.0, identity);
        portrait.c2w[0][3] = 1.0;
        let path = interpolate(&[landscape.clone(), portrait.clone()], 4);
        assert_eq!(path.len(), 5);
        assert!(path.iter().all(|c| (c.width, c.height) == (40, 30)));
        // The last key is the portrait view through the landscape frame: its focal length, its
        // principal point as far from the centre as in its own frame, the same principal ray.
        let last = path.last().unwrap();
        assert_eq!((last.fx, last.cx - 20.0, last.cy - 15.0), (36.0, 0.0, 1.0));
        let (a, b) = (portrait.ray(15.0, 21.0).1, last.ray(last.cx, last.cy).1);
        assert!((a - b).length() < 1e-6, "{a} {b}");
    }

    #[test]
    fn an_arc_goes_there_and_back_within_its_span() {
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let template = Camera::new(32, 32, 30.0, 30.0, 16.0, 16.0, identity);
        let (start, span) = (0.3f32, 1.2f32);
        let cams = arc(Vec3::ZERO, Vec3::Z, 2.0, 0.0, (start, span), 20, &template);
        let (e1, e2) = plane_basis(Vec3::Z);
        let az: Vec<f32> = cams
            .iter()
            .map(|c| {
                let v = c.origin();
                v.dot(e2).atan2(v.dot(e1))
            })
            .collect();
        assert!((az[0] - start).abs() < 1e-4);
        assert!(
            (az[10] - (start + span)).abs() < 1e-4,
            "the far end half way"
        );
        assert!(
            az.iter()
                .all(|&a| a >= start - 1e-4 && a <= start + span + 1e-4)
        );
        // Back the way it came: frame k and frame n − k coincide.
        assert!((az[3] - az[17]).abs() < 1e-4);
        for c in &cams {
            assert!((c.origin().length() - 2.0).abs() < 1e-4);
            assert!(
                c.forward().dot(-c.origin().normalize()) > 0.999,
                "looks at the centre"
            );
        }
    }
}
