//! A scene's summary and geometric sanity checks: cheap tests that catch a wrong axis order,
//! a flipped sign or a mis-scaled intrinsic matrix before hours of training do.

use serde::Serialize;

use super::scene::{Scene, SceneFormat, Split};
use crate::geometry::{Bounds, Vec3, orthonormality_error};

/// What a scene holds.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Folder name.
    pub name: String,
    /// Format.
    pub format: SceneFormat,
    /// Folder.
    pub root: String,
    /// Views loaded.
    pub views: usize,
    /// Views per split.
    pub train: usize,
    /// Views per split.
    pub val: usize,
    /// Views per split.
    pub test: usize,
    /// Image width (first view).
    pub width: u32,
    /// Image height (first view).
    pub height: u32,
    /// `[fx, fy]` of the first view.
    pub focal: [f32; 2],
    /// Smallest and largest `fx` over views.
    pub focal_x_range: [f32; 2],
    /// `[cx, cy]` of the first view.
    pub principal_point: [f32; 2],
    /// Scene near distance.
    pub near: f32,
    /// Scene far distance.
    pub far: f32,
    /// Bounding volume.
    pub bounds: Bounds,
    /// Whether rays are clipped to the bounding volume.
    pub per_ray_range: bool,
    /// Views with a mask or alpha.
    pub masks: usize,
    /// Mean fraction of foreground pixels over masked views.
    pub mean_mask_coverage: Option<f32>,
    /// Smallest and largest camera distance from the bounding volume's centre.
    pub camera_distance: [f32; 2],
    /// Scale of the source → scene map.
    pub to_scene_scale: f32,
    /// How the scene is framed and rendered (NDC, a box, the unit sphere).
    pub frame: String,
    /// What the photos' edges show: a plain backdrop (a capture without points is then framed
    /// in the box its photos share) or not.
    pub edges: Option<String>,
    /// The first view's lens distortion, when it has one.
    pub lens: Option<String>,
    /// What a user should know about how the folder was read ([`Scene::notes`]).
    pub notes: Vec<String>,
}

/// One sanity check: how many items passed.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    /// What was checked.
    pub name: String,
    /// Items that passed.
    pub passed: usize,
    /// Items checked.
    pub total: usize,
    /// Whether all passed.
    pub ok: bool,
    /// Extra detail (e.g. the first failures).
    pub note: String,
}

/// Summary and checks of a scene.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// What the scene holds.
    pub summary: Summary,
    /// Sanity checks.
    pub checks: Vec<Check>,
}

impl Report {
    /// Whether every check passed.
    pub fn all_ok(&self) -> bool {
        self.checks.iter().all(|c| c.ok)
    }
}

/// Summarizes `scene` and runs the checks that fit its format.
pub fn check_scene(scene: &Scene) -> Report {
    let mut checks = vec![rotations(scene), look_at_bounds(scene)];
    match scene.format {
        SceneFormat::Dtu => {
            checks.push(center_in_masks(scene));
            checks.push(mask_rays_hit_bounds(
                scene,
                "mask pixel rays hit the unit sphere",
            ));
        }
        SceneFormat::Blender => checks.push(mask_rays_hit_bounds(
            scene,
            "opaque pixel rays pass through the bounding box",
        )),
        SceneFormat::Llff => {
            checks.push(same_direction(scene));
            checks.push(near_points_in_frame(scene));
        }
        SceneFormat::Colmap | SceneFormat::Transforms if scene.forward_facing => {
            checks.push(same_direction(scene));
            checks.push(near_points_in_frame(scene));
        }
        SceneFormat::Colmap | SceneFormat::Transforms => {
            checks.push(center_in_frame(scene));
            // The centre is where the cameras look, which may fall between objects (scan37's
            // tools): the masks are checked against the volume instead.
            if scene.has_masks() {
                checks.push(mask_rays_hit_bounds(
                    scene,
                    "mask pixel rays pass through the bounding box",
                ));
            }
        }
    }
    Report {
        summary: summarize(scene),
        checks,
    }
}

/// The summary part alone.
pub fn summarize(scene: &Scene) -> Summary {
    let (width, height) = scene.resolution();
    let first = scene.views.first().map(|v| &v.camera);
    let fxs: Vec<f32> = scene.views.iter().map(|v| v.camera.fx).collect();
    let c = scene.bounds.center();
    let dists: Vec<f32> = scene
        .views
        .iter()
        .map(|v| (v.camera.origin() - c).length())
        .collect();
    let masked: Vec<f32> = scene
        .views
        .iter()
        .filter_map(|v| v.mask.as_ref().map(|m| m.coverage()))
        .collect();
    Summary {
        name: scene.name.clone(),
        format: scene.format,
        root: scene.root.display().to_string(),
        views: scene.views.len(),
        train: scene.split(Split::Train).len(),
        val: scene.split(Split::Val).len(),
        test: scene.split(Split::Test).len(),
        width,
        height,
        focal: first.map_or([0.0; 2], |c| [c.fx, c.fy]),
        focal_x_range: min_max(&fxs),
        principal_point: first.map_or([0.0; 2], |c| [c.cx, c.cy]),
        near: scene.near,
        far: scene.far,
        bounds: scene.bounds,
        per_ray_range: scene.per_ray_range,
        masks: masked.len(),
        mean_mask_coverage: (!masked.is_empty())
            .then(|| masked.iter().sum::<f32>() / masked.len() as f32),
        camera_distance: min_max(&dists),
        to_scene_scale: scene.to_scene.scale,
        frame: describe_frame(scene),
        edges: super::backdrop::edge_colour(&scene.views).map(|e| {
            let [r, g, b] = e.colour;
            let what = if e.is_plain() {
                "a plain backdrop"
            } else {
                "not a plain backdrop"
            };
            format!(
                "{what}: {:.0} % of the photos' edges near ({r:.2}, {g:.2}, {b:.2})",
                100.0 * e.share
            )
        }),
        lens: first
            .filter(|c| !c.distortion.is_none())
            .map(|c| format!("{:?}", c.distortion)),
        notes: scene.notes.clone(),
    }
}

/// One line on how the scene is framed: what the renderer will do with it.
fn describe_frame(scene: &Scene) -> String {
    if scene.forward_facing {
        return "forward-facing: rendered in NDC, depth from the near plane to infinity".into();
    }
    if let Some(c) = scene.contraction {
        return format!(
            "object-centred, unbounded: space within {:.2} of the centre as it is, beyond it \
             contracted (mip-NeRF 360), rays out to {:.0}",
            c.radius, scene.far
        );
    }
    match scene.bounds {
        Bounds::Sphere { radius, .. } => {
            format!("sphere of radius {radius:.2}, rays clipped to it")
        }
        Bounds::Aabb { min, max } => {
            let half = 0.5 * (max - min).max_element();
            let clip = if scene.per_ray_range {
                ", rays clipped to it"
            } else {
                ""
            };
            format!(
                "object-centred: box of half side {half:.2} (aabb_scale {:.0}){clip}",
                half / 1.5
            )
        }
    }
}

fn min_max(v: &[f32]) -> [f32; 2] {
    if v.is_empty() {
        return [0.0; 2];
    }
    [
        v.iter().copied().fold(f32::INFINITY, f32::min),
        v.iter().copied().fold(f32::NEG_INFINITY, f32::max),
    ]
}

fn check(name: &str, passed: usize, total: usize, failures: &[String]) -> Check {
    let mut note = failures
        .iter()
        .take(5)
        .cloned()
        .collect::<Vec<_>>()
        .join("; ");
    if failures.len() > 5 {
        note.push_str(&format!("; … {} more", failures.len() - 5));
    }
    Check {
        name: name.to_string(),
        passed,
        total,
        ok: passed == total && total > 0,
        note,
    }
}

fn rotations(scene: &Scene) -> Check {
    let mut fails = Vec::new();
    for (i, v) in scene.views.iter().enumerate() {
        let e = orthonormality_error(v.camera.rotation());
        if e > 1e-3 {
            fails.push(format!("view {i}: |RᵀR − I| = {e:.2e}"));
        }
    }
    check(
        "camera rotations are orthonormal",
        scene.views.len() - fails.len(),
        scene.views.len(),
        &fails,
    )
}

fn look_at_bounds(scene: &Scene) -> Check {
    let mut fails = Vec::new();
    for (i, v) in scene.views.iter().enumerate() {
        let (o, d) = v.camera.ray(v.camera.cx, v.camera.cy);
        if !scene.bounds.intersect(o, d).is_some_and(|(_, t1)| t1 > 0.0) {
            fails.push(format!("view {i}"));
        }
    }
    check(
        "principal rays meet the bounding volume",
        scene.views.len() - fails.len(),
        scene.views.len(),
        &fails,
    )
}

/// Up to `per_view` foreground pixels of each masked view, spread over the image.
fn foreground_samples(scene: &Scene, per_view: usize) -> Vec<(usize, u32, u32)> {
    let mut out = Vec::new();
    for (i, v) in scene.views.iter().enumerate() {
        let Some(m) = &v.mask else { continue };
        let fg: Vec<usize> = m
            .data
            .iter()
            .enumerate()
            .filter(|&(_, &x)| x >= 128)
            .map(|(k, _)| k)
            .collect();
        if fg.is_empty() {
            continue;
        }
        let step = (fg.len() / per_view).max(1);
        for &k in fg.iter().step_by(step).take(per_view) {
            out.push((
                i,
                (k % m.width as usize) as u32,
                (k / m.width as usize) as u32,
            ));
        }
    }
    out
}

fn mask_rays_hit_bounds(scene: &Scene, name: &str) -> Check {
    let samples = foreground_samples(scene, 64);
    let mut fails = Vec::new();
    for &(i, x, y) in &samples {
        let (o, d) = scene.views[i].camera.pixel_ray(x, y);
        if !scene.bounds.intersect(o, d).is_some_and(|(_, t1)| t1 > 0.0) {
            fails.push(format!("view {i} pixel ({x}, {y})"));
        }
    }
    check(name, samples.len() - fails.len(), samples.len(), &fails)
}

fn center_in_masks(scene: &Scene) -> Check {
    let c = scene.bounds.center();
    let mut fails = Vec::new();
    let mut total = 0;
    for (i, v) in scene.views.iter().enumerate() {
        let Some(m) = &v.mask else { continue };
        total += 1;
        match v.camera.project(c) {
            Some(p) if v.camera.in_frame(p) => {
                let val = m.value(p[0] as u32, p[1] as u32);
                if val < 0.5 {
                    fails.push(format!(
                        "view {i}: centre at ({:.0}, {:.0}) is background",
                        p[0], p[1]
                    ));
                }
            }
            Some(p) => fails.push(format!(
                "view {i}: centre at ({:.0}, {:.0}) is out of frame",
                p[0], p[1]
            )),
            None => fails.push(format!("view {i}: centre is behind the camera")),
        }
    }
    check(
        "bounding-sphere centre projects inside every mask",
        total - fails.len(),
        total,
        &fails,
    )
}

/// Object-centred captures: the centre the framing chose (what the cameras look at) is in
/// front of every camera and inside its image.
fn center_in_frame(scene: &Scene) -> Check {
    let c = scene.bounds.center();
    let mut fails = Vec::new();
    for (i, v) in scene.views.iter().enumerate() {
        match v.camera.project(c) {
            Some(p) if v.camera.in_frame(p) => {}
            Some(p) => fails.push(format!("view {i}: centre at ({:.0}, {:.0})", p[0], p[1])),
            None => fails.push(format!("view {i}: centre is behind the camera")),
        }
    }
    check(
        "the scene centre is in frame in every view",
        scene.views.len() - fails.len(),
        scene.views.len(),
        &fails,
    )
}

fn same_direction(scene: &Scene) -> Check {
    let mean = scene
        .views
        .iter()
        .map(|v| v.camera.forward())
        .sum::<Vec3>()
        .normalize_or_zero();
    let cos_max = 30f32.to_radians().cos();
    let mut fails = Vec::new();
    for (i, v) in scene.views.iter().enumerate() {
        let c = v.camera.forward().dot(mean);
        if c < cos_max {
            fails.push(format!(
                "view {i}: {:.1}° off the mean",
                c.clamp(-1.0, 1.0).acos().to_degrees()
            ));
        }
    }
    check(
        "cameras face the same way (within 30°)",
        scene.views.len() - fails.len(),
        scene.views.len(),
        &fails,
    )
}

fn near_points_in_frame(scene: &Scene) -> Check {
    let mut fails = Vec::new();
    let mut total = 0;
    for (i, vi) in scene.views.iter().enumerate() {
        let near = vi.depth_range.map_or(scene.near, |r| r.0);
        let (o, d) = vi.camera.ray(vi.camera.cx, vi.camera.cy);
        let z = d.dot(vi.camera.forward()).max(1e-6);
        let p = o + d * (near / z);
        for (j, vj) in scene.views.iter().enumerate() {
            total += 1;
            if !vj.camera.project(p).is_some_and(|q| vj.camera.in_frame(q)) {
                fails.push(format!("view {i}'s near point out of view {j}"));
            }
        }
    }
    check(
        "each view's centre point at its near depth is in frame in every view",
        total - fails.len(),
        total,
        &fails,
    )
}
