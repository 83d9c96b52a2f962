//! `dense`: one 64-wide hidden layer of a NeRF's MLPs (`x [2^18, 64] · W [64, 64] + b`, then a
//! ReLU), forward and backward to its input and weight, in the precision `--precision` asks
//! for: bf16 products by AVX-512 BF16 where the CPU has it (as a NeRF's stylization and
//! renders run them), f32 with `--precision f32`.

use anyhow::Result;
use burn::nn::LinearConfig;
use burn::prelude::*;
use burn::tensor::Distribution;
use burn::tensor::activation::relu;
use ins_core::kernels::dense::dense;
use ins_core::kernels::dense_bf16;

use super::{Timing, timed};

/// Rows of a step: about a stylizing step's samples in front of the surface.
const ROWS: usize = 1 << 18;

pub fn run(device: &Device, steps: usize, bf16: bool) -> Result<Timing> {
    let layer = LinearConfig::new(64, 64).init(device);
    let x = Tensor::<2>::random([ROWS, 64], Distribution::Default, device).require_grad();
    let g = Tensor::<2>::random([ROWS, 64], Distribution::Default, device);
    let _precision = dense_bf16::scope(bf16);
    let times = timed(steps, || {
        let y = relu(dense(&layer, x.clone()));
        let grads = (y * g.clone()).sum().backward();
        let dx = x
            .grad(&grads)
            .ok_or_else(|| anyhow::anyhow!("no input gradient"))?;
        let _ = dx.slice([0..1, 0..1]).into_scalar::<f32>();
        Ok(())
    })?;
    Ok(Timing {
        times,
        pipelined: None,
        rays: Some(ROWS as f64),
    })
}
