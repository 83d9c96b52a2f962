//! A small MLP's layers run together, a block of rows at a time, where no gradient is asked
//! for (renders, held-out views, the viewer).
//!
//! Why: layer by layer, each hidden activation `[N, 64]` is written to memory by the product,
//! read and written again by the ReLU, and read once more to round it to bf16 for the next
//! product (with the copies, about a fifth of a stylized frame's time). Here 256 rows go
//! through every layer while they sit in the cache, as tiny-cuda-nn's fused MLPs keep them in
//! registers and shared memory: the weights packed once per call, each product computed as the
//! layer alone computes it (bf16 from 32 columns, f32 below), so a render is the same
//! whichever way it runs. It runs where the layers' products run in bf16
//! ([`dense_bf16::active`]); on the GPU backends, trained or not, as [`super::fused_mlp`]'s
//! kernels where every width is at most 64; elsewhere the layers run one by one.

use burn::backend::flex::FlexTensor;
use burn::backend::{
    BackendTensor, DType, DispatchAutodiffContext, DispatchTensor, DispatchTensorKind,
};
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;
use rayon::prelude::*;

use crate::kernels::dense::dense_with;
use crate::kernels::dense_bf16::{
    self, ROW_CHUNK, available, pack_panels, product_packed, row_as_pairs,
};
use crate::kernels::flex::product_on;
use crate::kernels::fused_mlp::fused_chain;

/// Widest output (columns) of a layer in the fused chain; wider layers run one by one.
pub const MAX_COLUMNS: usize = 64;

/// One layer of a chain on the host: `w [i, o]` (row-major, Burn's layout), `bias [o]`, and
/// whether a ReLU follows.
pub struct HostLayer<'a> {
    /// Weights `[i, o]`.
    pub w: &'a [f32],
    /// Bias `[o]`.
    pub bias: &'a [f32],
    /// Input width.
    pub i: usize,
    /// Output width (at most [`MAX_COLUMNS`]).
    pub o: usize,
    /// A ReLU after the layer.
    pub relu: bool,
}

/// `x [n, layers[0].i]` through every layer in turn → `[n, last o]`, each product as the
/// layer alone computes it under a bf16 scope (`kernels::dense` on Flex): in bf16 where the
/// output is [`dense_bf16::worth_it`] wide ([`dense_bf16::forward`]'s sums, to the bit), in f32
/// by the `gemm` crate where it is narrower (the bias, then the product added to it).
///
/// # Panics
/// Unless [`available`], the widths chain up, and each output is 1 to [`MAX_COLUMNS`] wide.
pub fn forward(x: &[f32], n: usize, layers: &[HostLayer]) -> Vec<f32> {
    assert!(available() && !layers.is_empty());
    for (k, l) in layers.iter().enumerate() {
        assert!(
            (1..=MAX_COLUMNS).contains(&l.o) && l.i > 0,
            "layer {k}: {}→{}",
            l.i,
            l.o
        );
        assert!(
            l.w.len() == l.i * l.o && l.bias.len() == l.o,
            "layer {k}: sizes"
        );
        assert!(
            k == 0 || layers[k - 1].o == l.i,
            "layer {k} does not take the last's output"
        );
    }
    let (i0, o_last) = (layers[0].i, layers[layers.len() - 1].o);
    assert_eq!(x.len(), n * i0, "input of {n} rows of {i0}");
    // Packed weights of the layers whose products run in bf16.
    let packed: Vec<Option<Vec<u32>>> = layers
        .iter()
        .map(|l| dense_bf16::worth_it(l.o).then(|| pack_panels(l.w, [l.i, l.o], l.o)))
        .collect();
    let max_pairs = layers.iter().map(|l| l.i.div_ceil(2)).max().unwrap_or(1);
    let max_o = layers.iter().map(|l| l.o).max().unwrap_or(1);
    let mut out = Vec::<f32>::with_capacity(n * o_last);
    out.spare_capacity_mut()[..n * o_last]
        .par_chunks_mut(ROW_CHUNK * o_last)
        .enumerate()
        .for_each(|(ci, out)| {
            let rows = out.len() / o_last;
            let mut pairs = vec![0u32; rows * max_pairs];
            // Two buffers of activations: a layer reads one and writes the other.
            let mut buffers: [Vec<f32>; 2] = [vec![0f32; rows * max_o], vec![0f32; rows * max_o]];
            let mut input = Input::Rows(&x[ci * ROW_CHUNK * i0..][..rows * i0]);
            for (k, l) in layers.iter().enumerate() {
                // Layer k reads what layer k − 1 wrote (buffer k % 2) and writes the other.
                let (even, odd) = buffers.split_at_mut(1);
                let (read, write) = if k % 2 == 0 {
                    (&even[0], &mut odd[0])
                } else {
                    (&odd[0], &mut even[0])
                };
                let src: &[f32] = match input {
                    Input::Rows(r) => r,
                    Input::Buffer => &read[..rows * l.i],
                };
                let last = k + 1 == layers.len();
                let dst = if last {
                    out.as_mut_ptr() as *mut f32
                } else {
                    write.as_mut_ptr()
                };
                match &packed[k] {
                    Some(w) => {
                        let p = l.i.div_ceil(2);
                        as_pairs(src, l.i, &mut pairs);
                        // SAFETY: `pairs` holds `rows` rows of `p` pairs, `dst` `rows·o`
                        // values (`out`'s chunk or a buffer the layer does not read).
                        unsafe { product_packed(&pairs, [p, 1], [rows, p, l.o], w, l.bias, dst) };
                    }
                    // SAFETY: as above; the bias fills each row before the product adds to it.
                    None => unsafe {
                        for r in 0..rows {
                            std::ptr::copy_nonoverlapping(l.bias.as_ptr(), dst.add(r * l.o), l.o);
                        }
                        product_on(
                            gemm::Parallelism::None,
                            [rows, l.i, l.o],
                            dst,
                            true,
                            1.0,
                            (src.as_ptr(), [l.i as isize, 1]),
                            (l.w.as_ptr(), [l.o as isize, 1]),
                        )
                    },
                }
                if l.relu {
                    // SAFETY: the product wrote all `rows·o` values of `dst`.
                    let values = unsafe { std::slice::from_raw_parts_mut(dst, rows * l.o) };
                    values.iter_mut().for_each(|v| *v = v.max(0.0));
                }
                input = Input::Buffer;
            }
        });
    // SAFETY: every chunk's rows were written in full by its last layer.
    unsafe { out.set_len(n * o_last) };
    out
}

/// Where a layer of [`forward`] reads its input: the chain's own rows, or the buffer the
/// layer before wrote.
#[derive(Clone, Copy)]
enum Input<'a> {
    Rows(&'a [f32]),
    Buffer,
}

/// Rows of `width` values as bf16 pairs, `width.div_ceil(2)` a row: an even width's rows are
/// one run of pairs, converted at once; an odd one's last pair of each row takes a 0.
fn as_pairs(rows: &[f32], width: usize, dst: &mut [u32]) {
    if width.is_multiple_of(2) {
        row_as_pairs(rows, dst);
        return;
    }
    let p = width.div_ceil(2);
    for (row, dst) in rows.chunks_exact(width).zip(dst.chunks_exact_mut(p)) {
        row_as_pairs(row, dst);
    }
}

/// `layers` applied in turn to `x [N, I]`, each `(layer, relu)`: `relu(dense(layer, h))` or
/// `dense(layer, h)`. Fused ([`forward`]) on Flex without autodiff where the products run in
/// bf16, and on the GPU backends by [`fused_chain`] where it applies; one layer at a time
/// otherwise.
pub fn dense_chain(x: Tensor<2>, layers: &[(&Linear, bool)]) -> Tensor<2> {
    let layers = layers
        .iter()
        .map(|&(layer, relu)| {
            let w = layer.weight.val();
            let b = match &layer.bias {
                Some(b) => b.val(),
                None => Tensor::zeros([w.dims()[1]], &w.device()),
            };
            (w, b, relu)
        })
        .collect();
    dense_chain_with(x, layers)
}

/// [`dense_chain`] of any weights `[I, O]` and biases `[O]` (parts of layers, biases that fold
/// in what is constant over the rows), each with whether a ReLU follows.
pub fn dense_chain_with(x: Tensor<2>, layers: Vec<(Tensor<2>, Tensor<1>, bool)>) -> Tensor<2> {
    if let Some(y) = fused(&x, &layers).or_else(|| fused_chain(&x, &layers)) {
        return y;
    }
    layers.into_iter().fold(x, |h, (w, b, r)| {
        let h = dense_with(h, w, b);
        if r { relu(h) } else { h }
    })
}

/// The fused chain, where it applies.
fn fused(x: &Tensor<2>, layers: &[(Tensor<2>, Tensor<1>, bool)]) -> Option<Tensor<2>> {
    if layers.is_empty() || !dense_bf16::active() || x.is_autodiff() {
        return None;
    }
    let [n, i0] = x.dims();
    let mut width = i0;
    let mut params = Vec::with_capacity(layers.len());
    for (w, b, relu) in layers {
        let [i, o] = w.dims();
        if i != width || o > MAX_COLUMNS || b.dims() != [o] || n == 0 {
            return None;
        }
        width = o;
        params.push((host(w.clone())?, host(b.clone())?, i, o, *relu));
    }
    let x = host_tensor(x.clone())?;
    let xs = x.as_slice::<f32>()?;
    let host_layers: Vec<HostLayer> = params
        .iter()
        .map(|(w, b, i, o, relu)| HostLayer {
            w,
            bias: b,
            i: *i,
            o: *o,
            relu: *relu,
        })
        .collect();
    let y = forward(xs, n, &host_layers);
    let y = FlexTensor::from_data(TensorData::new(y, [n, width]));
    Some(Tensor::from_dispatch(DispatchTensor {
        kind: DispatchTensorKind::Flex(BackendTensor::Float(y)),
        autodiff: DispatchAutodiffContext::Disabled,
    }))
}

/// A tensor's Flex f32 values, contiguous, if it is one (and not under autodiff).
fn host_tensor<const D: usize>(t: Tensor<D>) -> Option<FlexTensor> {
    if t.is_autodiff() {
        return None;
    }
    match t.into_dispatch().kind {
        DispatchTensorKind::Flex(BackendTensor::Float(f)) if f.dtype() == DType::F32 => {
            Some(crate::kernels::flex::contiguous(&f))
        }
        _ => None,
    }
}

/// A (small) parameter's values on the host.
fn host<const D: usize>(t: Tensor<D>) -> Option<Vec<f32>> {
    host_tensor(t)?.as_slice::<f32>().map(<[f32]>::to_vec)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;
    use burn::tensor::Distribution;

    fn values(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// The fused chain gives what the layers give one by one under a bf16 scope (the 64-wide
    /// products in bf16, the 17- and 3-wide in f32): widths that are not whole vectors or
    /// pairs, rows past one block. Outside a scope, or under autodiff, it is the layers one by
    /// one.
    #[test]
    fn fused_chain_is_the_layers_one_by_one() {
        let d = Device::flex();
        d.seed(21);
        let layers: Vec<Linear> = [(31, 64), (64, 64), (64, 17), (17, 3)]
            .iter()
            .map(|&(i, o)| LinearConfig::new(i, o).init(&d))
            .collect();
        let chain: Vec<(&Linear, bool)> = layers
            .iter()
            .enumerate()
            .map(|(k, l)| (l, k + 1 < layers.len()))
            .collect();
        let n = 2 * ROW_CHUNK + 37;
        let x = Tensor::<2>::random([n, 31], Distribution::Uniform(-2.0, 2.0), &d);
        let one_by_one = |x: Tensor<2>| {
            values(chain.iter().fold(x, |h, &(l, r)| {
                let h = crate::kernels::dense::dense(l, h);
                if r { relu(h) } else { h }
            }))
        };
        let f32_ref = one_by_one(x.clone());
        assert_eq!(
            values(dense_chain(x.clone(), &chain)),
            f32_ref,
            "f32 outside a scope"
        );
        if !available() {
            eprintln!("no AVX-512 BF16 here: the chain runs layer by layer");
            return;
        }
        let _on = dense_bf16::scope(true);
        let want = one_by_one(x.clone());
        let fused = values(dense_chain(x.clone(), &chain));
        let diff = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f32::max)
        };
        // The f32 products may sum in another order on a block than on all rows at once.
        assert!(diff(&fused, &want) < 1e-5, "fused {}", diff(&fused, &want));
        let err = diff(&fused, &f32_ref);
        assert!(
            err > 1e-4 && err < 0.05,
            "the 64-wide products not in bf16: {err}"
        );
        // Under autodiff the layers run one by one (the gradient needs them).
        let da = Device::flex().autodiff();
        let tracked: Vec<Linear> = [(31, 64), (64, 3)]
            .iter()
            .map(|&(i, o)| LinearConfig::new(i, o).init(&da))
            .collect();
        let chain_a: Vec<(&Linear, bool)> = tracked.iter().map(|l| (l, true)).collect();
        let xa = x.autodiff().require_grad();
        let y = dense_chain(xa.clone(), &chain_a);
        let g = y.sum().backward();
        assert!(
            xa.grad(&g).is_some(),
            "no gradient through the chain under autodiff"
        );
    }
}
