//! The surface points a NeRF render's depth stands for (what view consistency warps by): a
//! render whose depth is the analytic scene's exact depth must give back the analytic surface
//! points, for a 360° scene and for a forward-facing one rendered in NDC.

use ins_models::nerf::eval::ViewRender;
use ins_models::nerf::render::RenderRays;
use ins_scene::data::synthetic::{self, SynthOptions};
use ins_scene::data::{LoadOptions, Scene, SceneFormat};
use ins_scene::rays::camera_rays;

fn check(format: SceneFormat) {
    let dir = tempfile::tempdir().unwrap();
    let synth = synthetic::write(format, dir.path(), &SynthOptions { size: 40, views: 6 }).unwrap();
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    let gt = &synth.views[0];
    let cam = &scene.views[0].camera;
    let world = camera_rays(cam, |o, d| scene.ray_range(o, d));
    // The rays the renderer marches (NDC for LLFF): depth is a distance along these.
    let marched = RenderRays::for_scene(&scene, world.clone()).rays;
    let n = world.len();
    let (mut depth, mut opacity, mut expected) = (vec![0.0; n], vec![0.0; n], vec![None; n]);
    for i in 0..n {
        if !gt.render.depth[i].is_finite() {
            continue;
        }
        // The analytic point, from the written world frame into the scene frame.
        let (o, d) = gt
            .camera
            .pixel_ray(i as u32 % gt.render.width, i as u32 / gt.render.width);
        let p = scene.to_scene.apply_point(o + d * gt.render.depth[i]);
        let t = match format {
            // NDC z of a point is 1 + 2·near/z (near = 1); t along the NDC ray reaches it.
            SceneFormat::Llff => {
                let z_ndc = 1.0 + 2.0 / p.z;
                (z_ndc - marched.origins[i].z) / marched.directions[i].z
            }
            _ => {
                let (o, d) = (world.origins[i], world.directions[i]);
                (p - o).dot(d) / d.dot(d)
            }
        };
        depth[i] = t;
        opacity[i] = 1.0;
        expected[i] = Some(p);
    }
    let render = ViewRender {
        width: cam.width as usize,
        height: cam.height as usize,
        rgb: vec![0.0; n * 3],
        depth,
        opacity,
    };
    let points = render.surface_points(&scene, cam);
    let mut checked = 0;
    for (got, want) in points.iter().zip(&expected) {
        match (got, want) {
            (Some(g), Some(w)) => {
                let err = (*g - *w).length() / w.length().max(1.0);
                assert!(err < 1e-3, "{format:?}: {g:?} vs {w:?}");
                checked += 1;
            }
            (None, None) => {}
            other => panic!("{format:?}: surface presence differs: {other:?}"),
        }
    }
    assert!(checked > 100, "{format:?}: only {checked} surface pixels");
}

#[test]
fn blender_depth_gives_the_analytic_surface() {
    check(SceneFormat::Blender);
}

#[test]
fn llff_ndc_depth_gives_the_analytic_surface() {
    check(SceneFormat::Llff);
}
