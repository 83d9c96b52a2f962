//! Putting a capture of an object into the frame surface methods (IDR, NeuS) work in: the
//! object inside the unit sphere at the origin, the cameras outside it, as DTU's `scale_mat`
//! places its scans.
//!
//! DTU ships that placement; a capture of one's own (COLMAP, transforms.json, NeRF-synthetic)
//! does not. With object masks it is found from the masks themselves: the visual hull (the
//! points every view's mask holds) bounds the object, and its bounding sphere, with a margin,
//! becomes the unit sphere. Without masks the sphere is centred on the point the cameras look at
//! and sized as DTU's, the cameras [`UNMASKED_CAMERA_DISTANCE`] radii away.

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

/// Where the object was found, in the scene's frame before the move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectSphere {
    /// Centre of the sphere that becomes the unit sphere.
    pub center: Vec3,
    /// Its radius (the hull's bounding radius times [`SPHERE_MARGIN`]).
    pub radius: f32,
    /// Whether it came from the masks' visual hull (else from the cameras alone).
    pub from_masks: bool,
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
        from_masks: true,
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
        from_masks: false,
    }
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
/// visual hull where every view has a mask and `use_masks`, else from its cameras alone.
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
        camera_sphere(&scene.views)
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
    Ok((reframe(scene, sphere), sphere))
}
