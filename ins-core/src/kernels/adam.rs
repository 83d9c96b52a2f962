//! Adam in one pass over each parameter on Flex: the trainer's optimizer.
//!
//! Burn's Adam is a dozen tensor ops per parameter, each allocating and filling a tensor of
//! the parameter's size. For small networks that is noise; for a hash table of 12.2 M entries
//! (IDR's appearance grid) it took 35 ms a step, two fifths of the step. This optimizer does
//! the same arithmetic element by element, reading the gradient and writing the parameter and
//! both moments once, in place where Flex owns them alone. Its state is Burn's [`AdamState`]
//! ([`FusedAdamState`] writes and reads it under the same names), so checkpoints written with
//! either optimizer load into the other. Other backends (wgpu, CUDA) run the same update as
//! tensor ops.

#![allow(deprecated)]

use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Backend, DType, Dispatch, Flex, TensorData, TensorMetadata, backend_extension,
};
use burn::optim::{
    AdamState, AdaptiveMomentumState, LearningRate, ModuleOptimizer, Optimizer, RecordState,
    StateSink, StateSource,
};
use burn::prelude::*;
use rayon::prelude::*;

use crate::kernels::flex::on_flex;

/// Adam's constants (Kingma & Ba), no weight decay, no AMSGrad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusedAdam {
    /// Decay of the first moment.
    pub beta_1: f32,
    /// Decay of the second moment.
    pub beta_2: f32,
    /// Added to the root of the second moment.
    pub epsilon: f32,
}

impl Default for FusedAdam {
    fn default() -> Self {
        Self {
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon: 1e-8,
        }
    }
}

impl FusedAdam {
    /// The optimizer for a whole module.
    pub fn init(self) -> ModuleOptimizer {
        ModuleOptimizer::from(self)
    }

    /// The scalars of step `time` (1-based) at learning rate `lr`.
    fn scalars(&self, lr: LearningRate, time: usize) -> kernel::Step {
        let t = time as i32;
        let bc2 = (1.0 - self.beta_2.powi(t)).sqrt();
        kernel::Step {
            lr: lr as f32,
            beta_1: self.beta_1,
            beta_2: self.beta_2,
            // Burn's form: m·(√(1−β₂ᵗ)/(1−β₁ᵗ)) / (√v + ε·√(1−β₂ᵗ)).
            scale: bc2 / (1.0 - self.beta_1.powi(t)),
            epsilon: self.epsilon * bc2,
        }
    }
}

/// The update on slices.
pub mod kernel {
    /// What one step needs besides the tensors.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Step {
        /// Learning rate.
        pub lr: f32,
        /// First-moment decay.
        pub beta_1: f32,
        /// Second-moment decay.
        pub beta_2: f32,
        /// Bias correction of the step: `√(1−β₂ᵗ)/(1−β₁ᵗ)`.
        pub scale: f32,
        /// `ε·√(1−β₂ᵗ)`.
        pub epsilon: f32,
    }

    /// Updates `param`, `m` and `v` in place with gradient `g` (all the same length).
    #[inline(always)]
    fn update_loop(s: Step, g: &[f32], param: &mut [f32], m: &mut [f32], v: &mut [f32]) {
        let n = param.len();
        let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
        for i in 0..n {
            let gi = g[i];
            let mi = m[i] * s.beta_1 + gi * (1.0 - s.beta_1);
            let vi = v[i] * s.beta_2 + gi * gi * (1.0 - s.beta_2);
            m[i] = mi;
            v[i] = vi;
            param[i] -= mi * s.scale / (vi.sqrt() + s.epsilon) * s.lr;
        }
    }

    crate::kernels::flex::vectorized! {
        /// The update.
        pub fn update(
            s: Step,
            g: &[f32],
            param: &mut [f32],
            m: &mut [f32],
            v: &mut [f32],
        ) = update_loop;
    }
}

/// Adam's update as one backend operation.
#[backend_extension(Flex)]
pub trait FusedAdamOps: Backend {
    /// `(param, m, v)` after one step with gradient `grad` (all of one shape).
    fn fused_adam_step(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        m: FloatTensor<Self>,
        v: FloatTensor<Self>,
        step: kernel::Step,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// A contiguous f32 tensor this code may write: itself when it is the only owner of its
/// storage, a copy otherwise.
fn writable(t: FlexTensor) -> FlexTensor {
    assert_eq!(t.dtype(), DType::F32, "Adam runs in f32");
    let mut t = t;
    let n = t.shape().num_elements();
    // The whole storage, in order, owned by this tensor alone.
    let owned = t.layout().contiguous_offsets() == Some((0, n))
        && t.try_storage_mut::<f32>().is_some_and(|s| s.len() == n);
    if owned {
        t
    } else {
        let values: Vec<f32> = t.to_contiguous().as_slice::<f32>().expect("f32").to_vec();
        FlexTensor::from_data(TensorData::new(values, t.shape()))
    }
}

/// Elements per parallel job.
const CHUNK: usize = 1 << 15;

impl FusedAdamOps for Flex {
    fn fused_adam_step(
        param: FlexTensor,
        grad: FlexTensor,
        m: FlexTensor,
        v: FlexTensor,
        s: kernel::Step,
    ) -> (FlexTensor, FlexTensor, FlexTensor) {
        let grad = grad.to_contiguous();
        let g = grad.as_slice::<f32>().expect("contiguous f32");
        let (mut param, mut m, mut v) = (writable(param), writable(m), writable(v));
        {
            let p = param.try_storage_mut::<f32>().expect("owned");
            let ms = m.try_storage_mut::<f32>().expect("owned");
            let vs = v.try_storage_mut::<f32>().expect("owned");
            assert!(
                p.len() == g.len() && ms.len() == g.len() && vs.len() == g.len(),
                "Adam: parameter, gradient and moments differ in size"
            );
            p.par_chunks_mut(CHUNK)
                .zip(ms.par_chunks_mut(CHUNK))
                .zip(vs.par_chunks_mut(CHUNK))
                .enumerate()
                .for_each(|(i, ((p, ms), vs))| {
                    kernel::update(s, &g[i * CHUNK..][..p.len()], p, ms, vs)
                });
        }
        (param, m, v)
    }
}

/// Burn's [`AdamState`], read back from a checkpoint onto the CPU.
///
/// Why: Burn loads an optimizer's state onto `Device::default()`, the first backend of the
/// build in its order (CUDA, then wgpu, then flex), and moves each parameter's state to that
/// parameter's device at its next step. On a machine without CUDA (or, before CUDA was in the
/// build, without Vulkan) creating the state there failed and a resume stopped as "damaged
/// optimizer state"; elsewhere it opened a GPU a CPU run never uses. Read onto flex, the state
/// moves to the parameter's device at the first step, as before.
#[derive(Clone)]
pub struct FusedAdamState<const D: usize>(pub AdamState<D>);

impl<const D: usize> RecordState for FusedAdamState<D> {
    fn state_flatten(&self, prefix: &str, out: &mut StateSink) {
        self.0.state_flatten(prefix, out);
    }

    fn state_unflatten(prefix: &str, src: &mut StateSource, _device: &Device) -> Option<Self> {
        AdamState::state_unflatten(prefix, src, &Device::flex()).map(Self)
    }
}

impl Optimizer for FusedAdam {
    type State<const D: usize> = FusedAdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        let (time, m, v) = match state {
            Some(FusedAdamState(s)) => (
                s.momentum.time + 1,
                s.momentum.moment_1,
                s.momentum.moment_2,
            ),
            None => (1, grad.zeros_like(), grad.zeros_like()),
        };
        let s = self.scalars(lr, time);
        let (tensor, m, v) = if on_flex(&tensor) && tensor.dtype() == burn::tensor::DType::F32 {
            let (p, m, v) = <Dispatch as FusedAdamOps>::fused_adam_step(
                tensor.into_dispatch(),
                grad.into_dispatch(),
                m.into_dispatch(),
                v.into_dispatch(),
                s,
            );
            (
                Tensor::from_dispatch(p),
                Tensor::from_dispatch(m),
                Tensor::from_dispatch(v),
            )
        } else {
            let m = m.mul_scalar(s.beta_1) + grad.clone().mul_scalar(1.0 - s.beta_1);
            let v = v.mul_scalar(s.beta_2) + grad.square().mul_scalar(1.0 - s.beta_2);
            let delta = (m.clone().mul_scalar(s.scale) / v.clone().sqrt().add_scalar(s.epsilon))
                .mul_scalar(s.lr);
            (tensor - delta, m, v)
        };
        let momentum = AdaptiveMomentumState::new(time, m, v);
        (tensor, Some(FusedAdamState(AdamState::new(momentum))))
    }

    fn to_device<const D: usize>(mut state: Self::State<D>, device: &Device) -> Self::State<D> {
        state.0.momentum = state.0.momentum.to_device(device);
        state
    }
}

#[cfg(test)]
mod tests {
    use burn::optim::{AdamConfig, GradientsParams};

    use super::*;

    /// A module of two parameters: one of a size where the parallel chunks split it unevenly.
    #[derive(burn::module::Module, Debug)]
    struct Two {
        a: burn::module::Param<Tensor<2>>,
        b: burn::module::Param<Tensor<1>>,
    }

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().convert::<f32>().to_vec::<f32>().unwrap()
    }

    const N: usize = CHUNK * 2 + 77;

    fn start(device: &Device, dtype: DType) -> Two {
        let a: Vec<f32> = (0..N)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) / 50.0)
            .collect();
        Two {
            a: burn::module::Param::from_tensor(
                Tensor::<1>::from_floats(a.as_slice(), device)
                    .reshape([N, 1])
                    .cast(dtype),
            ),
            b: burn::module::Param::from_tensor(
                Tensor::from_floats([0.5, -1.0, 2.0], device).cast(dtype),
            ),
        }
    }

    /// Runs steps `steps` on a least-squares loss whose target changes every step.
    fn run(optim: &mut ModuleOptimizer, mut model: Two, steps: std::ops::Range<usize>) -> Two {
        let device = model.b.val().device();
        for step in steps {
            let target: Vec<f32> = (0..N)
                .map(|i| {
                    (((i * 7919 + step * 104_729) % 2003) as f32 / 1001.0 - 1.0) * (step + 1) as f32
                })
                .collect();
            let target = Tensor::<1>::from_floats(target.as_slice(), &device)
                .reshape([N, 1])
                .cast(model.a.val().dtype());
            let loss = (model.a.val() - target).square().sum()
                + (model.b.val() * model.b.val()).sum().mul_scalar(3.0);
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            model = optim.step(1e-2 * (1.0 + step as f64), model, grads);
        }
        model
    }

    fn burns_adam() -> ModuleOptimizer {
        AdamConfig::new().with_epsilon(1e-8).init()
    }

    fn assert_close(fused: &Two, burn: &Two) {
        let (a, b) = (values(fused.a.val()), values(fused.b.val()));
        let (a_ref, b_ref) = (values(burn.a.val()), values(burn.b.val()));
        for (x, y) in a.iter().zip(&a_ref).chain(b.iter().zip(&b_ref)) {
            assert!((x - y).abs() <= 1e-5 * (1.0 + y.abs()), "{x} vs {y}");
        }
        // The parameters moved (a step that did nothing would also agree).
        assert!((b[0] - 0.5).abs() > 1e-2);
    }

    /// Burn's Adam and this one from the same start on the same losses, on `device`, with
    /// parameters of `dtype`.
    fn agree_on(device: Device, dtype: DType) {
        let fused = run(
            &mut FusedAdam::default().init(),
            start(&device, dtype),
            0..5,
        );
        let burn = run(&mut burns_adam(), start(&device, dtype), 0..5);
        assert_close(&fused, &burn);
    }

    #[test]
    fn the_fused_kernel_matches_burns_adam_over_several_steps() {
        agree_on(Device::flex().autodiff(), DType::F32);
    }

    /// The tensor-op path (wgpu, and any parameter not in f32) on the CPU: f64 parameters.
    #[test]
    fn the_tensor_op_fallback_matches_burns_adam_over_several_steps() {
        agree_on(Device::flex().autodiff(), DType::F64);
    }

    #[test]
    fn a_state_saved_by_burns_adam_resumes_here() {
        let device = Device::flex().autodiff();
        let mut adam = burns_adam();
        let half = run(&mut adam, start(&device, DType::F32), 0..3);
        let bytes = adam.into_bytes().unwrap();
        let mut fused = FusedAdam::default().init().from_bytes(bytes).unwrap();
        let resumed = run(&mut fused, half, 3..5);
        let burn = run(&mut burns_adam(), start(&device, DType::F32), 0..5);
        assert_close(&resumed, &burn);
        // Without the saved moments the resumed run would differ.
        let half = run(&mut burns_adam(), start(&device, DType::F32), 0..3);
        let fresh = run(&mut FusedAdam::default().init(), half, 3..5);
        let diff = (values(fresh.b.val())[0] - values(burn.b.val())[0]).abs();
        assert!(diff > 1e-4, "moments made no difference ({diff})");
    }
}
