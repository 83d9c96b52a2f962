//! Single rendering operations whose GPU path differs from the CPU's, each on wgpu (Mesa's
//! lavapipe where there is no GPU) against flex or the host: the samplers and their jitter,
//! ray samples merged instead of sorted, the smoothness term's picks, compositing and NeuS's
//! section weights in one kernel, sphere tracing with its rounds on the device, a learned
//! background fitted on the device. The training steps they take part in are compared whole in
//! `wgpu_steps.rs`. Each wgpu call runs under a timeout, so a hang fails the test instead of
//! the suite.

use burn::prelude::*;
use ins_core::backend::BackendChoice;
use ins_tests::{max_rel_diff, values};

/// NeuS's and NeRF's hierarchical sampler (one kernel a call on wgpu, ops on flex) draws the
/// same distances on wgpu as on flex, up to what the rounding of the CDF's running sum allows:
/// a sample in a bin of probability `p` moves by at most the bin's width times that rounding
/// over `p`. A sample put in the wrong bin, or at the wrong place in its bin, moves by far
/// more. Checked against the same sampler evaluated on the host in f64.
#[test]
fn fine_samples_drawn_from_weights_move_only_by_their_cdfs_rounding_on_wgpu() {
    use ins_core::render::samplers::draw_from_weights;
    let (rows, s, n) = (48usize, 40usize, 24usize);
    let seed = 11u64;
    // Distances spread unevenly over [1, 3]; a sharp bump of weight per ray (a surface), two
    // rays with no weight at all (they see nothing).
    let mut t = vec![0f32; rows * s];
    let mut w = vec![0f32; rows * s];
    for r in 0..rows {
        for k in 0..s {
            let x = k as f32 / (s - 1) as f32;
            t[r * s + k] = 1.0 + 2.0 * x * x.sqrt();
            let centre = 0.2 + 0.6 * r as f32 / rows as f32;
            w[r * s + k] = if r < 2 {
                0.0
            } else {
                (-((x - centre) / 0.03).powi(2)).exp()
            };
        }
    }
    let on = {
        let (t, w) = (t.clone(), w.clone());
        move |device: &Device| -> Vec<f32> {
            let tt = Tensor::<1>::from_floats(t.as_slice(), device).reshape([rows, s]);
            let ww = Tensor::<1>::from_floats(w.as_slice(), device).reshape([rows, s]);
            values(draw_from_weights(tt, ww, n, Some(seed)))
        }
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(
        ins_tests::WGPU_LIMIT_S,
        "the hierarchical sampler",
        move || on(&BackendChoice::Wgpu.device()),
    );
    // The host's f64 version of the same sampler, and each sample's allowed movement.
    let u = values(ins_core::render::samplers::uniforms(
        rows,
        n,
        seed,
        &Device::flex(),
    ));
    let rounding = 4.0 * s as f64 * f64::from(f32::EPSILON);
    let mut worst = 0f64;
    for r in 0..rows {
        let mids: Vec<f64> = (0..s - 1)
            .map(|k| 0.5 * f64::from(t[r * s + k] + t[r * s + k + 1]))
            .collect();
        let pdf: Vec<f64> = (1..s - 1).map(|k| f64::from(w[r * s + k]) + 1e-5).collect();
        let total: f64 = pdf.iter().sum();
        let mut cdf = vec![0f64];
        for p in &pdf {
            cdf.push(cdf.last().unwrap() + p / total);
        }
        for j in 0..n {
            let uj = ((j as f64 + f64::from(u[r * n + j])) / n as f64).min(1.0 - 1e-6);
            let bin = cdf.iter().rposition(|&c| c <= uj).unwrap().min(s - 3);
            let p = cdf[bin + 1] - cdf[bin];
            let width = mids[bin + 1] - mids[bin];
            let expected = mids[bin] + ((uj - cdf[bin]) / p).clamp(0.0, 1.0) * width;
            let allowed = width * (rounding / p).min(1.0) + 1e-5;
            for (backend, got) in [("flex", &flex), ("wgpu", &wgpu)] {
                let d = (f64::from(got[r * n + j]) - expected).abs();
                worst = worst.max(d / allowed);
                assert!(
                    d <= allowed,
                    "ray {r}, sample {j} on {backend}: {} where the host has {expected} \
                     (bin {bin} of probability {p:e}, allowed {allowed:e})",
                    got[r * n + j]
                );
            }
        }
    }
    eprintln!(
        "the hierarchical sampler: worst movement {worst:.3} of what its CDF's rounding allows"
    );
}

/// The samplers' jitter is made in their kernels on wgpu (hashed from a counter, as on the
/// host): stratified samples with jitter and at bin centres, and centred draws from weights,
/// are flex's.
#[test]
fn samplers_jitter_on_wgpu_as_on_the_host() {
    use ins_core::render::samplers::{draw_from_weights, stratified};
    let (rays, n) = (37usize, 24usize);
    let near: Vec<f32> = (0..rays).map(|r| 0.5 + 0.1 * (r % 5) as f32).collect();
    let far: Vec<f32> = (0..rays).map(|r| 3.0 + 0.3 * (r % 7) as f32).collect();
    let on = move |device: &Device| -> Vec<Vec<f32>> {
        let near = Tensor::<1>::from_floats(near.as_slice(), device);
        let far = Tensor::<1>::from_floats(far.as_slice(), device);
        let jittered = stratified(near.clone(), far.clone(), n, Some(0x5eed_0000_0042));
        let centred = stratified(near, far, n, None);
        let weights = jittered.clone().sin().abs();
        let drawn = draw_from_weights(jittered.clone(), weights, 16, None);
        [jittered, centred, drawn].map(values).to_vec()
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "the samplers", move || {
        on(&BackendChoice::Wgpu.device())
    });
    for (i, what) in ["jittered", "centred", "drawn at centres"]
        .iter()
        .enumerate()
    {
        let err = max_rel_diff(&wgpu[i], &flex[i], 1e-6);
        assert!(
            err < 1e-5,
            "{what} samples: {err:e} relative to the largest"
        );
    }
    // The jitter moved the samples off their bins' centres.
    let moved = (0..rays * n)
        .filter(|&i| (flex[0][i] - flex[1][i]).abs() > 1e-4)
        .count();
    assert!(moved > rays * n * 9 / 10, "only {moved} samples jittered");
}

/// Two sets of samples merged along their rays on the device (CubeCL has no sort kernel; one
/// kernel walks each ray's two sets instead of reading them back) come out as the host sorts
/// them, each index pointing at its value and equal values keeping their columns' order: rows
/// of 48 + 32 with ties within and across the sets, as IDR's volume merges its drawn samples
/// into its coarse ones.
#[test]
fn ray_samples_merge_on_wgpu_as_the_host_sorts() {
    use ins_core::render::merge_rows::merge_rows_with_indices;
    let (rows, ka, k) = (64usize, 48usize, 80usize);
    // Values on a coarse lattice (ties in every row), each set sorted.
    let x: Vec<f32> = (0..rows)
        .flat_map(|r| {
            let a = (0..ka).map(|c| c as f32 * 0.25);
            let mut b: Vec<f32> = (ka..k)
                .map(|c| ((c * 37 + r * 11) % 53) as f32 * 0.125)
                .collect();
            b.sort_by(f32::total_cmp);
            a.chain(b).collect::<Vec<_>>()
        })
        .collect();
    let on = {
        let x = x.clone();
        move |device: &Device| -> (Vec<f32>, Vec<i64>) {
            let t = Tensor::<1>::from_floats(x.as_slice(), device).reshape([rows, k]);
            let (a, b) = (t.clone().slice([0..rows, 0..ka]), t.slice([0..rows, ka..k]));
            let (sorted, order) = merge_rows_with_indices(a, b);
            let order = order.into_data().convert::<i64>();
            (values(sorted), order.try_to_vec::<i64>().unwrap())
        }
    };
    let (flex, _) = on(&Device::flex());
    let (wgpu, order) = ins_tests::within(ins_tests::WGPU_LIMIT_S, "merging rows", move || {
        on(&BackendChoice::Wgpu.device())
    });
    assert_eq!(wgpu, flex, "the sorted rows differ from the host's");
    let mut ties = 0;
    for r in 0..rows {
        let mut seen = vec![false; k];
        for j in 0..k {
            let from = order[r * k + j] as usize;
            assert!(
                from < k && !seen[from],
                "row {r}: column {from} twice or outside"
            );
            seen[from] = true;
            assert_eq!(x[r * k + from], wgpu[r * k + j], "row {r}, place {j}");
            if j > 0 && wgpu[r * k + j] == wgpu[r * k + j - 1] {
                ties += 1;
                let before = order[r * k + j - 1] as usize;
                assert!(before < from, "row {r}, place {j}: tie out of column order");
            }
        }
    }
    assert!(ties > rows, "only {ties} ties: the rows test little");
}

/// The smoothness term's picks among the samples seen, made on the device (one kernel: ranks
/// and a binary search), are the host's ops' exactly (integer arithmetic): with fewer flagged
/// than picks, as many, more, and none.
#[test]
fn flagged_samples_are_picked_on_wgpu_as_on_the_host() {
    use ins_core::render::flagged_picks::pick_flagged;
    let flags: Vec<f32> = (0..3000)
        .map(|j| (j % 7 == 0 || j % 11 == 3) as u8 as f32)
        .collect();
    let on = move |device: &Device| -> Vec<(Vec<i64>, Vec<f32>)> {
        [(64, 1.0), (663, 1.0), (1024, 1.0), (16, 0.0)]
            .into_iter()
            .map(|(k, on)| {
                let flags: Vec<f32> = flags.iter().map(|f| f * on).collect();
                let (index, weight) =
                    pick_flagged(Tensor::<1>::from_floats(flags.as_slice(), device), k, 5);
                let index = index.into_data().convert::<i64>();
                (index.try_to_vec::<i64>().unwrap(), values(weight))
            })
            .collect()
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(
        ins_tests::WGPU_LIMIT_S,
        "picking flagged samples",
        move || on(&BackendChoice::Wgpu.device()),
    );
    assert_eq!(
        flex[2].1.iter().sum::<f32>(),
        663.0,
        "all 663 flagged, then fillers"
    );
    assert_eq!(flex[3], (vec![0; 16], vec![0.0; 16]), "nothing flagged");
    assert_eq!(wgpu, flex, "the picks differ from the host's");
}

/// Padded samples composited as runs of one width, one kernel forward and one backward (the GPU
/// path), give the ordinary ops' colours, depths, opacities, weights (a kernel of their own) and
/// the gradients of densities and colours, on flex: rays that turn opaque, rays nearly empty,
/// rays ending in padding (δ = 0), a white background, and a loss that weighs all three outputs.
#[test]
fn compositing_in_one_kernel_matches_the_ordinary_ops_on_wgpu() {
    use ins_core::render::volume::{composite, composite_by_ops};
    let (rays, samples) = (37usize, 45usize);
    let mut sigma = Vec::new();
    let (mut t, mut delta, mut rgb, mut probe) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in 0..rays {
        let live = samples - (r * 7) % 20;
        for k in 0..samples {
            let x = (r * 31 + k * 17) % 23;
            sigma.push(match r % 3 {
                0 => 40.0 * x as f32,
                1 => 0.05 * x as f32,
                _ => (x as f32 - 11.0).max(0.0) * 3.0,
            });
            t.push(2.0 + 0.09 * k as f32 + 0.001 * r as f32);
            delta.push(if k < live { 0.09 } else { 0.0 });
            rgb.extend([
                x as f32 / 23.0,
                (k % 5) as f32 / 5.0,
                0.5 + 0.01 * (r % 9) as f32,
            ]);
        }
        probe.extend([
            (r % 4) as f32 - 1.5,
            0.3,
            -0.7,
            0.05 * (r % 3) as f32,
            1.0 - 0.1 * (r % 5) as f32,
        ]);
    }
    let on = move |device: &Device, reference: bool| -> Vec<Vec<f32>> {
        let device = device.clone().autodiff();
        let field =
            |v: &[f32], shape: [usize; 2]| Tensor::<1>::from_floats(v, &device).reshape(shape);
        let sigma = field(&sigma, [rays, samples]).require_grad();
        let rgb = Tensor::<1>::from_floats(rgb.as_slice(), &device)
            .reshape([rays, samples, 3])
            .require_grad();
        let c = (if reference {
            composite_by_ops
        } else {
            composite
        })(
            sigma.clone(),
            rgb.clone(),
            field(&t, [rays, samples]),
            field(&delta, [rays, samples]),
            [1.0, 1.0, 1.0],
        );
        let probe = field(&probe, [rays, 5]);
        let outputs = Tensor::cat(
            vec![
                c.rgb.clone(),
                c.depth.clone().reshape([rays, 1]),
                c.opacity.clone().reshape([rays, 1]),
            ],
            1,
        );
        let grads = (outputs.clone() * probe).sum().backward();
        vec![
            values(outputs),
            values(c.weights()),
            values(sigma.grad(&grads).unwrap()),
            values(rgb.grad(&grads).unwrap().reshape([rays, samples * 3])),
        ]
    };
    let flex = on(&Device::flex(), true);
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "compositing", move || {
        on(&BackendChoice::Wgpu.device(), false)
    });
    for (i, what) in ["outputs", "weights", "density gradient", "colour gradient"]
        .iter()
        .enumerate()
    {
        let err = max_rel_diff(&wgpu[i], &flex[i], 1e-6);
        eprintln!("compositing in one kernel, {what}: {err:e} relative to the largest");
        assert!(err < 1e-4, "{what}: {err:e} relative to the largest");
    }
    // The opaque rays reach full opacity; the padding takes no gradient.
    assert!(flex[0][4] > 0.999, "ray 0 opaque: {}", flex[0][4]);
    assert_eq!(
        wgpu[2][samples - 1 + samples * 4],
        0.0,
        "padding of ray 4 moved"
    );
}

/// Compositing each ray's run of samples (no padded layout) in one kernel forward and one
/// backward on wgpu gives flex's loops: two styles, rays of no, one and many samples, rays that
/// turn opaque and stop there (the stop a GPU uses for `until_opaque`), and rows past the last
/// ray (a bucket's padding) that take no gradient.
#[test]
fn ragged_compositing_matches_flex_on_wgpu() {
    use ins_core::render::volume::{RaySpans, composite_ragged};
    let counts: Vec<u32> = (0..29)
        .map(|r| [0, 1, 45, 7, 20][r % 5] + (r as u32 % 3))
        .collect();
    let mut offsets = vec![0u32];
    for c in &counts {
        offsets.push(offsets.last().unwrap() + c);
    }
    let (styles, rays, n) = (2usize, counts.len(), *offsets.last().unwrap() as usize);
    let rows = n + 13; // a bucket's padding after the last ray's samples
    let (mut sigma, mut rgb) = (Vec::new(), Vec::new());
    for s in 0..styles {
        for k in 0..rows {
            let x = (k * 17 + s * 5) % 23;
            sigma.push(if k % 3 == 0 {
                30.0 * x as f32
            } else {
                0.3 * x as f32
            });
            rgb.extend([x as f32 / 23.0, (k % 5) as f32 / 5.0, 0.2 + 0.1 * s as f32]);
        }
    }
    let t: Vec<f32> = (0..rows).map(|k| 2.0 + 0.01 * k as f32).collect();
    let delta: Vec<f32> = (0..rows).map(|k| 0.02 + 0.01 * (k % 4) as f32).collect();
    let probe: Vec<f32> = (0..styles * rays * 5)
        .map(|i| ((i * 7) % 11) as f32 / 5.0 - 1.0)
        .collect();
    let on = move |device: &Device| -> Vec<Vec<f32>> {
        let device = device.clone().autodiff();
        let mut out = Vec::new();
        for stop_below in [0.0, 0.01] {
            let sigma = Tensor::<1>::from_floats(sigma.as_slice(), &device).reshape([styles, rows]);
            let rgb = Tensor::<1>::from_floats(rgb.as_slice(), &device).reshape([styles, rows, 3]);
            let (sigma, rgb) = (sigma.require_grad(), rgb.require_grad());
            let spans = RaySpans::upload(&offsets, &t, &delta, &device);
            let c = composite_ragged(
                sigma.clone(),
                rgb.clone(),
                spans,
                [1.0, 1.0, 1.0],
                stop_below,
            );
            let outputs = Tensor::cat(
                vec![
                    c.rgb.clone(),
                    c.depth.clone().reshape([styles * rays, 1]),
                    c.opacity.clone().reshape([styles * rays, 1]),
                ],
                1,
            );
            let probe =
                Tensor::<1>::from_floats(probe.as_slice(), &device).reshape([styles * rays, 5]);
            let grads = (outputs.clone() * probe).sum().backward();
            out.extend([
                values(outputs),
                values(c.weights()),
                values(sigma.grad(&grads).unwrap()),
                values(rgb.grad(&grads).unwrap().reshape([styles, rows * 3])),
            ]);
        }
        out
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "ragged compositing", move || {
        on(&BackendChoice::Wgpu.device())
    });
    let what = ["outputs", "weights", "density gradient", "colour gradient"];
    for (i, (w, f)) in wgpu.iter().zip(&flex).enumerate() {
        let err = max_rel_diff(w, f, 1e-6);
        let stop = if i < 4 { "no stop" } else { "stopped" };
        eprintln!(
            "ragged compositing, {} ({stop}): {err:e} relative to the largest",
            what[i % 4]
        );
        assert!(
            err < 1e-4,
            "{} ({stop}): {err:e} relative to the largest",
            what[i % 4]
        );
    }
    // The stop leaves samples without gradient that the full walk moves; the padding rows
    // take none in either.
    let moved = |g: &[f32]| g.iter().filter(|&&x| x != 0.0).count();
    assert!(
        moved(&wgpu[6]) + 20 < moved(&wgpu[2]),
        "the stop changed nothing"
    );
    for g in [&wgpu[2], &wgpu[6]] {
        assert!(
            g[n..rows].iter().chain(&g[rows + n..]).all(|&x| x == 0.0),
            "padding moved"
        );
    }
}

/// NeuS's section weights as one kernel forward and one backward (the GPU path) give flex's
/// ordinary ops' weights and the gradients of the SDF and the sharpness: rays that cross the
/// surface sharply (their first section opaque), rays that leave it again (a rising SDF, where
/// the opacity's clamp stops the gradient), rays that miss it, and dead rays.
#[test]
fn section_weights_in_one_kernel_match_the_ordinary_ops_on_wgpu() {
    use ins_core::render::sdf_volume::section_weights;
    let (rays, ends) = (29usize, 33usize);
    let (mut f, mut live, mut probe) = (Vec::new(), Vec::new(), Vec::new());
    for r in 0..rays {
        let crossing = 0.2 + 0.6 * (r % 7) as f32 / 7.0;
        for k in 0..ends {
            let x = k as f32 / (ends - 1) as f32;
            f.push(match r % 4 {
                0 => crossing - x,
                1 => (x - crossing).abs() - 0.1,
                2 => 0.3 + 0.1 * (x * 9.0).sin(),
                _ => 0.02 * (crossing - x) + 0.001 * ((r * 13 + k * 7) % 11) as f32,
            });
            if k + 1 < ends {
                probe.push(((r * 5 + k * 3) % 17) as f32 / 17.0 - 0.4);
            }
        }
        live.push(if r % 9 == 4 { 0.0 } else { 1.0 });
    }
    let sharpness = 60.0f32;
    let on = move |device: &Device| -> Vec<Vec<f32>> {
        let device = device.clone().autodiff();
        let ends_t = Tensor::<1>::from_floats(f.as_slice(), &device)
            .reshape([rays, ends])
            .require_grad();
        let s = Tensor::<1>::from_floats([sharpness], &device).require_grad();
        let live = Tensor::<1>::from_floats(live.as_slice(), &device);
        let w = section_weights(ends_t.clone(), live, s.clone());
        let probe = Tensor::<1>::from_floats(probe.as_slice(), &device).reshape([rays, ends - 1]);
        let grads = (w.clone() * probe).sum().backward();
        vec![
            values(w),
            values(ends_t.grad(&grads).unwrap()),
            values(s.grad(&grads).unwrap()),
        ]
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "section weights", move || {
        on(&BackendChoice::Wgpu.device())
    });
    for (i, what) in ["weights", "SDF gradient", "sharpness gradient"]
        .iter()
        .enumerate()
    {
        let err = max_rel_diff(&wgpu[i], &flex[i], 1e-6);
        eprintln!("section weights in one kernel, {what}: {err:e} relative to the largest");
        assert!(err < 1e-4, "{what}: {err:e} relative to the largest");
    }
    // The sharp crossings are opaque; a dead ray weighs nothing and takes no gradient.
    let opacity = |r: usize| {
        flex[0][r * (ends - 1)..(r + 1) * (ends - 1)]
            .iter()
            .sum::<f32>()
    };
    assert!(opacity(0) > 0.99, "ray 0 opaque: {}", opacity(0));
    assert_eq!(opacity(4), 0.0, "dead ray 4");
    assert!(wgpu[1][4 * ends..5 * ends].iter().all(|g| *g == 0.0));
    assert!(flex[2][0].abs() > 1e-6, "no sharpness gradient to compare");
}

/// IDR's tracer with its rounds on the device (the GPU path) finds on wgpu the hits, depths and
/// closest approaches the host's tracer finds: a box (faces, edges) whose field overstates
/// distances, so the march brackets some rays and the search finds others; near and clear
/// misses.
#[test]
fn surfaces_are_traced_on_wgpu_as_on_the_host() {
    use ins_core::render::sphere_tracing::device::sphere_trace_on_device;
    use ins_core::render::sphere_tracing::{TraceOptions, sphere_trace};
    use ins_scene::geometry::Vec3;
    use ins_scene::rays::Rays;
    let mut rays = Rays::default();
    for i in 0..40 {
        let y = -0.5 + 1.0 * i as f32 / 39.0;
        let dir = Vec3::new(0.1, 0.0, -1.0).normalize();
        rays.push(Vec3::new(-0.1, y, 2.0), dir, 0.5, 3.5);
    }
    for k in [1.0f32, 1.5, 8.0] {
        // The box |x|, |y|, |z| ≤ 0.3: its exact distance, times k.
        let host = sphere_trace(&rays, &TraceOptions::default(), |p: &[f32]| {
            p.chunks_exact(3)
                .map(|p| {
                    let q = Vec3::new(p[0].abs(), p[1].abs(), p[2].abs()) - Vec3::splat(0.3);
                    k * (q.max(Vec3::ZERO).length() + q.max_element().min(0.0))
                })
                .collect()
        });
        let traced = {
            let rays = rays.clone();
            ins_tests::within(
                ins_tests::WGPU_LIMIT_S,
                "tracing on the device",
                move || {
                    let field = move |x: Tensor<2>| {
                        let [n, _] = x.dims();
                        let q = x.abs().sub_scalar(0.3);
                        let outside = q.clone().clamp_min(0.0).square().sum_dim(1).sqrt();
                        let inside = q.max_dim(1).clamp_max(0.0);
                        (outside + inside).mul_scalar(k).reshape([n])
                    };
                    let device = BackendChoice::Wgpu.device();
                    sphere_trace_on_device(&rays, &TraceOptions::default(), field, &device)
                },
            )
        };
        assert_eq!(traced.hit, host.hit, "k = {k}: the rays that hit");
        assert!(host.hit.iter().any(|&h| h) && !host.hit.iter().all(|&h| h));
        for i in 0..rays.len() {
            let (a, b) = if host.hit[i] {
                (traced.t[i], host.t[i])
            } else {
                (traced.t_min_sdf[i], host.t_min_sdf[i])
            };
            assert!(
                (a - b).abs() < 1e-4,
                "k = {k}, ray {i}: {a} on wgpu, {b} on the host"
            );
        }
    }
}

/// A capture's learned background, fitted on the device without a read-back, follows flex's
/// fit on wgpu, a batch with a NaN left out.
#[test]
fn a_learned_background_is_fitted_on_wgpu_as_on_the_host() {
    use ins_models::nerf::background::{BackgroundFit, LearnedBackground};
    let on = |device: &Device| -> Vec<f32> {
        let mut fit = BackgroundFit::new(LearnedBackground::default(), [0.0; 3], device);
        let mut out = Vec::new();
        for step in 0..4 {
            let rows =
                |v: Vec<f32>| Tensor::<1>::from_floats(v.as_slice(), device).reshape([64, 3]);
            let field: Vec<f32> = (0..192)
                .map(|i| ((i * 7 + step) % 13) as f32 / 26.0)
                .collect();
            let mut target: Vec<f32> = (0..192)
                .map(|i| ((i * 5 + step) % 11) as f32 / 11.0)
                .collect();
            if step == 2 {
                target[17] = f32::NAN;
            }
            let opacity: Vec<f32> = (0..64)
                .map(|i| ((i * 3 + step) % 10) as f32 / 10.0)
                .collect();
            let pred = fit.composite_and_fit(
                rows(field),
                Tensor::from_floats(opacity.as_slice(), device),
                rows(target),
            );
            out.extend(values(pred.reshape([192])));
            let (sums, colour) = fit.read();
            out.extend(sums.num);
            out.push(sums.den);
            out.extend(colour);
        }
        out
    };
    let flex = on(&Device::flex());
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "fitting a background", move || {
        on(&BackendChoice::Wgpu.device())
    });
    assert_eq!(flex.len(), wgpu.len());
    for (i, (a, b)) in flex.iter().zip(&wgpu).enumerate() {
        assert!(
            (a - b).abs() <= 1e-5 * (1.0 + a.abs()),
            "value {i}: flex {a}, wgpu {b}"
        );
    }
}
