//! Built-in demo inputs, so that a first run needs no files: a small shaded scene (content,
//! generated) and a real painting shipped small in the binary, Raphael's *Bridgewater Madonna*
//! (public domain; `assets/README.md`). A generated brush-stroke image ([`demo_style`]) is the
//! tests' synthetic style.

use ins_core::imaging::RgbImage;

fn hash(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(374_761_393)
        ^ (y as u32).wrapping_mul(668_265_263)
        ^ seed.wrapping_mul(2_246_822_519);
    h = (h ^ (h >> 13)).wrapping_mul(1_274_126_177);
    (h ^ (h >> 16)) as f32 / u32::MAX as f32
}

fn value_noise(x: f32, y: f32, seed: u32) -> f32 {
    let (xi, yi) = (x.floor() as i32, y.floor() as i32);
    let (fx, fy) = (x - xi as f32, y - yi as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let a = hash(xi, yi, seed);
    let b = hash(xi + 1, yi, seed);
    let c = hash(xi, yi + 1, seed);
    let d = hash(xi + 1, yi + 1, seed);
    (a + (b - a) * sx) + ((c + (d - c) * sx) - (a + (b - a) * sx)) * sy
}

fn fbm(x: f32, y: f32, seed: u32) -> f32 {
    (0..4)
        .map(|o| value_noise(x * (1 << o) as f32, y * (1 << o) as f32, seed + o) / (1 << o) as f32)
        .sum::<f32>()
        / 1.875
}

/// A `size`×`size` content image: two shaded spheres on a checkered floor under a sky.
pub fn demo_content(size: usize) -> RgbImage {
    let mut data = Vec::with_capacity(size * size * 3);
    let light = normalize([-0.5, 0.8, 0.6]);
    let spheres = [
        ([-0.45f32, 0.0, -3.2], 0.55f32, [0.85f32, 0.25, 0.2]),
        ([0.6, -0.15, -2.8], 0.4, [0.2, 0.45, 0.85]),
    ];
    for v in 0..size {
        for u in 0..size {
            let x = (u as f32 + 0.5) / size as f32 * 2.0 - 1.0;
            let y = 1.0 - (v as f32 + 0.5) / size as f32 * 2.0;
            let d = normalize([x * 0.8, y * 0.8, -1.0]);
            let mut best = f32::INFINITY;
            let mut col = {
                let t = (y + 1.0) / 2.0;
                [0.95 - 0.4 * t, 0.85 - 0.25 * t, 0.75 + 0.2 * t]
            };
            // Floor y = −0.55.
            if d[1] < -1e-3 {
                let t = -0.55 / d[1];
                if t < best {
                    best = t;
                    let px = d[0] * t;
                    let pz = d[2] * t;
                    let check =
                        ((px * 2.0).floor() as i32 + (pz * 2.0).floor() as i32).rem_euclid(2);
                    let base = if check == 0 {
                        [0.9, 0.88, 0.8]
                    } else {
                        [0.35, 0.3, 0.28]
                    };
                    let fade = (1.0 / (1.0 + 0.08 * t * t)).max(0.3);
                    col = base.map(|c| c * fade + 0.6 * (1.0 - fade));
                }
            }
            for (c, r, albedo) in spheres {
                let oc = [-c[0], -c[1], -c[2]];
                let b = dot(oc, d);
                let disc = b * b - (dot(oc, oc) - r * r);
                if disc > 0.0 {
                    let t = -b - disc.sqrt();
                    if t > 0.0 && t < best {
                        best = t;
                        let p = [d[0] * t, d[1] * t, d[2] * t];
                        let n = normalize([p[0] - c[0], p[1] - c[1], p[2] - c[2]]);
                        let diffuse = dot(n, light).max(0.0);
                        let h = normalize([light[0] - d[0], light[1] - d[1], light[2] - d[2]]);
                        let spec = dot(n, h).max(0.0).powf(40.0);
                        col = albedo.map(|a| (a * (0.25 + 0.75 * diffuse) + 0.6 * spec).min(1.0));
                    }
                }
            }
            data.extend(col);
        }
    }
    RgbImage {
        width: size,
        height: size,
        data,
    }
}

/// The demo's painting: Raphael, *The Bridgewater Madonna* (c. 1507), 192×284.
pub fn demo_painting() -> RgbImage {
    static JPEG: &[u8] = include_bytes!("../assets/bridgewater_madonna.jpg");
    // The file is part of the binary; failing to decode it is a build defect.
    let img = image::load_from_memory(JPEG)
        .unwrap_or_else(|e| panic!("the embedded demo painting does not decode: {e}"))
        .to_rgb8();
    RgbImage {
        width: img.width() as usize,
        height: img.height() as usize,
        data: img.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
    }
}

/// A `size`×`size` synthetic style image: short brush strokes following a swirling flow, in a
/// night-sky palette of blues and yellows.
pub fn demo_style(size: usize) -> RgbImage {
    let palette = [
        [0.05f32, 0.1, 0.3],
        [0.1, 0.25, 0.55],
        [0.3, 0.5, 0.8],
        [0.95, 0.85, 0.3],
        [0.85, 0.6, 0.15],
    ];
    let mut data = Vec::with_capacity(size * size * 3);
    for v in 0..size {
        for u in 0..size {
            let x = u as f32 / size as f32 * 6.0;
            let y = v as f32 / size as f32 * 6.0;
            // Flow angle from noise; strokes are stripes along the flow.
            let angle = fbm(x * 0.5, y * 0.5, 7) * std::f32::consts::TAU * 2.0;
            let (s, c) = angle.sin_cos();
            let along = x * c + y * s;
            let across = -x * s + y * c;
            let stroke = ((across * 9.0).sin() * 0.5 + 0.5) * (0.7 + 0.3 * (along * 2.0).sin());
            let tone = (fbm(x, y, 3) * 0.6 + stroke * 0.4).clamp(0.0, 0.999);
            let idx = tone * (palette.len() - 1) as f32;
            let (i, f) = (idx.floor() as usize, idx.fract());
            let a = palette[i];
            let b = palette[(i + 1).min(palette.len() - 1)];
            let grain = 0.9 + 0.1 * hash(u as i32, v as i32, 11);
            data.extend([0, 1, 2].map(|k| ((a[k] + (b[k] - a[k]) * f) * grain).clamp(0.0, 1.0)));
        }
    }
    RgbImage {
        width: size,
        height: size,
        data,
    }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let n = dot(a, a).sqrt().max(1e-12);
    a.map(|v| v / n)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_demo_painting_decodes_at_its_size() {
        let p = super::demo_painting();
        assert_eq!((p.width, p.height), (192, 284));
        assert!(p.data.iter().all(|v| (0.0..=1.0).contains(v)));
    }
}
