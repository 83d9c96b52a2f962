//! Finding where rays meet the zero level set of a signed distance function (IDR's ray
//! tracer), batched over rays with no gradient: sphere tracing from the near end, then, for
//! rays where it stalls or leaves the volume, dense sampling for the first sign change and a
//! secant refinement of it. Rays that meet nothing report where along them the SDF was
//! smallest (IDR's mask loss looks there).

use super::rays::Rays;

/// Settings of the tracer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceOptions {
    /// Sphere-tracing iterations.
    pub max_steps: usize,
    /// A ray has converged when `|f| < eps`.
    pub eps: f32,
    /// Samples per ray of the fallback search.
    pub samples: usize,
    /// Secant iterations refining a sign change.
    pub secant_steps: usize,
}

impl Default for TraceOptions {
    fn default() -> Self {
        Self {
            max_steps: 32,
            eps: 5e-5,
            samples: 96,
            secant_steps: 8,
        }
    }
}

/// Where each ray met the surface.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Traced {
    /// Distance to the surface (meaningful where `hit`).
    pub t: Vec<f32>,
    /// Whether the ray meets the surface inside its interval.
    pub hit: Vec<bool>,
    /// For rays that miss: the distance at which the SDF was smallest along the ray.
    pub t_min_sdf: Vec<f32>,
}

/// Traces `rays` (unit directions, intervals `[near, far]`) against `sdf`, which maps points
/// (`n·3`) to signed distances (`n`), negative inside.
pub fn sphere_trace(
    rays: &Rays,
    opts: &TraceOptions,
    mut sdf: impl FnMut(&[f32]) -> Vec<f32>,
) -> Traced {
    let n = rays.len();
    let mut t = rays.near.clone();
    let mut hit = vec![false; n];
    let mut active: Vec<usize> = (0..n).filter(|&i| rays.far[i] > rays.near[i]).collect();
    let mut points = Vec::new();
    // 1. Sphere tracing from the near end.
    for _ in 0..opts.max_steps {
        if active.is_empty() {
            break;
        }
        points.clear();
        for &i in &active {
            points.extend(rays.point(i, t[i]).to_array());
        }
        let f = sdf(&points);
        let mut still = Vec::with_capacity(active.len());
        for (k, &i) in active.iter().enumerate() {
            let v = f[k];
            if !v.is_finite() {
                continue;
            }
            if v.abs() < opts.eps {
                hit[i] = true;
            } else if v < 0.0 {
                // Started or stepped inside: leave it to the sign-change search.
                continue;
            } else {
                t[i] += v;
                if t[i] < rays.far[i] {
                    still.push(i);
                }
            }
        }
        active = still;
    }
    // 2. Dense sampling for every ray that has not converged.
    let rest: Vec<usize> = (0..n)
        .filter(|&i| !hit[i] && rays.far[i] > rays.near[i])
        .collect();
    let mut t_min = rays.near.clone();
    if !rest.is_empty() && opts.samples >= 2 {
        let m = opts.samples;
        let ts = |i: usize, j: usize| {
            rays.near[i] + (rays.far[i] - rays.near[i]) * j as f32 / (m - 1) as f32
        };
        points.clear();
        for &i in &rest {
            for j in 0..m {
                points.extend(rays.point(i, ts(i, j)).to_array());
            }
        }
        let f = sdf(&points);
        let mut brackets = Vec::new();
        for (k, &i) in rest.iter().enumerate() {
            let fs = &f[k * m..(k + 1) * m];
            let first_inside = (1..m).find(|&j| fs[j] < 0.0 && fs[j - 1] >= 0.0);
            match first_inside {
                Some(j) => brackets.push((i, ts(i, j - 1), fs[j - 1], ts(i, j), fs[j])),
                None => {
                    let (jmin, _) = fs.iter().enumerate().filter(|(_, v)| v.is_finite()).fold(
                        (0, f32::INFINITY),
                        |b, (j, &v)| if v < b.1 { (j, v) } else { b },
                    );
                    t_min[i] = ts(i, jmin);
                }
            }
        }
        // 3. Secant refinement of each sign change, all brackets at once.
        for _ in 0..opts.secant_steps {
            if brackets.is_empty() {
                break;
            }
            points.clear();
            let mids: Vec<f32> = brackets
                .iter()
                .map(|&(_, t0, f0, t1, f1)| {
                    let d = f1 - f0;
                    if d.abs() > 1e-12 {
                        (t0 - f0 * (t1 - t0) / d).clamp(t0, t1)
                    } else {
                        0.5 * (t0 + t1)
                    }
                })
                .collect();
            for (b, &tm) in brackets.iter().zip(&mids) {
                points.extend(rays.point(b.0, tm).to_array());
            }
            let f = sdf(&points);
            for ((b, &tm), &fm) in brackets.iter_mut().zip(&mids).zip(&f) {
                if fm >= 0.0 {
                    b.1 = tm;
                    b.2 = fm;
                } else {
                    b.3 = tm;
                    b.4 = fm;
                }
            }
        }
        for (i, t0, f0, t1, f1) in brackets {
            let d = f1 - f0;
            t[i] = if d.abs() > 1e-12 {
                t0 - f0 * (t1 - t0) / d
            } else {
                0.5 * (t0 + t1)
            };
            hit[i] = true;
        }
    }
    Traced {
        t,
        hit,
        t_min_sdf: t_min,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::Vec3;

    fn sphere(points: &[f32]) -> Vec<f32> {
        points
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]).length() - 0.5)
            .collect()
    }

    fn cube(points: &[f32]) -> Vec<f32> {
        // Exact SDF of the box |x|,|y|,|z| ≤ 0.3.
        points
            .chunks_exact(3)
            .map(|p| {
                let q = Vec3::new(p[0].abs(), p[1].abs(), p[2].abs()) - Vec3::splat(0.3);
                q.max(Vec3::ZERO).length() + q.max_element().min(0.0)
            })
            .collect()
    }

    fn rays() -> Rays {
        let mut r = Rays::default();
        for i in 0..50 {
            let y = -0.7 + 1.4 * i as f32 / 49.0;
            let o = Vec3::new(0.1, y, 2.0);
            r.push(o, Vec3::NEG_Z, 0.5, 3.5);
        }
        r
    }

    #[test]
    fn hits_an_analytic_sphere_at_the_known_depth() {
        let r = rays();
        let out = sphere_trace(&r, &TraceOptions::default(), sphere);
        for i in 0..r.len() {
            let (x, y) = (r.origins[i].x, r.origins[i].y);
            let rr = x * x + y * y;
            if rr < 0.49 * 0.49 {
                assert!(out.hit[i], "ray {i} missed");
                let want = 2.0 - (0.25 - rr).sqrt();
                assert!(
                    (out.t[i] - want).abs() < 1e-3,
                    "ray {i}: {} vs {want}",
                    out.t[i]
                );
            } else if rr > 0.51 * 0.51 {
                assert!(!out.hit[i], "ray {i} should miss");
                // The closest approach is the sphere's nearest point along the ray: t = 2.
                assert!(
                    (out.t_min_sdf[i] - 2.0).abs() < 0.05,
                    "ray {i}: {}",
                    out.t_min_sdf[i]
                );
            }
        }
    }

    #[test]
    fn hits_a_box_at_its_face() {
        let r = rays();
        let out = sphere_trace(&r, &TraceOptions::default(), cube);
        for i in 0..r.len() {
            let y = r.origins[i].y;
            if y.abs() < 0.29 {
                assert!(
                    out.hit[i] && (out.t[i] - 1.7).abs() < 1e-3,
                    "ray {i}: {:?}",
                    (out.hit[i], out.t[i])
                );
            } else if y.abs() > 0.31 {
                assert!(!out.hit[i]);
            }
        }
    }

    #[test]
    fn a_thin_shell_missed_by_sphere_tracing_is_found_by_the_search() {
        // A non-metric field (scaled ×8) makes sphere tracing overshoot; the sign-change
        // search and the secant still find the surface.
        let r = rays();
        let scaled = |p: &[f32]| sphere(p).into_iter().map(|v| v * 8.0).collect::<Vec<_>>();
        let out = sphere_trace(&r, &TraceOptions::default(), scaled);
        let i = 25;
        let (x, y) = (r.origins[i].x, r.origins[i].y);
        let want = 2.0 - (0.25 - x * x - y * y).sqrt();
        assert!(
            out.hit[i] && (out.t[i] - want).abs() < 1e-3,
            "{} vs {want}",
            out.t[i]
        );
    }
}
