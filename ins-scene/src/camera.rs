//! The pinhole camera, in the one convention every loader converts to.
//!
//! **Convention** (OpenGL / NeRF): `c2w` is camera-to-world, 3×4 row major `[R | t]`; the
//! camera's x axis points right, y up, and it looks down −z. Pixel `(u, v)` counts u to the
//! right and v downward from the top-left corner; pixel `(u, v)` covers `[u, u+1) × [v, v+1)`,
//! so its centre is `(u + 0.5, v + 0.5)`. Intrinsics are OpenCV style (`fx, fy, cx, cy, skew`
//! with `K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]` acting on (x right, y down, z forward)
//! coordinates), so the camera-frame direction of continuous pixel position `(x, y)` is
//! `[(x − cx − skew·y_n)/fx, −y_n, −1]` with `y_n = (y − cy)/fy`, after undistorting
//! `(x_n, y_n)` when the camera has lens [`Distortion`].

use serde::Serialize;

use super::distortion::Distortion;
use super::geometry::{Mat3, Vec3, mat3_from_rows};

/// A pinhole camera: image size, intrinsics and camera-to-world pose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in continuous pixel coordinates.
    pub cx: f32,
    /// Principal point y, in continuous pixel coordinates.
    pub cy: f32,
    /// Skew (`K[0][1]`); 0 for all but decomposed projection matrices.
    pub skew: f32,
    /// Camera-to-world `[R | t]`, row major, OpenGL axes (x right, y up, looking down −z).
    pub c2w: [[f32; 4]; 3],
    /// Lens distortion of the images this camera took (real captures); rays and projections
    /// follow it exactly.
    #[serde(skip_serializing_if = "Distortion::is_none")]
    pub distortion: Distortion,
}

impl Camera {
    /// A camera with principal point and focal lengths given, no skew.
    pub fn new(
        width: u32,
        height: u32,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        c2w: [[f32; 4]; 3],
    ) -> Self {
        Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            skew: 0.0,
            c2w,
            distortion: Distortion::None,
        }
    }

    /// The same camera with `distortion`.
    pub fn with_distortion(self, distortion: Distortion) -> Camera {
        Camera { distortion, ..self }
    }

    /// The same camera as an ideal pinhole: what rendered paths use, so novel views come out
    /// free of the capture lens' distortion.
    pub fn pinhole(&self) -> Camera {
        Camera {
            distortion: Distortion::None,
            ..self.clone()
        }
    }

    /// A camera with horizontal field of view `fov_x` (radians), square pixels and the
    /// principal point at the image centre (the NeRF-synthetic convention).
    pub fn from_fov_x(width: u32, height: u32, fov_x: f32, c2w: [[f32; 4]; 3]) -> Self {
        let f = 0.5 * width as f32 / (0.5 * fov_x).tan();
        Camera::new(
            width,
            height,
            f,
            f,
            0.5 * width as f32,
            0.5 * height as f32,
            c2w,
        )
    }

    /// A camera at `eye` looking at `target`, with `up` roughly up in the image.
    pub fn look_at(width: u32, height: u32, focal: f32, eye: Vec3, target: Vec3, up: Vec3) -> Self {
        Camera::new(
            width,
            height,
            focal,
            focal,
            0.5 * width as f32,
            0.5 * height as f32,
            pose_look_at(eye, target, up),
        )
    }

    /// Rotation part of `c2w` (columns: right, up, back).
    pub fn rotation(&self) -> Mat3 {
        mat3_from_rows(self.c2w.map(|r| [r[0], r[1], r[2]]))
    }

    /// Camera centre in world coordinates.
    pub fn origin(&self) -> Vec3 {
        Vec3::new(self.c2w[0][3], self.c2w[1][3], self.c2w[2][3])
    }

    fn column(&self, c: usize) -> Vec3 {
        Vec3::new(self.c2w[0][c], self.c2w[1][c], self.c2w[2][c])
    }

    /// Viewing direction (the −z axis) in world coordinates.
    pub fn forward(&self) -> Vec3 {
        (-self.column(2)).normalize_or_zero()
    }

    /// Image-up direction (the +y axis) in world coordinates.
    pub fn up(&self) -> Vec3 {
        self.column(1).normalize_or_zero()
    }

    /// Image-right direction (the +x axis) in world coordinates.
    pub fn right(&self) -> Vec3 {
        self.column(0).normalize_or_zero()
    }

    /// Direction in the camera frame (OpenGL axes, z = −1, not unit) through the continuous
    /// pixel position `(x, y)`; the centre of pixel `(u, v)` is `(u + 0.5, v + 0.5)`.
    pub fn direction_camera(&self, x: f32, y: f32) -> Vec3 {
        let yn = (y - self.cy) / self.fy;
        let xn = (x - self.cx - self.skew * yn) / self.fx;
        if matches!(self.distortion, Distortion::None) {
            return Vec3::new(xn, -yn, -1.0);
        }
        let (xu, yu) = self.distortion.undistort(xn as f64, yn as f64);
        Vec3::new(xu as f32, -yu as f32, -1.0)
    }

    /// World-space ray `(origin, unit direction)` through continuous pixel position `(x, y)`.
    pub fn ray(&self, x: f32, y: f32) -> (Vec3, Vec3) {
        let d = self.rotation() * self.direction_camera(x, y);
        (self.origin(), d.normalize_or_zero())
    }

    /// World-space ray through the centre of pixel `(u, v)`.
    pub fn pixel_ray(&self, u: u32, v: u32) -> (Vec3, Vec3) {
        self.ray(u as f32 + 0.5, v as f32 + 0.5)
    }

    /// World point `p` in the camera frame (OpenGL axes: in front of the camera means z < 0).
    /// `None` only if the rotation is singular.
    pub fn world_to_camera(&self, p: Vec3) -> Option<Vec3> {
        let r = self.rotation();
        let det = r.determinant();
        if !det.is_finite() || det.abs() < 1e-12 {
            return None;
        }
        Some(r.inverse() * (p - self.origin()))
    }

    /// Continuous pixel position of world point `p`, or `None` when it is not in front of the
    /// camera. The result may lie outside the image; see [`Camera::in_frame`].
    pub fn project(&self, p: Vec3) -> Option<[f32; 2]> {
        let c = self.world_to_camera(p)?;
        let z = -c[2];
        if z <= 1e-8 {
            return None;
        }
        let (xn, yn) = match self.distortion {
            Distortion::None => (c[0] / z, -c[1] / z),
            d => {
                let (x, y) = d.distort((c[0] / z) as f64, (-c[1] / z) as f64);
                (x as f32, y as f32)
            }
        };
        Some([
            self.fx * xn + self.skew * yn + self.cx,
            self.fy * yn + self.cy,
        ])
    }

    /// Whether continuous pixel position `p` lies inside the image.
    pub fn in_frame(&self, p: [f32; 2]) -> bool {
        p[0] >= 0.0 && p[1] >= 0.0 && p[0] < self.width as f32 && p[1] < self.height as f32
    }

    /// Depth of world point `p` along the viewing axis (positive in front of the camera).
    pub fn depth_of(&self, p: Vec3) -> Option<f32> {
        self.world_to_camera(p).map(|c| -c[2])
    }

    /// The same camera for an image downscaled by `factor` (image size floored). Continuous
    /// pixel coordinates scale by `1/factor`, so the principal point and focal lengths do too.
    pub fn downscaled(&self, factor: u32) -> Camera {
        let f = factor.max(1);
        self.rescaled(
            self.width / f,
            self.height / f,
            1.0 / f as f32,
            1.0 / f as f32,
        )
    }

    /// The same camera rendering a `width × height` image (each axis scaled on its own).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f32 / self.width.max(1) as f32;
        let sy = height as f32 / self.height.max(1) as f32;
        self.rescaled(width, height, sx, sy)
    }

    /// The same view through a frame of `width`×`height` pixels: focal lengths kept, the
    /// principal point at the same offset from the frame's centre. How a camera path through
    /// photos of different sizes (portrait and landscape) shares one frame size.
    pub fn reframed(&self, width: u32, height: u32) -> Camera {
        Camera {
            width,
            height,
            cx: self.cx + 0.5 * (width as f32 - self.width as f32),
            cy: self.cy + 0.5 * (height as f32 - self.height as f32),
            ..self.clone()
        }
    }

    fn rescaled(&self, width: u32, height: u32, sx: f32, sy: f32) -> Camera {
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            skew: self.skew * sx,
            c2w: self.c2w,
            distortion: self.distortion,
        }
    }
}

/// Camera-to-world pose at `eye` looking at `target` (OpenGL axes). `up` must not be parallel
/// to the viewing direction.
pub fn pose_look_at(eye: Vec3, target: Vec3, up: Vec3) -> [[f32; 4]; 3] {
    pose_from_back_up(eye - target, up, eye)
}

/// Camera-to-world pose from the backward axis (+z), a rough up vector and the centre; the
/// LLFF `viewmatrix`. Columns are right = up × back, up' = back × right, back.
pub fn pose_from_back_up(back: Vec3, up: Vec3, center: Vec3) -> [[f32; 4]; 3] {
    let z = back.normalize_or_zero();
    let x = up.cross(z).normalize_or_zero();
    let y = z.cross(x).normalize_or_zero();
    [
        [x[0], y[0], z[0], center[0]],
        [x[1], y[1], z[1], center[1]],
        [x[2], y[2], z[2], center[2]],
    ]
}

/// `c2w` with the rotation columns multiplied by `(1, −1, −1)`: converts an OpenCV pose (x right,
/// y down, z forward) to OpenGL axes and back.
pub fn flip_yz(c2w: &[[f32; 4]; 3]) -> [[f32; 4]; 3] {
    c2w.map(|r| [r[0], -r[1], -r[2], r[3]])
}

/// Point at distance `t` along the ray `o + t·d`.
pub fn ray_point(o: Vec3, d: Vec3, t: f32) -> Vec3 {
    o + t * d
}
