//! The `--size WxH` of the render commands.

use ins_scene::camera::Camera;

/// `camera` rendering at `size` when one is given (each axis scaled on its own), else as it is.
pub fn resized(camera: &Camera, size: Option<(usize, usize)>) -> Camera {
    match size {
        Some((w, h)) => camera.resized(w as u32, h as u32),
        None => camera.clone(),
    }
}
