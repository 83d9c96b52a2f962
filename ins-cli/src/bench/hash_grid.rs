//! `hash-grid` and `hash-grid-reference`: the hash encoding alone (16 levels × 2 features,
//! T = 2^17, resolutions 16…1024) of 2^17 random points, forward and backward to the table:
//! through the kernel op, or the plain Burn-ops reference it is proven against.
//! `hash-grid-object`: the kernel op on points where a NeRF's marched samples are, inside a
//! small object (a ball of radius 0.15 in the unit cube): the coarse levels' rows then take
//! thousands of the backward's scatter-adds each, which is what the atomics must survive.

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::Distribution;
use ins_core::kernels::hash_grid::{op, reference};
use ins_core::modules::hash_grid::HashGridConfig;

use super::{Timing, timed};

/// Points of a step.
const POINTS: usize = 1 << 17;

/// Where the points of a step lie.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Points {
    /// Uniform in the unit cube.
    Spread,
    /// Uniform in a ball of radius 0.15 at the cube's centre.
    Object,
}

pub fn run(device: &Device, steps: usize, kernel: bool, points: Points) -> Result<Timing> {
    let grid = HashGridConfig::new().init(device);
    let x = match points {
        Points::Spread => Tensor::<2>::random([POINTS, 3], Distribution::Uniform(0.0, 1.0), device),
        Points::Object => {
            // A direction (normalized Gaussian) times a radius with density ∝ r²: uniform in
            // the ball.
            let d = Tensor::<2>::random([POINTS, 3], Distribution::Normal(0.0, 1.0), device);
            let d = d.clone() / d.powf_scalar(2.0).sum_dim(1).sqrt().clamp_min(1e-6);
            let r = Tensor::<2>::random([POINTS, 1], Distribution::Uniform(0.0, 1.0), device)
                .powf_scalar(1.0 / 3.0)
                * 0.15;
            d * r + 0.5
        }
    };
    let g = Tensor::<2>::random([POINTS, grid.d_out()], Distribution::Default, device);
    if kernel && !op::kernel_device(device) {
        bail!(
            "the hash-grid kernel runs on flex and the CubeCL backends (wgpu) only (this is {device:?})"
        );
    }
    let times = timed(steps, || {
        let t = grid.table.val();
        let enc = if kernel {
            op::encode_kernel(x.clone(), t.clone(), grid.shape)
        } else {
            reference::encode(x.clone(), t.clone(), grid.shape)
        };
        let grads = (enc * g.clone()).sum().backward();
        let gt = t
            .grad(&grads)
            .ok_or_else(|| anyhow::anyhow!("no table gradient"))?;
        let _ = gt.slice([0..1, 0..1]).into_scalar::<f32>();
        Ok(())
    })?;
    Ok(Timing {
        times,
        pipelined: None,
        rays: Some(POINTS as f64),
    })
}
