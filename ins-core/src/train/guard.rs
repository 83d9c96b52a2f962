//! Reading a step's loss values in one host sync, and stopping on NaN or overflow.

use burn::prelude::*;

use super::error::TrainError;
use super::phase::Phase;
use super::task::LossTerms;

/// The weighted total of a step (to differentiate) and every value read back.
pub struct StepValues {
    /// Σ weight · term, on the device.
    pub total: Tensor<1>,
    /// Each term's unweighted value, in the order of [`LossTerms::terms`].
    pub terms: Vec<(&'static str, f64)>,
    /// The weighted total's value.
    pub total_value: f64,
    /// Each probe's value, in the order of [`LossTerms::probes`] (not checked: a probe only
    /// reports).
    pub probes: Vec<f64>,
}

impl StepValues {
    /// Weights and sums the terms, then reads every term, the total and the probes back in
    /// one transfer.
    /// A term that is NaN or infinite is [`TrainError::Diverged`]; a finite set of terms
    /// whose weighted sum is not finite is [`TrainError::WeightOverflow`].
    pub fn read<O>(
        terms: &LossTerms,
        phase: &Phase<O>,
        step: usize,
        lr: f64,
        last_checkpoint: impl Fn() -> Option<std::path::PathBuf>,
    ) -> Result<Self, TrainError> {
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
        let read: Vec<Tensor<1>> = terms
            .terms
            .iter()
            .map(|(_, t)| t.clone())
            .chain(std::iter::once(total.clone()))
            .chain(terms.probes.iter().map(|p| p.value.clone()))
            .map(|t| t.detach())
            .collect();
        let values = Tensor::cat(read, 0)
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| TrainError::Task(anyhow::anyhow!("reading the loss values: {e:?}")))?;
        for ((name, _), &value) in terms.terms.iter().zip(&values) {
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
        let total_value = values[terms.terms.len()];
        if !total_value.is_finite() {
            return Err(TrainError::WeightOverflow {
                value: total_value,
                step,
                phase: phase.name.clone(),
                weights: format!("{:?}", phase.weights),
            });
        }
        Ok(Self {
            total,
            terms: terms
                .terms
                .iter()
                .zip(&values)
                .map(|((n, _), &v)| (*n, v as f64))
                .collect(),
            total_value: total_value as f64,
            probes: values[terms.terms.len() + 1..]
                .iter()
                .map(|&v| v as f64)
                .collect(),
        })
    }
}
