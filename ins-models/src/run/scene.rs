//! Loading a scene at a run's resolution, and choosing the views a run evaluates on.

use std::path::Path;

use anyhow::{Result, bail};
use ins_scene::data::{LoadOptions, Scene, SceneFormat, Split, detect_format};

/// The longer side a scene is brought near when no downscale is given: about 400 px keeps a
/// capture's pretraining and stylizing within minutes on a CPU.
pub const DEFAULT_LONG_SIDE: u32 = 400;

/// The whole downscale that brings the longer side of `width × height` nearest `long_side`
/// (never below 1): 800 → 2, 1600 → 4, a phone's 4032 → 10 (403 px), 1920 → 5 (384 px).
pub fn auto_downscale(width: u32, height: u32, long_side: u32) -> u32 {
    let long = width.max(height).max(1) as f64;
    ((long / long_side.max(1) as f64).round() as u32).max(1)
}

/// The scene in `path` at `downscale` (0: the factor that brings the longer side nearest
/// [`DEFAULT_LONG_SIDE`]), its format and the factor used; `images` names a COLMAP
/// workspace's photo folder. A scene without training views is an error naming the folder;
/// the scene's notes (photos left out) are printed.
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
        auto_downscale(w, h, DEFAULT_LONG_SIDE)
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
    for note in &scene.notes {
        eprintln!("note: {note}");
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_factor_brings_the_long_side_nearest_400_px() {
        for ((w, h), factor) in [
            ((800, 800), 2),
            ((1600, 1200), 4),
            ((4032, 3024), 10),
            ((1920, 1080), 5),
            ((504, 378), 1),
            ((64, 48), 1),
            ((599, 300), 1),
            ((600, 300), 2),
        ] {
            assert_eq!(auto_downscale(w, h, DEFAULT_LONG_SIDE), factor, "{w}×{h}");
        }
    }
}
