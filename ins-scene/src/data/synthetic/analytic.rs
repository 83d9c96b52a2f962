//! The analytic scene: primitives with textures, ray-cast with exact depth, normals and masks.

use crate::camera::Camera;
use crate::geometry::{Similarity, Vec3};

/// A primitive, in the scene's local frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
    },
    /// An axis-aligned box.
    Box {
        /// Minimum corner.
        min: Vec3,
        /// Maximum corner.
        max: Vec3,
    },
    /// An infinite plane.
    Plane {
        /// A point on it.
        point: Vec3,
        /// Its normal.
        normal: Vec3,
    },
}

/// Surface colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Texture {
    /// One colour.
    Solid(Vec3),
    /// A 3D checkerboard of two colours with cells of side `size` (local units).
    Checker {
        /// First colour.
        a: Vec3,
        /// Second colour.
        b: Vec3,
        /// Cell size.
        size: f32,
    },
}

/// A textured primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Object {
    /// Geometry.
    pub shape: Shape,
    /// Colour.
    pub texture: Texture,
    /// Whether it counts as foreground in masks and alpha (ground and backdrop planes do not).
    pub foreground: bool,
}

impl Object {
    /// The object scaled by `k` about the origin (its texture's cells with it).
    pub fn scaled(self, k: f32) -> Self {
        let shape = match self.shape {
            Shape::Sphere { center, radius } => Shape::Sphere {
                center: center * k,
                radius: radius * k,
            },
            Shape::Box { min, max } => Shape::Box {
                min: min * k,
                max: max * k,
            },
            Shape::Plane { point, normal } => Shape::Plane {
                point: point * k,
                normal,
            },
        };
        let texture = match self.texture {
            Texture::Checker { a, b, size } => Texture::Checker {
                a,
                b,
                size: size * k,
            },
            solid => solid,
        };
        Self {
            shape,
            texture,
            ..self
        }
    }
}

/// A set of objects placed in the world by a similarity.
#[derive(Clone, Debug, PartialEq)]
pub struct AnalyticScene {
    /// Objects, in local coordinates.
    pub objects: Vec<Object>,
    /// Local → world map.
    pub to_world: Similarity,
    /// What a ray that meets nothing shows (black, or a studio's plain backdrop).
    pub backdrop: Vec3,
}

/// The first surface a ray meets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) world ray.
    pub t: f32,
    /// World position.
    pub point: Vec3,
    /// Index into [`AnalyticScene::objects`].
    pub object: usize,
    /// Shaded colour.
    pub rgb: Vec3,
}

/// A ray-cast image with exact per-pixel geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct Rendering {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Colour, `h·w·3`; black where nothing is hit.
    pub rgb: Vec<f32>,
    /// Distance along the unit world ray of the pixel centre; infinite where nothing is hit.
    pub depth: Vec<f32>,
    /// Which object was hit, if any.
    pub object: Vec<Option<usize>>,
    /// Whether a foreground object was hit.
    pub mask: Vec<bool>,
}

impl Rendering {
    /// Whether pixel `(x, y)` and its 8 neighbours all see the same foreground object: a pixel
    /// safely away from silhouettes, for tests.
    pub fn is_interior(&self, x: u32, y: u32) -> bool {
        if x == 0 || y == 0 || x + 1 >= self.width || y + 1 >= self.height {
            return false;
        }
        let i = (y * self.width + x) as usize;
        let Some(o) = self.object[i] else {
            return false;
        };
        if !self.mask[i] {
            return false;
        }
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let j = ((y as i32 + dy) as u32 * self.width + (x as i32 + dx) as u32) as usize;
                if self.object[j] != Some(o) {
                    return false;
                }
            }
        }
        true
    }
}

impl AnalyticScene {
    /// Spheres and boxes inside the unit ball (radius ≤ 0.95), on a ground plane `z = −0.55`
    /// when `ground` is true; local z is up.
    pub fn tabletop(ground: bool) -> Self {
        let red = Vec3::new(0.85, 0.2, 0.15);
        let white = Vec3::new(0.95, 0.95, 0.9);
        let mut objects = vec![
            Object {
                shape: Shape::Sphere {
                    center: Vec3::new(0.0, 0.0, 0.0),
                    radius: 0.45,
                },
                texture: Texture::Checker {
                    a: red,
                    b: white,
                    size: 0.15,
                },
                foreground: true,
            },
            Object {
                shape: Shape::Box {
                    min: Vec3::new(0.25, 0.15, -0.55),
                    max: Vec3::new(0.6, 0.5, -0.2),
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.1, 0.6, 0.2),
                    b: Vec3::new(0.9, 0.8, 0.2),
                    size: 0.1,
                },
                foreground: true,
            },
            Object {
                shape: Shape::Sphere {
                    center: Vec3::new(-0.45, 0.35, -0.3),
                    radius: 0.2,
                },
                texture: Texture::Solid(Vec3::new(0.15, 0.3, 0.9)),
                foreground: true,
            },
        ];
        if ground {
            objects.push(Object {
                shape: Shape::Plane {
                    point: Vec3::new(0.0, 0.0, -0.55),
                    normal: Vec3::new(0.0, 0.0, 1.0),
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.35, 0.3, 0.25),
                    b: Vec3::new(0.6, 0.55, 0.5),
                    size: 0.25,
                },
                foreground: false,
            });
        }
        AnalyticScene {
            objects,
            to_world: Similarity::identity(),
            backdrop: Vec3::ZERO,
        }
    }

    /// A block with a notch: a base slab and two walls standing on it in an L, so the corner
    /// between the walls is hollow and, from every camera above it, seen against the object
    /// itself (its floor is the slab), never against the background. Masks alone cannot carve
    /// it (the visual hull fills it); only the photos' colours can. The notch is
    /// [`Self::NOTCH`]; local z is up, on a ground plane at `z = −0.55`.
    pub fn notched_block() -> Self {
        let checker = |a: Vec3, b: Vec3, size: f32| Texture::Checker { a, b, size };
        let block = |min: Vec3, max: Vec3, texture| Object {
            shape: Shape::Box { min, max },
            texture,
            foreground: true,
        };
        let objects = vec![
            // The slab: the notch's floor.
            block(
                Vec3::new(-0.5, -0.5, -0.55),
                Vec3::new(0.5, 0.5, -0.35),
                checker(Vec3::new(0.85, 0.75, 0.2), Vec3::new(0.2, 0.25, 0.7), 0.125),
            ),
            // The walls along x (at the back, low y) and along y (at low x).
            block(
                Vec3::new(-0.5, -0.5, -0.35),
                Vec3::new(0.5, -0.1, 0.15),
                checker(Vec3::new(0.85, 0.2, 0.15), Vec3::new(0.95, 0.95, 0.9), 0.1),
            ),
            block(
                Vec3::new(-0.5, -0.1, -0.35),
                Vec3::new(-0.1, 0.5, 0.15),
                checker(Vec3::new(0.1, 0.6, 0.2), Vec3::new(0.95, 0.9, 0.6), 0.1),
            ),
            Object {
                shape: Shape::Plane {
                    point: Vec3::new(0.0, 0.0, -0.55),
                    normal: Vec3::new(0.0, 0.0, 1.0),
                },
                texture: checker(Vec3::new(0.35, 0.3, 0.25), Vec3::new(0.6, 0.55, 0.5), 0.25),
                foreground: false,
            },
        ];
        AnalyticScene {
            objects,
            to_world: Similarity::identity(),
            backdrop: Vec3::ZERO,
        }
    }

    /// The hollow corner of [`Self::notched_block`] (local frame): empty space bounded by
    /// the slab below and the walls on two sides.
    pub const NOTCH: [[f32; 3]; 2] = [[-0.1, -0.1, -0.35], [0.5, 0.5, 0.15]];

    /// Signed distance (local frame) to the union of the foreground boxes: exact outside,
    /// a bound inside. For measuring reconstructed surfaces against the truth.
    pub fn foreground_distance(&self, p: Vec3) -> f32 {
        self.objects
            .iter()
            .filter(|o| o.foreground)
            .filter_map(|o| match o.shape {
                Shape::Box { min, max } => {
                    let c = (min + max) * 0.5;
                    let h = (max - min) * 0.5;
                    let q = (p - c).abs() - h;
                    let outside = q.max(Vec3::ZERO).length();
                    Some(outside + q.x.max(q.y).max(q.z).min(0.0))
                }
                Shape::Sphere { center, radius } => Some((p - center).length() - radius),
                Shape::Plane { .. } => None,
            })
            .fold(f32::INFINITY, f32::min)
    }

    /// The tabletop's objects before a plain light backdrop, as in a photo studio or on a white
    /// table: nothing past the objects for structure from motion to find, and a background no
    /// surface in front of the cameras explains.
    pub fn studio() -> Self {
        Self {
            backdrop: Vec3::new(0.92, 0.92, 0.9),
            ..Self::tabletop(false)
        }
    }

    /// The tabletop's objects at `scale`, inside a dome of radius 9 painted in broad checks,
    /// with no floor.
    fn in_dome(scale: f32) -> Self {
        let mut scene = Self::tabletop(false);
        scene.objects = scene.objects.into_iter().map(|o| o.scaled(scale)).collect();
        scene.objects.push(Object {
            shape: Shape::Sphere {
                center: Vec3::ZERO,
                radius: 9.0,
            },
            texture: Texture::Checker {
                a: Vec3::new(0.55, 0.7, 0.9),
                b: Vec3::new(0.85, 0.85, 0.75),
                size: 3.0,
            },
            foreground: false,
        });
        scene
    }

    /// The tabletop's objects at 0.7 times their size, within radius 0.67 of the centre (as
    /// DTU's unit sphere leaves a margin around its object), inside a dome of radius 9 painted
    /// in broad checks, with no floor: everything behind them lies beyond the unit sphere, as
    /// NeRF++'s background model assumes, and the masks (written, but a run without masks
    /// leaves them unused) score the objects alone.
    pub fn domed() -> Self {
        Self::in_dome(0.7)
    }

    /// The tabletop in a room: its objects on a floor of large tiles, inside a dome of radius
    /// 9 painted in broad checks: a background well past cameras 3 units away, as a capture of
    /// an object in a room has, coarse enough to be learnt from small images.
    pub fn room() -> Self {
        let mut scene = Self::in_dome(1.0);
        scene.objects.insert(
            scene.objects.len() - 1,
            Object {
                shape: Shape::Plane {
                    point: Vec3::new(0.0, 0.0, -0.55),
                    normal: Vec3::Z,
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.35, 0.3, 0.25),
                    b: Vec3::new(0.65, 0.6, 0.5),
                    size: 1.2,
                },
                foreground: false,
            },
        );
        scene
    }

    /// A forward-facing arrangement for LLFF: objects 3–6 units down −z (local), a ground plane
    /// `y = −1.5` and a backdrop `z = −8`, so every ray from near the origin hits something.
    pub fn forward_facing() -> Self {
        let objects = vec![
            Object {
                shape: Shape::Sphere {
                    center: Vec3::new(0.0, 0.0, -4.0),
                    radius: 0.8,
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.85, 0.2, 0.15),
                    b: Vec3::new(0.95, 0.95, 0.9),
                    size: 0.25,
                },
                foreground: true,
            },
            Object {
                shape: Shape::Box {
                    min: Vec3::new(-1.8, -1.5, -5.5),
                    max: Vec3::new(-0.8, 0.2, -4.5),
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.1, 0.6, 0.2),
                    b: Vec3::new(0.9, 0.8, 0.2),
                    size: 0.3,
                },
                foreground: true,
            },
            Object {
                shape: Shape::Sphere {
                    center: Vec3::new(1.3, 0.6, -3.2),
                    radius: 0.5,
                },
                texture: Texture::Solid(Vec3::new(0.15, 0.3, 0.9)),
                foreground: true,
            },
            Object {
                shape: Shape::Plane {
                    point: Vec3::new(0.0, -1.5, 0.0),
                    normal: Vec3::new(0.0, 1.0, 0.0),
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.35, 0.3, 0.25),
                    b: Vec3::new(0.6, 0.55, 0.5),
                    size: 0.5,
                },
                foreground: false,
            },
            Object {
                shape: Shape::Plane {
                    point: Vec3::new(0.0, 0.0, -8.0),
                    normal: Vec3::new(0.0, 0.0, 1.0),
                },
                texture: Texture::Checker {
                    a: Vec3::new(0.5, 0.6, 0.8),
                    b: Vec3::new(0.8, 0.85, 0.95),
                    size: 0.7,
                },
                foreground: false,
            },
        ];
        AnalyticScene {
            objects,
            to_world: Similarity::identity(),
            backdrop: Vec3::ZERO,
        }
    }

    /// First hit of the world ray `o + t·d` (unit `d`, `t > 0`).
    pub fn trace(&self, o: Vec3, d: Vec3) -> Option<Hit> {
        let s = &self.to_world;
        let rt = s.rotation.transpose();
        let ol = rt * (o - s.translation) / s.scale;
        let dl = rt * d;
        let mut best: Option<(f32, usize, Vec3)> = None;
        for (i, obj) in self.objects.iter().enumerate() {
            if let Some((t, n)) = intersect(&obj.shape, ol, dl)
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, i, n));
            }
        }
        let (tl, i, n) = best?;
        let pl = ol + dl * tl;
        let n = if n.dot(dl) > 0.0 { -n } else { n };
        let light = Vec3::new(0.3, 0.5, 0.8).normalize();
        let shade = 0.45 + 0.55 * n.dot(light).max(0.0);
        let base = match self.objects[i].texture {
            Texture::Solid(c) => c,
            Texture::Checker { a, b, size } => {
                let k = (pl[0] / size).floor() + (pl[1] / size).floor() + (pl[2] / size).floor();
                if (k as i64).rem_euclid(2) == 0 { a } else { b }
            }
        };
        Some(Hit {
            t: tl * s.scale,
            point: s.apply_point(pl),
            object: i,
            rgb: base * shade,
        })
    }

    /// Ray-casts the scene through every pixel centre of `camera`.
    pub fn render(&self, camera: &Camera) -> Rendering {
        let n = (camera.width * camera.height) as usize;
        let mut r = Rendering {
            width: camera.width,
            height: camera.height,
            rgb: self.backdrop.to_array().repeat(n),
            depth: vec![f32::INFINITY; n],
            object: vec![None; n],
            mask: vec![false; n],
        };
        for v in 0..camera.height {
            for u in 0..camera.width {
                let i = (v * camera.width + u) as usize;
                let (o, d) = camera.pixel_ray(u, v);
                if let Some(h) = self.trace(o, d) {
                    r.rgb[i * 3..i * 3 + 3].copy_from_slice(&h.rgb.to_array());
                    r.depth[i] = h.t;
                    r.object[i] = Some(h.object);
                    r.mask[i] = self.objects[h.object].foreground;
                }
            }
        }
        r
    }
}

/// Ray–shape intersection in local coordinates: nearest `t > ε` and the outward normal there.
fn intersect(shape: &Shape, o: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
    const EPS: f32 = 1e-5;
    match *shape {
        Shape::Sphere { center, radius } => {
            let oc = o - center;
            let b = oc.dot(d);
            let c = oc.dot(oc) - radius * radius;
            let disc = b * b - d.dot(d) * c;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            let a = d.dot(d);
            let t = [(-b - s) / a, (-b + s) / a]
                .into_iter()
                .find(|&t| t > EPS)?;
            Some((t, (o + d * t - center).normalize()))
        }
        Shape::Box { min, max } => {
            let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
            let (mut n0, mut n1) = (Vec3::ZERO, Vec3::ZERO);
            for k in 0..3 {
                if d[k].abs() < 1e-12 {
                    if o[k] < min[k] || o[k] > max[k] {
                        return None;
                    }
                    continue;
                }
                let (a, b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
                let (near, far, sn) = if a < b { (a, b, -1.0) } else { (b, a, 1.0) };
                if near > t0 {
                    t0 = near;
                    n0 = Vec3::ZERO;
                    n0[k] = sn;
                }
                if far < t1 {
                    t1 = far;
                    n1 = Vec3::ZERO;
                    n1[k] = -sn;
                }
            }
            if t0 > t1 {
                return None;
            }
            if t0 > EPS {
                Some((t0, n0))
            } else if t1 > EPS {
                Some((t1, n1))
            } else {
                None
            }
        }
        Shape::Plane { point, normal } => {
            let denom = d.dot(normal);
            if denom.abs() < 1e-9 {
                return None;
            }
            let t = (point - o).dot(normal) / denom;
            (t > EPS).then(|| (t, normal.normalize()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_notched_blocks_corner_is_hollow_and_seen_against_the_block() {
        let scene = AnalyticScene::notched_block();
        let [lo, hi] = AnalyticScene::NOTCH;
        let centre = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
        // The notch's centre is empty: 0.25 above its floor, 0.3 from either wall.
        assert!((scene.foreground_distance(centre) - 0.25).abs() < 1e-5);
        // Inside the back wall and the slab, the distance is negative.
        assert!(scene.foreground_distance(Vec3::new(0.2, -0.3, -0.1)) < 0.0);
        assert!(scene.foreground_distance(Vec3::new(0.2, 0.2, -0.45)) < 0.0);
        // A ray straight down the notch meets its floor (the slab, foreground), not the ground.
        let hit = scene
            .trace(Vec3::new(0.2, 0.2, 2.0), Vec3::new(0.0, 0.0, -1.0))
            .unwrap();
        assert!(scene.objects[hit.object].foreground);
        assert!((hit.point.z + 0.35).abs() < 1e-4, "{:?}", hit.point);
    }
}
