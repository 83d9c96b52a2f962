//! Style mixes at render time: weights given on the command line become a convex combination
//! of the one-hot codes a multi-style model was trained with.

use std::path::Path;

use anyhow::{Result, bail};
use burn::prelude::*;

/// Checks `mix` against `n` styles and normalises it to sum 1 (default: the first style).
pub fn normalized(n: usize, mix: Option<&[f32]>) -> Result<Vec<f32>> {
    let mix: Vec<f32> = match mix {
        Some(m) => m.to_vec(),
        None => (0..n).map(|i| if i == 0 { 1.0 } else { 0.0 }).collect(),
    };
    if mix.len() != n {
        bail!("--mix has {} weights but the run has {n} styles", mix.len());
    }
    if mix.iter().any(|v| !v.is_finite() || *v < 0.0) {
        bail!("--mix weights must be non-negative numbers");
    }
    let sum: f32 = mix.iter().sum();
    if sum <= 0.0 {
        bail!("--mix weights sum to 0");
    }
    Ok(mix.iter().map(|v| v / sum).collect())
}

/// The code `[1, n]` for a run with `n_styles` styles, or `None` for an unstylized run (where
/// a mix is an error naming the run).
pub fn code(
    n_styles: usize,
    mix: Option<&[f32]>,
    run: &Path,
    device: &Device,
) -> Result<Option<Tensor<2>>> {
    if n_styles == 0 {
        if mix.is_some() {
            bail!("--mix: {} is not a stylized run", run.display());
        }
        return Ok(None);
    }
    let code = normalized(n_styles, mix)?;
    Ok(Some(
        Tensor::<1>::from_floats(code.as_slice(), device).reshape([1, n_styles]),
    ))
}
