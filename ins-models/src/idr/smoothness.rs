//! The volume renderer's smoothness term: how much the SDF's gradient turns over a short
//! random step near the surface, which keeps a hash-grid surface from bending to explain texture.

use burn::prelude::*;
use ins_core::render::flagged_picks::pick_flagged;
use ins_core::render::gather::select_parallel;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::model::IdrModel;

/// How far the smoothness term looks: a step of this length in a random direction, about
/// five of the finest grid cells (1024 across the unit sphere's box) and a tenth of a checker
/// square on the synthetic scenes: long enough to see texture bent into the surface, short
/// next to the object's own corners.
const CURVATURE_STEP: f32 = 0.01;

/// The smoothness term: the mean squared change of the SDF's gradient `g` (rows of `points`)
/// over a step of [`CURVATURE_STEP`] in a random direction, at up to `k` of the samples flagged
/// in `seen [N]` (all of them when there are at most `k`, else one from each of `k` strata,
/// chosen on the device by `seed`: [`pick_flagged`]). Zero when nothing was seen.
pub(super) fn gradient_change(
    model: &IdrModel,
    points: &Tensor<2>,
    g: &Tensor<2>,
    seen: &Tensor<1>,
    k: usize,
    seed: u64,
) -> Tensor<1> {
    let device = points.device();
    let (index, counted) = pick_flagged(seen.clone(), k, seed ^ 0xc0be);
    let mut rng = SmallRng::seed_from_u64(seed ^ 0xc0be);
    let steps: Vec<f32> = (0..k)
        .flat_map(|_| {
            let d = loop {
                let v = [0; 3].map(|_| rng.random::<f32>() * 2.0 - 1.0);
                let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if n > 1e-3 && n <= 1.0 {
                    break v.map(|c| c / n);
                }
            };
            d.map(|c| c * CURVATURE_STEP)
        })
        .collect();
    let here = select_parallel(points.clone(), 0, index.clone());
    let there = here + Tensor::<1>::from_floats(steps.as_slice(), &device).reshape([k, 3]);
    let g_there = model.sdf.forward_with_gradient(there).2;
    let change = (select_parallel(g.clone(), 0, index) - g_there)
        .square()
        .sum_dim(1)
        .reshape([k]);
    (change * counted.clone()).sum() / counted.sum().clamp_min(1.0)
}
