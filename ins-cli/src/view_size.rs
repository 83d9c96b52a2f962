//! The `--size WxH` of the render commands.

use ins_scene::camera::Camera;

/// `camera` rendering at `size` when one is given (each axis scaled on its own), else as it is.
pub fn resized(camera: &Camera, size: Option<(usize, usize)>) -> Camera {
    match size {
        Some((w, h)) => camera.resized(w as u32, h as u32),
        None => camera.clone(),
    }
}

/// Parses `--orbit AZ,EL[,DIST[,PANX,PANY]]` (degrees, degrees, a multiple of the training
/// cameras' distance, pan as fractions of the distance): the viewer's pose, so a view seen in
/// `ins-cli view` renders again from the command line.
pub fn parse_orbit(s: &str) -> anyhow::Result<ins_scene::viewpoints::ViewerPose> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--orbit {s:?}: expected AZ,EL[,DIST[,PANX,PANY]] numbers"))?;
    if !matches!(v.len(), 2 | 3 | 5) || v.iter().any(|x| !x.is_finite()) {
        anyhow::bail!(
            "--orbit {s:?}: expected AZ,EL[,DIST[,PANX,PANY]] (2, 3 or 5 finite numbers)"
        );
    }
    Ok(ins_scene::viewpoints::ViewerPose {
        azimuth: v[0],
        elevation: v[1],
        distance: v.get(2).copied().unwrap_or(1.0),
        pan: [
            v.get(3).copied().unwrap_or(0.0),
            v.get(4).copied().unwrap_or(0.0),
        ],
    })
}

/// The camera of `--orbit` in `scene` at `size` (default: the first training view's size).
pub fn orbit_camera(
    scene: &ins_scene::data::Scene,
    orbit: &str,
    size: Option<(usize, usize)>,
) -> anyhow::Result<Camera> {
    let pose = parse_orbit(orbit)?;
    let vp = ins_scene::viewpoints::Viewpoints::for_scene(scene)
        .ok_or_else(|| anyhow::anyhow!("{}: no training views to orbit", scene.root.display()))?;
    let (w, h) = size.unwrap_or_else(|| {
        let t = &scene.views[scene.split(ins_scene::data::Split::Train)[0]].camera;
        (t.width as usize, t.height as usize)
    });
    Ok(vp.camera(pose, w as u32, h as u32))
}
