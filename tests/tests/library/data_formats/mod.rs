//! Scenes and cameras: analytic scenes written in each dataset format, read back through the
//! real loaders, must give rays that meet the rendered surface point at the rendered depth.
//! Plus masks, LLFF holdout and spiral, strided patches, paths, and bad input.

mod bad_inputs;
mod capture_framing;
mod captures;
mod loaders;
mod rays_and_paths;

use std::path::Path;

use ins_scene::camera::Camera;
use ins_scene::data::check::check_scene;
use ins_scene::data::contact_sheet::contact_sheet;
use ins_scene::data::plain_image::{load_rgb, pixel_coordinates};
use ins_scene::data::synthetic::{self, SynthOptions, SynthScene};
use ins_scene::data::{LoadOptions, Scene, SceneFormat, Split};
use ins_scene::geometry::{Vec3, orthonormality_error};
use ins_scene::patches::PatchSampler;
use ins_scene::paths::{
    PathKind, average_pose, capture_arc, default_kind, interpolate, path_for_scene, plane_basis,
    scene_orbit, spiral_for_scene, turntable_for_scene,
};
use ins_scene::rays::RaySampler;

fn write(format: SceneFormat, size: u32, views: usize) -> (tempfile::TempDir, SynthScene) {
    let dir = tempfile::tempdir().expect("tempdir");
    let synth = synthetic::write(format, dir.path(), &SynthOptions { size, views })
        .expect("write synthetic scene");
    (dir, synth)
}

fn load(dir: &Path) -> Scene {
    Scene::load(dir, &LoadOptions::default()).expect("load scene")
}

fn dist(a: Vec3, b: Vec3) -> f32 {
    (a - b).length()
}

fn sub(a: Vec3, b: Vec3) -> Vec3 {
    a - b
}

fn dot(a: Vec3, b: Vec3) -> f32 {
    a.dot(b)
}

fn norm(a: Vec3) -> f32 {
    a.length()
}

/// For interior foreground pixels of every view (every 3rd in each direction), the loaded ray
/// at the rendered depth (× `scale`) must land on the rendered point mapped by `map`.
fn assert_rays_hit_surface(
    scene: &Scene,
    synth: &SynthScene,
    map: impl Fn(Vec3) -> Vec3,
    scale: f32,
    tol: f32,
) {
    assert_eq!(scene.views.len(), synth.views.len());
    let mut checked = 0;
    for (i, gt) in synth.views.iter().enumerate() {
        let r = &gt.render;
        let mut pixels = Vec::new();
        for y in (1..r.height).step_by(3) {
            for x in (1..r.width).step_by(3) {
                if r.is_interior(x, y) {
                    pixels.push((x, y));
                }
            }
        }
        let rays = scene.pixel_rays(i, &pixels).expect("pixel rays");
        for (k, &(x, y)) in pixels.iter().enumerate() {
            let t_world = r.depth[(y * r.width + x) as usize];
            let (o, d) = gt.camera.pixel_ray(x, y);
            let p_world = Vec3::new(
                o[0] + t_world * d[0],
                o[1] + t_world * d[1],
                o[2] + t_world * d[2],
            );
            let expected = map(p_world);
            let got = rays.point(k, t_world * scale);
            assert!(
                (rays.directions[k].length() - 1.0).abs() < 1e-5,
                "direction not unit"
            );
            assert!(
                dist(got, expected) < tol,
                "view {i} pixel ({x}, {y}): ray at depth {} gives {got:?}, surface is at {expected:?}",
                t_world * scale
            );
            checked += 1;
        }
    }
    assert!(
        checked >= 20 * synth.views.len().min(4),
        "too few interior pixels checked: {checked}"
    );
}
