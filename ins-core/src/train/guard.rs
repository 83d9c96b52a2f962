//! A step's loss values: weighed on the device, read back (one transfer for one step or for
//! several), and checked for NaN or overflow.

use burn::prelude::*;

use super::error::TrainError;
use super::phase::Phase;
use super::task::LossTerms;

/// A step's weighted total (to differentiate) and the values to read back, both still on the
/// device.
pub struct Weighed {
    /// Σ weight · term.
    pub total: Tensor<1>,
    /// Every term, the total, then every probe, detached `[T + 1 + P]`.
    pub values: Tensor<1>,
}

/// Weighs and sums a step's terms; nothing is read back.
pub fn weigh<O>(terms: &LossTerms, phase: &Phase<O>) -> Result<Weighed, TrainError> {
    let mut total: Option<Tensor<1>> = None;
    for (name, t) in &terms.terms {
        let w = phase.weight_of(name);
        if w != 0.0 {
            let weighted = t.clone().mul_scalar(w);
            total = Some(match total {
                Some(acc) => acc + weighted,
                None => weighted,
            });
        }
    }
    let total = total.ok_or_else(|| TrainError::NothingToMinimise {
        phase: phase.name.clone(),
    })?;
    let values: Vec<Tensor<1>> = terms
        .terms
        .iter()
        .map(|(_, t)| t.clone())
        .chain(std::iter::once(total.clone()))
        .chain(terms.probes.iter().map(|p| p.value.clone()))
        .map(|t| t.detach())
        .collect();
    Ok(Weighed {
        total,
        values: Tensor::cat(values, 0),
    })
}

/// Reads several steps' [`Weighed::values`] back in one transfer, each step's in its own vector.
pub fn read_back(values: Vec<Tensor<1>>) -> Result<Vec<Vec<f32>>, TrainError> {
    let lengths: Vec<usize> = values.iter().map(|v| v.dims()[0]).collect();
    let all = Tensor::cat(values, 0)
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| TrainError::Task(anyhow::anyhow!("reading the loss values: {e:?}")))?;
    let mut rest = all.as_slice();
    Ok(lengths
        .into_iter()
        .map(|n| {
            let (this, next) = rest.split_at(n);
            rest = next;
            this.to_vec()
        })
        .collect())
}

/// Every value of a step, read back.
pub struct StepValues {
    /// Each term's unweighted value, in the order of [`LossTerms::terms`].
    pub terms: Vec<(&'static str, f64)>,
    /// The weighted total's value.
    pub total_value: f64,
    /// Each probe's value, in the order of [`LossTerms::probes`] (not checked: a probe only
    /// reports).
    pub probes: Vec<f64>,
}

impl StepValues {
    /// Weighs the terms and reads them, the total and the probes back in one transfer (see
    /// [`StepValues::check`]): the total to differentiate, and the values.
    pub fn read<O>(
        terms: &LossTerms,
        phase: &Phase<O>,
        step: usize,
        lr: f64,
        last_checkpoint: impl Fn() -> Option<std::path::PathBuf>,
    ) -> Result<(Tensor<1>, Self), TrainError> {
        let weighed = weigh(terms, phase)?;
        let values = read_back(vec![weighed.values])?;
        let names: Vec<&'static str> = terms.terms.iter().map(|(n, _)| *n).collect();
        let values = Self::check(&values[0], &names, phase, step, lr, last_checkpoint)?;
        Ok((weighed.total, values))
    }

    /// The values of step `step` read back (`values`: the terms named `names`, the total, the
    /// probes). A term that is NaN or infinite is [`TrainError::Diverged`]; a finite set of
    /// terms whose weighted sum is not finite is [`TrainError::WeightOverflow`].
    pub fn check<O>(
        values: &[f32],
        names: &[&'static str],
        phase: &Phase<O>,
        step: usize,
        lr: f64,
        last_checkpoint: impl Fn() -> Option<std::path::PathBuf>,
    ) -> Result<Self, TrainError> {
        for (name, &value) in names.iter().zip(values) {
            if !value.is_finite() {
                return Err(TrainError::Diverged {
                    term: name.to_string(),
                    value,
                    step,
                    phase: phase.name.clone(),
                    lr,
                    weight: phase.weight_of(name),
                    checkpoint: last_checkpoint(),
                });
            }
        }
        let total_value = values[names.len()];
        if !total_value.is_finite() {
            return Err(TrainError::WeightOverflow {
                value: total_value,
                step,
                phase: phase.name.clone(),
                weights: format!("{:?}", phase.weights),
            });
        }
        Ok(Self {
            terms: names
                .iter()
                .zip(values)
                .map(|(n, &v)| (*n, v as f64))
                .collect(),
            total_value: total_value as f64,
            probes: values[names.len() + 1..]
                .iter()
                .map(|&v| v as f64)
                .collect(),
        })
    }
}
