//! Loading a scene at a run's resolution, and choosing the views a run evaluates on.

use std::path::Path;

use anyhow::{Result, bail};
use ins_scene::data::{LoadOptions, Scene, SceneFormat, Split, detect_format};

/// The longer side a scene is brought within when no downscale is given.
pub const DEFAULT_MAX_SIDE: u32 = 512;

/// The downscale that brings the longer side of `width × height` to at most `max_side`.
pub fn auto_downscale(width: u32, height: u32, max_side: u32) -> u32 {
    let long = width.max(height).max(1);
    long.div_ceil(max_side.max(1)).max(1)
}

/// The scene in `path` at `downscale` (0: the smallest factor that brings the longer side to
/// at most [`DEFAULT_MAX_SIDE`]), its format and the factor used; `images` names a COLMAP
/// workspace's photo folder. A scene without training views is an error naming the folder.
pub fn load_scene(
    path: &Path,
    downscale: u32,
    images: Option<&Path>,
) -> Result<(Scene, SceneFormat, u32)> {
    let format = detect_format(path)?;
    if let Some(dir) = images
        && format != SceneFormat::Colmap
    {
        bail!(
            "--images {}: a {format} scene names its own photos; --images is for COLMAP \
             workspaces whose photos are not in images/",
            dir.display()
        );
    }
    let factor = if downscale == 0 {
        let (w, h) = Scene::probe_resolution(path)?;
        auto_downscale(w, h, DEFAULT_MAX_SIDE)
    } else {
        downscale
    };
    let scene = Scene::load(
        path,
        &LoadOptions {
            downscale: factor,
            image_dir: images.map(Path::to_path_buf),
            ..Default::default()
        },
    )?;
    if scene.split(Split::Train).is_empty() {
        bail!("{}: the scene has no training views", path.display());
    }
    Ok((scene, format, factor))
}

/// Held-out views to evaluate: the val split, else the test split (LLFF holds every 8th view
/// out as both).
pub fn heldout_views(scene: &Scene) -> Vec<usize> {
    let val = scene.split(Split::Val);
    if !val.is_empty() {
        val.to_vec()
    } else {
        scene.split(Split::Test).to_vec()
    }
}

/// `n` views spread evenly over `views`.
pub fn spread(views: &[usize], n: usize) -> Vec<usize> {
    if views.len() <= n {
        return views.to_vec();
    }
    (0..n).map(|i| views[i * views.len() / n]).collect()
}
