//! `hash-grid` and `hash-grid-reference`: the hash encoding alone (16 levels × 2 features,
//! T = 2^17, resolutions 16…1024) of 2^17 random points, forward and backward to the table:
//! through the kernel op, or the plain Burn-ops reference it is proven against.

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::Distribution;
use ins_core::modules::hash_grid::{HashGridConfig, op, reference};

use super::{Timing, timed};

/// Points of a step.
const POINTS: usize = 1 << 17;

pub fn run(device: &Device, steps: usize, kernel: bool) -> Result<Timing> {
    let grid = HashGridConfig::new().init(device);
    let x = Tensor::<2>::random([POINTS, 3], Distribution::Uniform(0.0, 1.0), device);
    let g = Tensor::<2>::random([POINTS, grid.d_out()], Distribution::Default, device);
    if kernel && !op::kernel_device(device) {
        bail!(
            "the hash-grid kernel runs on flex, ndarray and the CubeCL backends (wgpu) only (this is {device:?})"
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
        rays: Some(POINTS as f64),
    })
}
