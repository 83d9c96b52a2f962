//! Putting a capture of an object into the frame surface methods (IDR, NeuS) work in: the
//! object inside the unit sphere at the origin, the cameras outside it, as DTU's `scale_mat`
//! places its scans.
//!
//! DTU ships that placement; a capture of one's own (COLMAP, transforms.json, NeRF-synthetic)
//! does not. With object masks it is found from the masks themselves: the visual hull (the
//! points every view's mask holds) bounds the object, and its bounding sphere, with a margin,
//! becomes the unit sphere. Without masks the sphere holds the sparse points (SfM's) that
//! nearly every view keeps in frame; with no points it is centred on the point the cameras
//! look at and sized as DTU's, the cameras [`UNMASKED_CAMERA_DISTANCE`] radii away.

use rayon::prelude::*;

use super::DataError;
use super::scene::{Scene, View};
use crate::geometry::{Bounds, Mat3, Similarity, Vec3};

/// Voxels per side of each pass of the hull's search grid.
pub const HULL_RESOLUTION: usize = 48;
/// Share of the views that see a point (it projects into their image) whose masks must hold
/// it for the point to stay in the hull: below 1 so that a few wrong masks (a finger, a
/// shadow cut off) cannot carve the object away.
pub const HULL_AGREEMENT: f32 = 0.9;
/// A point must project into at least this share of the masked views to count: the object
/// is what a capture keeps in frame.
pub const HULL_MIN_SEEN: f32 = 0.5;
/// The unit sphere's radius over the hull's bounding radius: room around the object for the
/// surface to move while it is learnt.
pub const SPHERE_MARGIN: f32 = 1.15;
/// Without masks, the cameras' mean distance from the centre in unit radii: DTU's (scan37's
/// 49 cameras sit 2.51–2.95 radii from its sphere's centre, 2.82 on average).
pub const UNMASKED_CAMERA_DISTANCE: f32 = 2.8;

/// Without masks, the share of the sparse points (of those nearly every view keeps in frame)
/// that the sphere holds before its margin: the rest are stray matches, and whatever lies
/// beyond is the field beyond the sphere's.
pub const POINT_COVERAGE: f32 = 0.99;
/// Without masks, the share of the views that must keep a sparse point in frame for it to
/// count as the object's: what every photo is of, not the floor or walls around it, which
/// only the views facing them see.
pub const POINT_MIN_SEEN: f32 = 0.9;
/// Fewest sparse points in frame for them to size the sphere.
pub const MIN_POINTS: usize = 50;
/// Without masks, the nearest camera stays at least this many radii from the centre, however
/// far the points reach: surface methods need the cameras well outside the sphere.
pub const MIN_CAMERA_DISTANCE: f32 = 1.5;

/// What placed the unit sphere.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SphereSource {
    /// The masks' visual hull.
    Masks,
    /// This many sparse points that most views keep in frame.
    Points(usize),
    /// The cameras alone.
    Cameras,
}

/// Where the object was found, in the scene's frame before the move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectSphere {
    /// Centre of the sphere that becomes the unit sphere.
    pub center: Vec3,
    /// Its radius (the hull's or the points' bounding radius times [`SPHERE_MARGIN`]).
    pub radius: f32,
    /// What placed it.
    pub source: SphereSource,
}

/// The object's sphere from the views' masks: the visual hull found on a coarse grid over
/// the region the cameras surround, then again on a grid over the first hull's box.
pub fn visual_hull_sphere(views: &[View]) -> Result<ObjectSphere, String> {
    let masked: Vec<&View> = views.iter().filter(|v| v.mask.is_some()).collect();
    if masked.is_empty() {
        return Err("no view has a mask".into());
    }
    let reach = masked
        .iter()
        .map(|v| v.camera.origin().length())
        .fold(f32::INFINITY, f32::min);
    if !(reach.is_finite() && reach > 0.0) {
        return Err("a camera sits at the centre of the scene".into());
    }
    let mut lo = Vec3::splat(-reach);
    let mut hi = Vec3::splat(reach);
    let mut hull = Vec::new();
    for _pass in 0..2 {
        let cell = (hi - lo) / HULL_RESOLUTION as f32;
        hull = hull_points(&masked, lo, cell);
        if hull.is_empty() {
            return Err(format!(
                "the masks agree on no point in front of the cameras (searched a cube of half \
                 side {reach:.2} around the point they look at)"
            ));
        }
        let (a, b) = hull.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(a, b), p| (a.min(*p), b.max(*p)),
        );
        // The next grid spans the hull's box and a cell of the last grid around it.
        lo = a - cell;
        hi = b + cell;
    }
    let cell = (hi - lo) / HULL_RESOLUTION as f32;
    let center = 0.5 * (lo + hi);
    let reach = hull
        .iter()
        .map(|p| (*p - center).length())
        .fold(0.0f32, f32::max)
        + 0.5 * cell.length();
    Ok(ObjectSphere {
        center,
        radius: reach * SPHERE_MARGIN,
        source: SphereSource::Masks,
    })
}

/// Centres of the grid cells (`HULL_RESOLUTION³` from `lo`, cells of `cell`) that the masks
/// keep.
fn hull_points(views: &[&View], lo: Vec3, cell: Vec3) -> Vec<Vec3> {
    let n = HULL_RESOLUTION;
    let min_seen = ((views.len() as f32 * HULL_MIN_SEEN).ceil() as usize).max(1);
    (0..n * n * n)
        .into_par_iter()
        .filter_map(|i| {
            let idx = Vec3::new((i % n) as f32, ((i / n) % n) as f32, (i / (n * n)) as f32);
            let p = lo + (idx + 0.5) * cell;
            let (mut seen, mut inside) = (0usize, 0usize);
            for v in views {
                let Some(px) = v.camera.project(p).filter(|q| v.camera.in_frame(*q)) else {
                    continue;
                };
                seen += 1;
                let m = v.mask.as_ref().expect("only masked views");
                let (x, y) = (px[0] as u32, px[1] as u32);
                if x < m.width && y < m.height && m.value(x, y) > 0.5 {
                    inside += 1;
                }
            }
            (seen >= min_seen && inside as f32 >= HULL_AGREEMENT * seen as f32).then_some(p)
        })
        .collect()
}

/// The object's sphere without masks: centred where the scene's frame puts the point the
/// cameras look at (the origin of an object-centred capture's frame), the cameras
/// [`UNMASKED_CAMERA_DISTANCE`] radii away on average.
pub fn camera_sphere(views: &[View]) -> ObjectSphere {
    let n = views.len().max(1) as f32;
    let mean = views
        .iter()
        .map(|v| v.camera.origin().length())
        .sum::<f32>()
        / n;
    ObjectSphere {
        center: Vec3::ZERO,
        radius: mean / UNMASKED_CAMERA_DISTANCE,
        source: SphereSource::Cameras,
    }
}

/// The object's sphere from a capture's sparse points, without masks: the points that at
/// least [`POINT_MIN_SEEN`] of the views keep in frame (what a capture is of) are the object;
/// the sphere is centred on their box (between the 1st and 99th percentile on each axis, so
/// stray matches do not move it) and holds [`POINT_COVERAGE`] of them, with the margin, the
/// nearest camera at least [`MIN_CAMERA_DISTANCE`] radii away. `None` with fewer than
/// [`MIN_POINTS`] such points. Where the cameras look is not where the object is: scan37's
/// photos through SfM have their axes meet 0.6 sphere radii in front of its bricks' centre, and
/// a sphere centred there and sized by the cameras' distance cut the back brick off.
pub fn point_sphere(views: &[View], points: &[Vec3]) -> Option<ObjectSphere> {
    let min_seen = ((views.len() as f32 * POINT_MIN_SEEN).ceil() as usize).max(1);
    let object: Vec<Vec3> = points
        .par_iter()
        .filter(|p| {
            let seen = views
                .iter()
                .filter(|v| v.camera.project(**p).is_some_and(|q| v.camera.in_frame(q)))
                .count();
            seen >= min_seen
        })
        .copied()
        .collect();
    if object.len() < MIN_POINTS {
        return None;
    }
    let percentile = |mut v: Vec<f32>, q: f32| -> f32 {
        v.sort_by(f32::total_cmp);
        let k = ((v.len() as f32 * q).ceil() as usize).clamp(1, v.len());
        v[k - 1]
    };
    let axis = |i: usize| -> f32 {
        let v: Vec<f32> = object.iter().map(|p| p[i]).collect();
        0.5 * (percentile(v.clone(), 0.01) + percentile(v, 0.99))
    };
    let center = Vec3::new(axis(0), axis(1), axis(2));
    let reach = percentile(
        object.iter().map(|p| (*p - center).length()).collect(),
        POINT_COVERAGE,
    );
    let nearest = nearest_camera(views, center);
    Some(ObjectSphere {
        center,
        radius: (reach * SPHERE_MARGIN).min(nearest / MIN_CAMERA_DISTANCE),
        source: SphereSource::Points(object.len()),
    })
}

/// `scene` moved so that `sphere` becomes the unit sphere at the origin: cameras, the map from
/// the dataset's frame, and bounds (the unit sphere, rays cut to it as DTU's are).
pub fn reframe(mut scene: Scene, sphere: ObjectSphere) -> Scene {
    let s = 1.0 / sphere.radius;
    let to_unit = Similarity {
        scale: s,
        rotation: Mat3::IDENTITY,
        translation: -s * sphere.center,
    };
    for p in &mut scene.points {
        *p = to_unit.apply_point(*p);
    }
    for v in &mut scene.views {
        let c = &mut v.camera.c2w;
        let o = to_unit.apply_point(Vec3::new(c[0][3], c[1][3], c[2][3]));
        for (r, row) in c.iter_mut().enumerate() {
            row[3] = o[r];
        }
        v.depth_range = None;
    }
    let old = scene.to_scene;
    scene.to_scene = Similarity {
        scale: s * old.scale,
        rotation: old.rotation,
        translation: s * old.translation + to_unit.translation,
    };
    let dists: Vec<f32> = scene
        .views
        .iter()
        .map(|v| v.camera.origin().length())
        .collect();
    scene.near = (dists.iter().fold(f32::INFINITY, |a, &d| a.min(d)) - 1.0).max(0.0);
    scene.far = dists.iter().fold(0.0f32, |a, &d| a.max(d)) + 1.0;
    scene.bounds = Bounds::Sphere {
        center: Vec3::ZERO,
        radius: 1.0,
    };
    scene.per_ray_range = true;
    scene.contraction = None;
    scene
}

/// `scene` (an object captured from around it) in the unit-sphere frame: from its masks'
/// visual hull where every view has a mask and `use_masks`, else from its sparse points
/// ([`point_sphere`]) where it has enough, else from its cameras alone. A note on the scene
/// says which.
/// A forward-facing capture has no object to surround, and a sphere that would hold a camera
/// cannot be used: both are errors naming the scene.
pub fn into_unit_sphere(scene: Scene, use_masks: bool) -> Result<(Scene, ObjectSphere), DataError> {
    let root = scene.root.clone();
    if scene.forward_facing {
        return Err(DataError::invalid(
            &root,
            "the cameras all look one way (a forward-facing capture): a surface method needs \
             photos taken around the object",
        ));
    }
    let masked = use_masks && scene.views.iter().all(|v| v.mask.is_some());
    let sphere = if masked {
        visual_hull_sphere(&scene.views).map_err(|e| {
            DataError::invalid(
                &root,
                format!("cannot place the object from its masks: {e}"),
            )
        })?
    } else {
        point_sphere(&scene.views, &scene.points).unwrap_or_else(|| camera_sphere(&scene.views))
    };
    let inside = scene
        .views
        .iter()
        .filter(|v| (v.camera.origin() - sphere.center).length() <= sphere.radius)
        .count();
    if inside > 0 {
        return Err(DataError::invalid(
            &root,
            format!(
                "{inside} camera(s) lie inside the sphere found around the object (centre {:?}, \
                 radius {:.2}): check the masks cover only the object",
                sphere.center.to_array(),
                sphere.radius
            ),
        ));
    }
    let mut scene = reframe(scene, sphere);
    scene.notes.push(match sphere.source {
        SphereSource::Masks => {
            "the object's unit sphere is its masks' visual hull, with a margin".into()
        }
        SphereSource::Points(n) => format!(
            "without masks, the object's unit sphere holds the {n} sparse points nearly every \
             view keeps in frame (the nearest camera {:.2} radii away)",
            nearest_camera(&scene.views, Vec3::ZERO)
        ),
        SphereSource::Cameras => format!(
            "without masks or sparse points, the object's unit sphere is centred where the \
             cameras look, {UNMASKED_CAMERA_DISTANCE} radii from them on average"
        ),
    });
    Ok((scene, sphere))
}

/// The nearest camera's distance from `center`.
fn nearest_camera(views: &[View], center: Vec3) -> f32 {
    views
        .iter()
        .map(|v| (v.camera.origin() - center).length())
        .fold(f32::INFINITY, f32::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::data::images::Image;

    /// Twelve views in a ring of radius 3 (up +z, a little above the middle), looking at the
    /// origin with a 90° field of view.
    fn ring() -> Vec<View> {
        (0..12)
            .map(|i| {
                let a = i as f32 / 12.0 * std::f32::consts::TAU;
                let eye = Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.8);
                View {
                    camera: Camera::look_at(64, 48, 32.0, eye, Vec3::ZERO, Vec3::Z),
                    image: Image {
                        width: 64,
                        height: 48,
                        data: vec![0; 64 * 48 * 3],
                    },
                    mask: None,
                    path: format!("{i}.png").into(),
                    mask_path: None,
                    depth_range: None,
                }
            })
            .collect()
    }

    /// Points on a sphere of `radius` about the origin (a Fibonacci spiral).
    fn shell(radius: f32, n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let a = i as f32 * 2.399_963;
                let r = (1.0 - z * z).sqrt();
                radius * Vec3::new(r * a.cos(), r * a.sin(), z)
            })
            .collect()
    }

    /// An object wider than a sphere sized by the cameras' distance alone, and not where
    /// their axes meet (as scan37's bricks through SfM): the points' sphere is centred on it
    /// and holds it, stray far points do not widen it, and points reaching towards the
    /// cameras leave the nearest one its distance.
    #[test]
    fn sparse_points_place_the_sphere_the_cameras_alone_would_cut() {
        let views = ring();
        let offset = Vec3::new(0.3, -0.2, 0.1);
        let by_cameras = camera_sphere(&views);
        assert!(by_cameras.radius < 1.3, "{}", by_cameras.radius);
        let mut points: Vec<Vec3> = shell(1.3, 600).into_iter().map(|p| p + offset).collect();
        points.extend([Vec3::new(1.9, 0.0, 0.0), Vec3::new(0.0, -1.9, 0.1)]);
        let s = point_sphere(&views, &points).unwrap();
        let SphereSource::Points(n) = s.source else {
            panic!("{:?}", s.source)
        };
        assert!(n > 500, "{n} points in frame");
        assert!((s.center - offset).length() < 0.05, "centre {:?}", s.center);
        assert!(
            s.radius >= 1.3 && s.radius <= 1.3 * SPHERE_MARGIN * 1.02,
            "radius {}",
            s.radius
        );
        // Points every view sees reaching out towards the cameras (a tall pole through the
        // object): the sphere stops short of the cameras.
        let pole: Vec<Vec3> = (0..=100)
            .map(|i| Vec3::new(0.0, 0.0, -1.9 + 3.8 * i as f32 / 100.0))
            .collect();
        let s = point_sphere(&views, &pole).unwrap();
        let nearest = views
            .iter()
            .map(|v| (v.camera.origin() - s.center).length())
            .fold(f32::INFINITY, f32::min);
        assert!((s.radius - nearest / MIN_CAMERA_DISTANCE).abs() < 1e-4);
        // Too few points in frame to tell: none.
        assert!(point_sphere(&views, &shell(1.0, MIN_POINTS - 1)).is_none());
    }
}
