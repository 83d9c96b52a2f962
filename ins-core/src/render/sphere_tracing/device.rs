//! [`sphere_trace`](super::sphere_trace) for GPUs: the same three steps, with
//! the march's rounds and the secant's kept on the device.
//!
//! Why: the host's tracer reads the SDF back once a round, up to 42 times a trace (32 march
//! rounds, two searches, 8 secant steps), and a GPU waits for the host at each read. Here every
//! ray is evaluated in every march round (no shrinking set to choose on the host) and its state
//! is kept as masks; one read ends the march, the search stays on the host (two reads, over the
//! rays the march left open), and the secant runs its fixed rounds on the device with one read.
//! Four reads a trace. On a CPU the host's tracer stays: it evaluates only the rays still going.

use burn::prelude::*;
use ins_scene::rays::Rays;

use super::records::{Bracket, Closest, MarchMinimum};
use super::{Marched, TraceOptions, Traced, conclude, search_the_rest};
use crate::shape_buckets::{pad_rows, padded_size};

/// Traces `rays` against `sdf` (points `[N, 3]` → signed distances `[N]`, no gradient) on
/// `device`, giving what [`sphere_trace`](super::sphere_trace) gives.
pub fn sphere_trace_on_device(
    rays: &Rays,
    opts: &TraceOptions,
    sdf: impl Fn(Tensor<2>) -> Tensor<1>,
    device: &Device,
) -> Traced {
    let mut host_sdf = |points: &[f32]| sdf_on_host(&sdf, points, device);
    let mut m = march(rays, opts, &sdf, device);
    let clear = search_the_rest(rays, opts, &mut m, &mut host_sdf);
    secant(rays, opts, &mut m.brackets, &sdf, device);
    conclude(m, &clear)
}

/// Points evaluated at once by the search: its samples of a whole view's chunk of rays run to
/// millions, each carrying the network's activations.
const POINTS_AT_ONCE: usize = 65536;

/// `sdf` at host points in chunks (each padded to a size bucket so its kernels are reused),
/// read back in one transfer.
fn sdf_on_host(sdf: &impl Fn(Tensor<2>) -> Tensor<1>, points: &[f32], device: &Device) -> Vec<f32> {
    let n = points.len() / 3;
    if n == 0 {
        return Vec::new();
    }
    let mut values = Vec::new();
    let mut counts = Vec::new();
    for chunk in points.chunks(3 * POINTS_AT_ONCE) {
        let m = chunk.len() / 3;
        let rows = padded_size(m, device);
        let mut padded = chunk.to_vec();
        pad_rows(&mut padded, 3, rows);
        let x = Tensor::<1>::from_floats(padded.as_slice(), device).reshape([rows, 3]);
        values.push(sdf(x).reshape([rows]));
        counts.push((m, rows));
    }
    let all = read(Tensor::cat(values, 0));
    let mut out = Vec::with_capacity(n);
    let mut at = 0;
    for (m, rows) in counts {
        out.extend_from_slice(&all[at..at + m]);
        at += rows;
    }
    out
}

fn read(t: Tensor<1>) -> Vec<f32> {
    let n = t.dims()[0];
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap_or_else(|_| vec![f32::NAN; n])
}

/// Rows `[R, 3]` of host vectors, padded to `rows` with the first.
fn rows_of(v: impl Iterator<Item = [f32; 3]>, rows: usize, device: &Device) -> Tensor<2> {
    let mut flat: Vec<f32> = v.flatten().collect();
    pad_rows(&mut flat, 3, rows);
    Tensor::<1>::from_floats(flat.as_slice(), device).reshape([rows, 3])
}

/// A host column padded to `rows` with `fill`.
fn column(v: impl Iterator<Item = f32>, rows: usize, fill: f32, device: &Device) -> Tensor<1> {
    let mut c: Vec<f32> = v.collect();
    c.resize(rows, fill);
    Tensor::from_floats(c.as_slice(), device)
}

/// A pair of a ray's samples kept by the march: `(t, f)` and whether it is set.
#[derive(Clone)]
struct Sample {
    t: Tensor<1>,
    f: Tensor<1>,
    set: Tensor<1, Bool>,
}

impl Sample {
    fn unset(rows: usize, device: &Device) -> Self {
        Self {
            t: Tensor::zeros([rows], device),
            f: Tensor::zeros([rows], device),
            set: Tensor::<1>::zeros([rows], device).greater_elem(0.0),
        }
    }

    /// `other` where `mask`, `self` elsewhere.
    fn take(self, mask: &Tensor<1, Bool>, other: &Sample) -> Self {
        Self {
            t: self.t.mask_where(mask.clone(), other.t.clone()),
            f: self.f.mask_where(mask.clone(), other.f.clone()),
            set: self.set.mask_where(mask.clone(), other.set.clone()),
        }
    }

    /// The host's `(t, f)`, NaN where unset.
    fn host(t: &[f32], f: &[f32], set: &[f32]) -> Vec<(f32, f32)> {
        (0..t.len())
            .map(|i| {
                if set[i] > 0.5 {
                    (t[i], f[i])
                } else {
                    MarchMinimum::NONE
                }
            })
            .collect()
    }
}

/// Step 1 on the device: every round evaluates every ray, the ones still marching move.
fn march(
    rays: &Rays,
    opts: &TraceOptions,
    sdf: &impl Fn(Tensor<2>) -> Tensor<1>,
    device: &Device,
) -> Marched {
    let n = rays.len();
    let rows = padded_size(n.max(1), device);
    let origins = rows_of(rays.origins.iter().map(|o| o.to_array()), rows, device);
    let dirs = rows_of(rays.directions.iter().map(|d| d.to_array()), rows, device);
    let near = column(rays.near.iter().copied(), rows, 0.0, device);
    // Padding rows have an empty interval and never march.
    let far = column(rays.far.iter().copied(), rows, 0.0, device);
    let mut t = near.clone();
    let mut active = far.clone().greater(near.clone());
    let never = active.clone().bool_and(active.clone().bool_not());
    let mut hit = never.clone();
    let mut exited = never.clone();
    let mut last = Sample::unset(rows, device);
    let mut closest = Sample::unset(rows, device);
    let (mut before, mut at, mut after) = (last.clone(), last.clone(), last.clone());
    let mut bracket0 = last.clone();
    let mut bracket1 = last.clone();
    for _ in 0..opts.max_steps {
        let x = origins.clone() + dirs.clone() * t.clone().reshape([rows, 1]);
        let v = sdf(x).reshape([rows]);
        let ok = active
            .clone()
            .bool_and(v.clone().is_nan().bool_or(v.clone().is_inf()).bool_not());
        let now = Sample {
            t: t.clone(),
            f: v.clone(),
            set: ok.clone(),
        };
        let closer = ok.clone().bool_and(
            closest
                .set
                .clone()
                .bool_not()
                .bool_or(v.clone().lower(closest.f.clone())),
        );
        closest = closest.take(&closer, &now);
        // The march's smallest sample with the one before it (the last outside) and after it.
        let lower = ok.clone().bool_and(
            at.set
                .clone()
                .bool_not()
                .bool_or(v.clone().lower(at.f.clone())),
        );
        let first_after = ok
            .clone()
            .bool_and(lower.clone().bool_not())
            .bool_and(after.set.clone().bool_not());
        before = before.take(&lower, &last);
        at = at.take(&lower, &now);
        after = after
            .take(&lower, &Sample::unset(rows, device))
            .take(&first_after, &now);
        let converged = ok.clone().bool_and(v.clone().abs().lower_elem(opts.eps));
        hit = hit.bool_or(converged.clone());
        let going = ok.bool_and(converged.bool_not());
        let inside = going.clone().bool_and(v.clone().lower_elem(0.0));
        // Stepped inside: the last sample outside closes the bracket (none if it started in).
        let closes = inside.bool_and(last.set.clone());
        bracket0 = bracket0.take(&closes, &last);
        bracket1 = bracket1.take(&closes, &now);
        let outside = going.bool_and(v.clone().greater_equal_elem(0.0));
        last = last.take(&outside, &now);
        t = t.clone().mask_where(outside.clone(), t + v);
        let within = t.clone().lower(far.clone());
        exited = exited.bool_or(outside.clone().bool_and(within.clone().bool_not()));
        active = outside.bool_and(within);
    }
    let flag = |b: Tensor<1, Bool>| b.float();
    let parts = vec![
        t,
        flag(hit),
        flag(exited),
        closest.t,
        closest.f,
        flag(closest.set),
        before.t,
        before.f,
        flag(before.set),
        at.t,
        at.f,
        flag(at.set),
        after.t,
        after.f,
        flag(after.set),
        bracket0.t,
        bracket0.f,
        bracket1.t,
        bracket1.f,
        flag(bracket1.set),
    ];
    let k = parts.len();
    let all = read(Tensor::cat(parts, 0));
    let part = |j: usize| &all[j * rows..j * rows + n];
    let set = |j: usize| part(j).iter().map(|&v| v > 0.5).collect::<Vec<bool>>();
    debug_assert_eq!(all.len(), k * rows);
    let closest_set = set(5);
    let closest = Closest {
        t: (0..n)
            .map(|i| {
                if closest_set[i] {
                    part(3)[i]
                } else {
                    rays.near[i]
                }
            })
            .collect(),
        f: (0..n)
            .map(|i| {
                if closest_set[i] {
                    part(4)[i]
                } else {
                    f32::INFINITY
                }
            })
            .collect(),
    };
    let before = Sample::host(part(6), part(7), part(8));
    let at = Sample::host(part(9), part(10), part(11));
    let after = Sample::host(part(12), part(13), part(14));
    let march_min = (0..n)
        .map(|i| MarchMinimum {
            before: before[i],
            at: at[i],
            after: after[i],
        })
        .collect();
    let bracketed = set(19);
    let brackets = (0..n)
        .filter(|&i| bracketed[i])
        .map(|i| Bracket {
            ray: i,
            t0: part(15)[i],
            f0: part(16)[i],
            t1: part(17)[i],
            f1: part(18)[i],
        })
        .collect();
    Marched {
        t: part(0).to_vec(),
        hit: set(1),
        closest,
        brackets,
        exited: set(2),
        march_min,
    }
}

/// Step 3 on the device: the secant's rounds over all brackets at once, one read at the end.
fn secant(
    rays: &Rays,
    opts: &TraceOptions,
    brackets: &mut [Bracket],
    sdf: &impl Fn(Tensor<2>) -> Tensor<1>,
    device: &Device,
) {
    if brackets.is_empty() || opts.secant_steps == 0 {
        return;
    }
    let n = brackets.len();
    let rows = padded_size(n, device);
    let origins = rows_of(
        brackets.iter().map(|b| rays.origins[b.ray].to_array()),
        rows,
        device,
    );
    let dirs = rows_of(
        brackets.iter().map(|b| rays.directions[b.ray].to_array()),
        rows,
        device,
    );
    let col = |f: fn(&Bracket) -> f32| column(brackets.iter().map(f), rows, 0.0, device);
    let (mut t0, mut f0) = (col(|b| b.t0), col(|b| b.f0));
    let (mut t1, mut f1) = (col(|b| b.t1), col(|b| b.f1));
    for _ in 0..opts.secant_steps {
        let tm = secant_estimate(&t0, &f0, &t1, &f1);
        let x = origins.clone() + dirs.clone() * tm.clone().reshape([rows, 1]);
        let fm = sdf(x).reshape([rows]);
        let outside = fm.clone().greater_equal_elem(0.0);
        let inside = outside.clone().bool_not();
        t0 = t0.mask_where(outside.clone(), tm.clone());
        f0 = f0.mask_where(outside, fm.clone());
        t1 = t1.mask_where(inside.clone(), tm);
        f1 = f1.mask_where(inside, fm);
    }
    let ends = read(Tensor::cat(vec![t0, f0, t1, f1], 0));
    for (i, b) in brackets.iter_mut().enumerate() {
        b.t0 = ends[i];
        b.f0 = ends[rows + i];
        b.t1 = ends[2 * rows + i];
        b.f1 = ends[3 * rows + i];
    }
}

/// [`Bracket::secant`] on columns.
fn secant_estimate(t0: &Tensor<1>, f0: &Tensor<1>, t1: &Tensor<1>, f1: &Tensor<1>) -> Tensor<1> {
    let d = f1.clone() - f0.clone();
    let flat = d.clone().abs().lower_equal_elem(1e-12);
    // Where the two values are equal the division is replaced before it can matter.
    let safe = d.mask_fill(flat.clone(), 1.0);
    let along = (t0.clone() - f0.clone() * (t1.clone() - t0.clone()) / safe)
        .max_pair(t0.clone())
        .min_pair(t1.clone());
    along.mask_where(flat, (t0.clone() + t1.clone()).mul_scalar(0.5))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sphere_tracing::sphere_trace;
    use ins_scene::geometry::Vec3;

    /// The sphere of radius 0.5, scaled by `k` (`k` > 1 overstates distances).
    fn sphere_tensor(k: f32) -> impl Fn(Tensor<2>) -> Tensor<1> {
        move |x: Tensor<2>| {
            let [n, _] = x.dims();
            x.square()
                .sum_dim(1)
                .sqrt()
                .sub_scalar(0.5)
                .mul_scalar(k)
                .reshape([n])
        }
    }

    fn sphere_host(k: f32) -> impl FnMut(&[f32]) -> Vec<f32> {
        move |p: &[f32]| {
            p.chunks_exact(3)
                .map(|p| (Vec3::new(p[0], p[1], p[2]).length() - 0.5) * k)
                .collect()
        }
    }

    /// Rays through, beside and far from the sphere, one starting inside it, one with an
    /// empty interval.
    fn rays() -> Rays {
        let mut r = Rays::default();
        for i in 0..60 {
            let y = -0.8 + 1.6 * i as f32 / 59.0;
            r.push(Vec3::new(0.13, y, 2.0), Vec3::NEG_Z, 0.5, 3.5);
        }
        r.push(Vec3::new(0.0, 0.0, 0.1), Vec3::NEG_Z, 0.0, 1.0);
        r.push(Vec3::new(0.0, 0.0, 2.0), Vec3::NEG_Z, 1.0, 1.0);
        for y in [0.505f32, 0.52, 0.55] {
            r.push(Vec3::new(0.0, y, 2.0), Vec3::NEG_Z, 0.5, 3.5);
        }
        r
    }

    /// The device's march and secant give the host tracer's hits, depths and closest
    /// approaches: an exact field, one overstating distances (the march steps inside: its
    /// brackets) and one overstating them eightfold (the search finds what the march missed).
    #[test]
    fn the_device_traces_what_the_host_traces() {
        let device = Device::flex();
        let r = rays();
        for k in [1.0f32, 1.5, 8.0] {
            let host = sphere_trace(&r, &TraceOptions::default(), sphere_host(k));
            let dev =
                sphere_trace_on_device(&r, &TraceOptions::default(), sphere_tensor(k), &device);
            assert_eq!(dev.hit, host.hit, "k = {k}: hits");
            assert!(
                host.hit.iter().filter(|&&h| h).count() > 20,
                "k = {k}: rays hit"
            );
            for i in 0..r.len() {
                if host.hit[i] {
                    assert!(
                        (dev.t[i] - host.t[i]).abs() < 1e-5,
                        "k = {k}, ray {i}: t {} vs {}",
                        dev.t[i],
                        host.t[i]
                    );
                } else {
                    let (a, b) = (dev.t_min_sdf[i], host.t_min_sdf[i]);
                    assert!((a - b).abs() < 1e-4, "k = {k}, ray {i}: closest {a} vs {b}");
                }
            }
        }
    }
}
