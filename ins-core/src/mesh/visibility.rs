//! Which points on a mesh a set of cameras sees, the mesh hiding itself: a depth buffer of the
//! mesh per camera (its triangles rasterized at pixel centres, depth interpolated
//! perspective-correctly), a point seen where it is no deeper than the buffer by more than a
//! tolerance. A surface score counts only the parts the photos could show, as DTU's
//! observation masks do: the underside of an object on a table is no error of a
//! reconstruction.

use glam::Vec3;
use ins_scene::camera::Camera;
use rayon::prelude::*;

use super::triangle_mesh::Mesh;

/// `mesh`'s depth (along the viewing axis) at each pixel centre of `camera`, infinite where it
/// shows nothing; `width · height`, row-major.
pub fn depth_buffer(mesh: &Mesh, camera: &Camera) -> Vec<f32> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut depth = vec![f32::INFINITY; w * h];
    // Each vertex's pixel position and depth, `None` behind the camera.
    let projected: Vec<Option<([f32; 2], f32)>> = mesh
        .vertices
        .iter()
        .map(|v| {
            let p = Vec3::from_array(*v);
            Some((camera.project(p)?, camera.depth_of(p)?))
        })
        .collect();
    for t in &mesh.triangles {
        let [Some(a), Some(b), Some(c)] = t.map(|i| projected[i as usize]) else {
            continue;
        };
        let ([ax, ay], [bx, by], [cx, cy]) = (a.0, b.0, c.0);
        let area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = ax.min(bx).min(cx).floor().max(0.0) as usize;
        let y0 = ay.min(by).min(cy).floor().max(0.0) as usize;
        let x1 = (ax.max(bx).max(cx).ceil() as isize).min(w as isize - 1);
        let y1 = (ay.max(by).max(cy).ceil() as isize).min(h as isize - 1);
        if x1 < 0 || y1 < 0 {
            continue;
        }
        let (inv_a, inv_b, inv_c) = (1.0 / a.1, 1.0 / b.1, 1.0 / c.1);
        for y in y0..=y1 as usize {
            for x in x0..=x1 as usize {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                // Barycentric weights from the edge functions (either winding).
                let wa = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / area;
                let wb = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / area;
                let wc = 1.0 - wa - wb;
                if wa < 0.0 || wb < 0.0 || wc < 0.0 {
                    continue;
                }
                let z = 1.0 / (wa * inv_a + wb * inv_b + wc * inv_c);
                let d = &mut depth[y * w + x];
                *d = d.min(z);
            }
        }
    }
    depth
}

/// For each of `points` (on `mesh`'s surface), whether some camera of `cameras` sees it: in
/// its frame, and within `tolerance` of the mesh's depth there.
pub fn seen_by(mesh: &Mesh, points: &[Vec3], cameras: &[Camera], tolerance: f32) -> Vec<bool> {
    let per_camera: Vec<Vec<bool>> = cameras
        .par_iter()
        .map(|camera| {
            let depth = depth_buffer(mesh, camera);
            let w = camera.width as usize;
            points
                .iter()
                .map(|&p| {
                    let (Some(px), Some(d)) = (camera.project(p), camera.depth_of(p)) else {
                        return false;
                    };
                    camera.in_frame(px)
                        && d <= depth[px[1] as usize * w + px[0] as usize] + tolerance
                })
                .collect()
        })
        .collect();
    (0..points.len())
        .map(|i| per_camera.iter().any(|seen| seen[i]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned square of side 2 centred on `centre`, facing +z.
    fn square(centre: Vec3) -> Mesh {
        let v = |x: f32, y: f32| (centre + Vec3::new(x, y, 0.0)).to_array();
        Mesh {
            vertices: vec![v(-1.0, -1.0), v(1.0, -1.0), v(1.0, 1.0), v(-1.0, 1.0)],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    fn camera_above() -> Camera {
        Camera::look_at(32, 32, 40.0, Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y)
    }

    #[test]
    fn the_buffer_holds_the_nearer_of_two_squares() {
        let mut mesh = square(Vec3::new(0.0, 0.0, 0.0));
        let far = square(Vec3::new(0.5, 0.0, -1.0));
        mesh.vertices.extend(far.vertices);
        mesh.normals.extend(far.normals);
        mesh.triangles
            .extend(far.triangles.iter().map(|t| t.map(|i| i + 4)));
        let camera = camera_above();
        let depth = depth_buffer(&mesh, &camera);
        let centre = depth[16 * 32 + 16];
        assert!((centre - 5.0).abs() < 1e-4, "{centre}");
        // The far square's points: hidden under the near one, seen beside it.
        let points = [
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(1.4, 0.0, -1.0),
            Vec3::new(0.0, 0.0, 0.0),
        ];
        assert_eq!(
            seen_by(&mesh, &points, &[camera], 0.01),
            [false, true, true]
        );
    }

    #[test]
    fn points_outside_every_frame_are_not_seen() {
        let mesh = square(Vec3::ZERO);
        let behind = Camera::look_at(
            8,
            8,
            10.0,
            Vec3::new(0.0, 0.0, -5.0),
            Vec3::new(0.0, 0.0, -10.0),
            Vec3::Y,
        );
        assert_eq!(seen_by(&mesh, &[Vec3::ZERO], &[behind], 0.01), [false]);
        assert_eq!(seen_by(&mesh, &[Vec3::ZERO], &[], 0.01), [false]);
    }
}
