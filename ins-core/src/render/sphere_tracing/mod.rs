//! Finding where rays meet the zero level set of a signed distance function (IDR's ray
//! tracer), batched over rays with no gradient.
//!
//! 1. Sphere tracing from the near end. A ray that steps from outside to inside is bracketed
//!    by its last two steps; one that converges is a hit.
//! 2. The rest are searched by sampling the ray for its first sign change, then refined by
//!    secant steps. How densely depends on what the march saw. A ray that left the volume
//!    without ever coming closer than [`TraceOptions::clear_miss`] to the surface is a clear
//!    miss: a coarse check (which still catches a field that overstates distances by far) and
//!    nothing more. Every other ray gets the full search, then a finer look around its closest
//!    sample (thin parts hide between samples).
//!
//! Rays that meet nothing report where along them the SDF was smallest (IDR's mask loss
//! looks there): for a clear miss the vertex of the parabola through its three march samples
//! around the smallest value, for the others the smallest of all their samples.

use ins_scene::rays::Rays;

pub mod device;
mod records;

use records::{Bracket, Closest, MarchMinimum, Stretch};

/// Settings of the tracer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceOptions {
    /// Sphere-tracing iterations.
    pub max_steps: usize,
    /// A ray has converged when `|f| < eps`.
    pub eps: f32,
    /// Samples per ray of the full search.
    pub samples: usize,
    /// Samples per ray of the check on clear misses.
    pub coarse_samples: usize,
    /// Samples in the window of two spacings around a fully searched ray's closest sample.
    pub refine_samples: usize,
    /// A ray that left the volume with the SDF above this all along its march is a clear
    /// miss (in the scene's units; the full search's spacing on a unit sphere's diameter is
    /// about 0.02).
    pub clear_miss: f32,
    /// Secant iterations refining a sign change.
    pub secant_steps: usize,
}

impl Default for TraceOptions {
    fn default() -> Self {
        Self {
            max_steps: 32,
            eps: 5e-5,
            samples: 96,
            coarse_samples: 8,
            refine_samples: 12,
            clear_miss: 0.05,
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

/// Samples every stretch at once; each ray's first sign change becomes a bracket, and every
/// sample is offered to `closest`. Returns the brackets and the stretches without one.
fn search(
    rays: &Rays,
    stretches: &[Stretch],
    closest: &mut Closest,
    sdf: &mut impl FnMut(&[f32]) -> Vec<f32>,
) -> (Vec<Bracket>, Vec<(Stretch, usize)>) {
    let mut points = Vec::with_capacity(3 * stretches.iter().map(|s| s.count).sum::<usize>());
    for s in stretches {
        for j in 0..s.count {
            points.extend(rays.point(s.ray, s.at(j)).to_array());
        }
    }
    let f = sdf(&points);
    let (mut brackets, mut open) = (Vec::new(), Vec::new());
    let mut at = 0;
    for s in stretches {
        let fs = &f[at..at + s.count];
        at += s.count;
        for (j, &v) in fs.iter().enumerate() {
            closest.offer(s.ray, s.at(j), v);
        }
        match (1..s.count).find(|&j| fs[j] < 0.0 && fs[j - 1] >= 0.0) {
            Some(j) => brackets.push(Bracket {
                ray: s.ray,
                t0: s.at(j - 1),
                f0: fs[j - 1],
                t1: s.at(j),
                f1: fs[j],
            }),
            None => {
                let (jmin, _) = fs.iter().enumerate().filter(|(_, v)| v.is_finite()).fold(
                    (0, f32::INFINITY),
                    |b, (j, &v)| if v < b.1 { (j, v) } else { b },
                );
                open.push((*s, jmin));
            }
        }
    }
    (brackets, open)
}

/// Traces `rays` (unit directions, intervals `[near, far]`) against `sdf`, which maps points
/// (`n·3`) to signed distances (`n`), negative inside.
pub fn sphere_trace(
    rays: &Rays,
    opts: &TraceOptions,
    mut sdf: impl FnMut(&[f32]) -> Vec<f32>,
) -> Traced {
    let mut m = march(rays, opts, &mut sdf);
    let clear = search_the_rest(rays, opts, &mut m, &mut sdf);
    refine_by_secant(rays, opts, &mut m.brackets, &mut sdf);
    conclude(m, &clear)
}

/// What the march (step 1) leaves for the search and the secant.
struct Marched {
    /// Where each ray's march stopped.
    t: Vec<f32>,
    /// Rays that converged.
    hit: Vec<bool>,
    /// Each ray's closest sample.
    closest: Closest,
    /// Sign changes the march stepped over.
    brackets: Vec<Bracket>,
    /// Rays that left their interval.
    exited: Vec<bool>,
    /// Each ray's smallest march sample with its neighbours.
    march_min: Vec<MarchMinimum>,
}

/// Step 1, sphere tracing from the near end: the rays still marching are evaluated each round.
fn march(rays: &Rays, opts: &TraceOptions, sdf: &mut impl FnMut(&[f32]) -> Vec<f32>) -> Marched {
    let n = rays.len();
    let mut t = rays.near.clone();
    let mut hit = vec![false; n];
    let mut closest = Closest {
        t: rays.near.clone(),
        f: vec![f32::INFINITY; n],
    };
    let mut brackets = Vec::new();
    // Rays that left the volume: clear misses get the coarse check, the rest the full search.
    let mut exited = vec![false; n];
    // The last sample of each ray, outside the surface.
    let mut last = vec![(0f32, f32::NAN); n];
    let mut march_min = vec![MarchMinimum::EMPTY; n];
    let mut active: Vec<usize> = (0..n).filter(|&i| rays.far[i] > rays.near[i]).collect();
    let mut points = Vec::new();
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
            closest.offer(i, t[i], v);
            march_min[i].offer(last[i], (t[i], v));
            if v.abs() < opts.eps {
                hit[i] = true;
            } else if v < 0.0 {
                // Stepped inside: the previous step, outside, closes the bracket. A ray that
                // starts inside has none and goes to the full search.
                let (t0, f0) = last[i];
                if f0.is_finite() {
                    brackets.push(Bracket {
                        ray: i,
                        t0,
                        f0,
                        t1: t[i],
                        f1: v,
                    });
                }
            } else {
                last[i] = (t[i], v);
                t[i] += v;
                if t[i] < rays.far[i] {
                    still.push(i);
                } else {
                    exited[i] = true;
                }
            }
        }
        active = still;
    }
    Marched {
        t,
        hit,
        closest,
        brackets,
        exited,
        march_min,
    }
}

/// Step 2, sampling every ray that has neither converged nor been bracketed: the sign changes
/// found join `m.brackets`. Returns the clear misses.
fn search_the_rest(
    rays: &Rays,
    opts: &TraceOptions,
    m: &mut Marched,
    sdf: &mut impl FnMut(&[f32]) -> Vec<f32>,
) -> Vec<bool> {
    let n = rays.len();
    let bracketed: Vec<bool> = {
        let mut b = vec![false; n];
        for br in &m.brackets {
            b[br.ray] = true;
        }
        b
    };
    let clear: Vec<bool> = (0..n)
        .map(|i| m.exited[i] && m.closest.f[i] > opts.clear_miss)
        .collect();
    let stretches: Vec<Stretch> = (0..n)
        .filter(|&i| !m.hit[i] && !bracketed[i] && rays.far[i] > rays.near[i])
        .map(|i| Stretch {
            ray: i,
            t0: rays.near[i],
            t1: rays.far[i],
            count: if clear[i] {
                opts.coarse_samples
            } else {
                opts.samples
            },
        })
        .filter(|s| s.count >= 2)
        .collect();
    let (found, open) = search(rays, &stretches, &mut m.closest, sdf);
    m.brackets.extend(found);
    // A finer look around the closest sample of each fully searched ray without a crossing.
    if opts.refine_samples >= 2 {
        let windows: Vec<Stretch> = open
            .iter()
            .filter(|(s, _)| !clear[s.ray])
            .map(|&(s, j)| {
                let step = (s.t1 - s.t0) / (s.count - 1).max(1) as f32;
                let centre = s.at(j);
                Stretch {
                    ray: s.ray,
                    t0: (centre - step).max(s.t0),
                    t1: (centre + step).min(s.t1),
                    count: opts.refine_samples,
                }
            })
            .collect();
        let (found, _) = search(rays, &windows, &mut m.closest, sdf);
        m.brackets.extend(found);
    }
    clear
}

/// Step 3, secant refinement of each sign change, all brackets at once.
fn refine_by_secant(
    rays: &Rays,
    opts: &TraceOptions,
    brackets: &mut [Bracket],
    sdf: &mut impl FnMut(&[f32]) -> Vec<f32>,
) {
    let mut points = Vec::new();
    for _ in 0..opts.secant_steps {
        if brackets.is_empty() {
            break;
        }
        points.clear();
        let mids: Vec<f32> = brackets.iter().map(Bracket::secant).collect();
        for (b, &tm) in brackets.iter().zip(&mids) {
            points.extend(rays.point(b.ray, tm).to_array());
        }
        let f = sdf(&points);
        for ((b, &tm), &fm) in brackets.iter_mut().zip(&mids).zip(&f) {
            if fm >= 0.0 {
                b.t0 = tm;
                b.f0 = fm;
            } else {
                b.t1 = tm;
                b.f1 = fm;
            }
        }
    }
}

/// The hits (each bracket's secant estimate) and the misses' closest approaches.
fn conclude(m: Marched, clear: &[bool]) -> Traced {
    let Marched {
        mut t,
        mut hit,
        mut closest,
        brackets,
        march_min,
        ..
    } = m;
    for b in &brackets {
        t[b.ray] = b.secant();
        hit[b.ray] = true;
    }
    // A clear miss's closest approach: its march samples are about as far apart as the ray is
    // from the surface there, and the parabola through them finds the minimum between them.
    for i in 0..t.len() {
        if clear[i] && !hit[i] && march_min[i].at.1 <= closest.f[i] {
            closest.t[i] = march_min[i].vertex();
        }
    }
    Traced {
        t,
        hit,
        t_min_sdf: closest.t,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ins_scene::geometry::Vec3;

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
    fn a_ray_that_steps_inside_is_bracketed_by_its_march() {
        // A field that overstates distances by half makes the march step through the
        // surface; the last two steps bracket it, with no search along the ray.
        let r = rays();
        let calls = std::cell::Cell::new(0usize);
        let overstated = |p: &[f32]| {
            calls.set(calls.get() + p.len() / 3);
            sphere(p).into_iter().map(|v| v * 1.5).collect::<Vec<_>>()
        };
        let out = sphere_trace(&r, &TraceOptions::default(), overstated);
        let i = 25;
        let (x, y) = (r.origins[i].x, r.origins[i].y);
        let want = 2.0 - (0.25 - x * x - y * y).sqrt();
        assert!(
            out.hit[i] && (out.t[i] - want).abs() < 1e-4,
            "{} vs {want}",
            out.t[i]
        );
        // Every ray through the sphere was bracketed by its march: the only samples beyond
        // the march and secant steps are the clear misses' coarse checks.
        let through = (0..r.len()).filter(|&i| out.hit[i]).count();
        let opts = TraceOptions::default();
        let bound = r.len() * opts.max_steps
            + (r.len() - through) * opts.coarse_samples
            + through * opts.secant_steps;
        assert!(calls.get() <= bound, "{} samples > {bound}", calls.get());
    }

    #[test]
    fn clear_misses_cost_only_the_coarse_check() {
        let mut r = Rays::default();
        for i in 0..20 {
            // Passing 0.2 or more beside the sphere of radius 0.5.
            r.push(
                Vec3::new(0.7 + 0.01 * i as f32, 0.0, 2.0),
                Vec3::NEG_Z,
                0.5,
                3.5,
            );
        }
        let calls = std::cell::Cell::new(0usize);
        let counted = |p: &[f32]| {
            calls.set(calls.get() + p.len() / 3);
            sphere(p)
        };
        let opts = TraceOptions::default();
        let out = sphere_trace(&r, &opts, counted);
        assert!(out.hit.iter().all(|&h| !h));
        assert!(
            calls.get() <= r.len() * (opts.max_steps + opts.coarse_samples),
            "{} samples",
            calls.get()
        );
        // The parabola through the march samples around the smallest value puts the closest
        // approach (t = 2) well inside the march's own spacing (about 0.2 here).
        for i in 0..r.len() {
            assert!(
                (out.t_min_sdf[i] - 2.0).abs() < 0.02,
                "{}",
                out.t_min_sdf[i]
            );
        }
    }

    #[test]
    fn a_near_miss_finds_its_closest_approach_finer_than_the_samples() {
        // Rays passing 0.01–0.03 beside the sphere: the closest approach is at t = 2, and
        // the search refines it well below its own spacing (3 / 95 ≈ 0.03).
        let mut r = Rays::default();
        for y in [0.51f32, 0.52, 0.53] {
            r.push(Vec3::new(0.0, y, 2.0), Vec3::NEG_Z, 0.5, 3.5);
        }
        let out = sphere_trace(&r, &TraceOptions::default(), sphere);
        for i in 0..r.len() {
            assert!(!out.hit[i]);
            assert!(
                (out.t_min_sdf[i] - 2.0).abs() < 0.005,
                "ray {i}: {}",
                out.t_min_sdf[i]
            );
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
