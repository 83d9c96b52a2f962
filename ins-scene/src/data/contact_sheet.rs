//! A contact sheet: thumbnails of a scene's views with the bounding volume projected into each,
//! so a glance shows whether cameras and volume agree (the outline should sit on the object in
//! every thumbnail). Where masks come from their own files (DTU), background pixels are dimmed;
//! alpha-composited images (Blender) show as loaded, on white.

use super::images::Image;
use super::scene::Scene;
use crate::camera::Camera;
use crate::geometry::{Bounds, Vec3};

/// Draws up to `max_views` views (evenly spread over all views), each `thumb_width` pixels
/// wide, in a near-square grid.
pub fn contact_sheet(scene: &Scene, max_views: usize, thumb_width: u32) -> Image {
    let n_all = scene.views.len();
    let n = n_all.min(max_views.max(1));
    if n == 0 {
        return Image {
            width: 1,
            height: 1,
            data: vec![0; 3],
        };
    }
    let picks: Vec<usize> = (0..n).map(|k| k * n_all / n).collect();
    let tw = thumb_width.max(8);
    // Each thumbnail keeps its photo's shape (a capture may mix portrait and landscape); a row
    // is as tall as the tallest.
    let height_of = |vi: usize| {
        let c = &scene.views[vi].camera;
        ((tw as u64 * c.height as u64) / c.width.max(1) as u64).max(1) as u32
    };
    let row_height = picks.iter().map(|&vi| height_of(vi)).max().unwrap_or(1);
    let cols = (n as f32).sqrt().ceil() as u32;
    let rows = (n as u32).div_ceil(cols);
    let gap = 4;
    let (sw, sh) = (cols * (tw + gap) + gap, rows * (row_height + gap) + gap);
    let mut sheet = Image {
        width: sw,
        height: sh,
        data: vec![40; (sw * sh * 3) as usize],
    };
    for (k, &vi) in picks.iter().enumerate() {
        let view = &scene.views[vi];
        let th = height_of(vi);
        let mut thumb = view.image.resized(tw, th);
        if let (Some(m), Some(_)) = (&view.mask, &view.mask_path) {
            for y in 0..th {
                for x in 0..tw {
                    let mx = (x as u64 * m.width as u64 / tw as u64) as u32;
                    let my = (y as u64 * m.height as u64 / th as u64) as u32;
                    if m.value(mx.min(m.width - 1), my.min(m.height - 1)) < 0.5 {
                        let i = ((y * tw + x) * 3) as usize;
                        for c in &mut thumb.data[i..i + 3] {
                            *c /= 2;
                        }
                    }
                }
            }
        }
        let s = tw as f32 / view.camera.width.max(1) as f32;
        let colour = match scene.bounds {
            Bounds::Sphere { .. } => [255, 210, 0],
            Bounds::Aabb { .. } => [0, 255, 80],
        };
        for (a, b) in scene.bounds.outline() {
            if let Some((p, q)) = project_segment(&view.camera, a, b) {
                draw_line(
                    &mut thumb,
                    [p[0] * s, p[1] * s],
                    [q[0] * s, q[1] * s],
                    colour,
                );
            }
        }
        if let Some(c) = view.camera.project(scene.bounds.center()) {
            let c = [c[0] * s, c[1] * s];
            draw_line(
                &mut thumb,
                [c[0] - 4.0, c[1]],
                [c[0] + 4.0, c[1]],
                [255, 40, 40],
            );
            draw_line(
                &mut thumb,
                [c[0], c[1] - 4.0],
                [c[0], c[1] + 4.0],
                [255, 40, 40],
            );
        }
        let (ox, oy) = (
            gap + (k as u32 % cols) * (tw + gap),
            gap + (k as u32 / cols) * (row_height + gap),
        );
        for y in 0..th {
            let src = ((y * tw) * 3) as usize;
            let dst = (((oy + y) * sw + ox) * 3) as usize;
            sheet.data[dst..dst + (tw * 3) as usize]
                .copy_from_slice(&thumb.data[src..src + (tw * 3) as usize]);
        }
    }
    sheet
}

/// Projects the world segment `a–b` after clipping it to the part in front of the camera.
fn project_segment(cam: &Camera, a: Vec3, b: Vec3) -> Option<([f32; 2], [f32; 2])> {
    let (ca, cb) = (cam.world_to_camera(a)?, cam.world_to_camera(b)?);
    let eps = 1e-4;
    let (za, zb) = (-ca[2], -cb[2]);
    if za < eps && zb < eps {
        return None;
    }
    let clip = |p: Vec3, q: Vec3, zp: f32, zq: f32| -> Vec3 {
        let t = (eps - zp) / (zq - zp);
        p + t * (q - p)
    };
    let ca2 = if za < eps { clip(ca, cb, za, zb) } else { ca };
    let cb2 = if zb < eps { clip(cb, ca, zb, za) } else { cb };
    let proj = |c: Vec3| {
        let z = -c[2];
        let (xn, yn) = (c[0] / z, -c[1] / z);
        [cam.fx * xn + cam.skew * yn + cam.cx, cam.fy * yn + cam.cy]
    };
    Some((proj(ca2), proj(cb2)))
}

/// Draws a 1-px line, clipped to the image (Liang–Barsky), so far-away endpoints cost nothing.
fn draw_line(img: &mut Image, p: [f32; 2], q: [f32; 2], colour: [u8; 3]) {
    let (w, h) = (img.width as f32, img.height as f32);
    let d = [q[0] - p[0], q[1] - p[1]];
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (pk, qk) in [
        (-d[0], p[0]),
        (d[0], w - 1.0 - p[0]),
        (-d[1], p[1]),
        (d[1], h - 1.0 - p[1]),
    ] {
        if pk == 0.0 {
            if qk < 0.0 {
                return;
            }
        } else {
            let r = qk / pk;
            if pk < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    if t0 > t1 || !t0.is_finite() || !t1.is_finite() {
        return;
    }
    let a = [p[0] + t0 * d[0], p[1] + t0 * d[1]];
    let b = [p[0] + t1 * d[0], p[1] + t1 * d[1]];
    let steps = ((b[0] - a[0]).abs().max((b[1] - a[1]).abs()).ceil() as usize).max(1);
    for k in 0..=steps {
        let t = k as f32 / steps as f32;
        let x = (a[0] + t * (b[0] - a[0])).round();
        let y = (a[1] + t * (b[1] - a[1])).round();
        if x >= 0.0 && y >= 0.0 && x < w && y < h {
            let i = ((y as u32 * img.width + x as u32) * 3) as usize;
            img.data[i..i + 3].copy_from_slice(&colour);
        }
    }
}
