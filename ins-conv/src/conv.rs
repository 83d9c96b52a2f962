//! Convolution forward, input gradient and weight gradient on plain slices, as im2col + GEMM
//! over chunks of output pixels, in parallel over (image, chunk).
//!
//! The input gradient is itself a convolution (of the output gradient with the flipped,
//! channel-swapped kernel; see [`Gather::transposed`]), so both run through one routine and
//! any of the GEMM engines. The weight gradient is one `[c_out, pixels] × [pixels, taps]` product per
//! chunk, summed, in f32: a frozen network (VGG) never asks for it.

use rayon::prelude::*;

use crate::bf16::{Block32, TILE, TILE_K, pack_right, round_up};
use crate::engine::{Bf16Block, Engine};
use crate::geometry::{ConvGeometry, Gather};
use crate::im2col::{ImageSource, im2col};
use crate::kernel_matrix::{KernelMatrix, Left};
use crate::vnni_im2col::{UnitGather, im2col_vnni};

/// Bytes of f32 im2col values per chunk: a few hundred kB, so a chunk stays in L2.
const CHUNK_BYTES: usize = 1 << 20;

thread_local! {
    /// Each worker's im2col buffers (f32 and VNNI bf16), kept between calls.
    static SCRATCH: std::cell::RefCell<(Vec<f32>, Vec<u16>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// The starting tile of rows `r0 .. r0 + 16`: each row holds its bias (zero past `m`).
fn bias_tile(bias: Option<&[f32]>, r0: usize, m: usize) -> [f32; 256] {
    let mut t = [0.0f32; 256];
    if let Some(bias) = bias {
        for r in 0..TILE.min(m.saturating_sub(r0)) {
            t[r * TILE..(r + 1) * TILE].fill(bias[r0 + r]);
        }
    }
    t
}

/// A pointer that parallel jobs write disjoint parts of.
#[derive(Clone, Copy)]
struct Shared(*mut f32);
// SAFETY: every job writes a disjoint set of elements (its image, its pixel chunk).
unsafe impl Send for Shared {}
unsafe impl Sync for Shared {}

/// The common routine: `out[b, m, p] = Σ_k left[m, k] · cols_b[k, p] (+ bias[m])`, where
/// `cols_b` is im2col of image `b` of `src` (`[batch, channels, h, w]`) through `gather`.
#[allow(clippy::too_many_arguments)]
fn conv_gemm(
    src: ImageSource,
    batch: usize,
    kernel: [usize; 2],
    gather: [Gather; 2],
    out_hw: [usize; 2],
    left: Left<'_>,
    m: usize,
    bias: Option<&[f32]>,
    relu: bool,
) -> Vec<f32> {
    let channels = src.channels;
    let k = channels * kernel[0] * kernel[1];
    let pixels = out_hw[0] * out_hw[1];
    let chunk = (CHUNK_BYTES / (4 * k)).max(1);
    let chunk = round_up(chunk.min(pixels), 2 * TILE).min(round_up(pixels, 2 * TILE));
    let chunks = pixels.div_ceil(chunk);
    // Every element is written by exactly one job before anything reads it, so the buffer
    // starts uninitialised (zeroing 16 MB per layer showed in profiles).
    let len = batch * m * pixels;
    let mut out = Vec::<f32>::with_capacity(len);
    let dst = Shared(out.as_mut_ptr());
    let (left, packed) = match left {
        Left::F32(a) => {
            assert_eq!(a.len(), m * k, "kernel matrix of the wrong size");
            (a, None)
        }
        Left::Bf16(p, engine) => {
            assert!(
                p.m >= m && p.k == round_up(k, TILE_K),
                "packed kernel of the wrong size"
            );
            (&[][..], Some((p, engine)))
        }
    };
    let job = |cols: &mut Vec<f32>, vnni: &mut Vec<u16>, b: usize, c: usize| {
        // Captures the whole `Shared` (Sync), not its raw pointer field (closures capture
        // fields on their own since edition 2021).
        #[allow(clippy::redundant_locals)]
        let dst = dst;
        let p0 = c * chunk;
        let n = chunk.min(pixels - p0);
        let src = src.image(b);
        // SAFETY: rows `m` of image `b`, columns `p0 .. p0 + n`: this job's alone.
        let out_at =
            |row: usize, col: usize| unsafe { dst.0.add((b * m + row) * pixels + p0 + col) };
        match &packed {
            None => unsafe {
                cols.resize(k * n, 0.0);
                im2col(src, kernel, gather, out_hw[1], p0, n, cols);
                gemm::gemm(
                    m,
                    n,
                    k,
                    out_at(0, 0),
                    1,
                    pixels as isize,
                    false,
                    left.as_ptr(),
                    1,
                    k as isize,
                    cols.as_ptr(),
                    1,
                    n as isize,
                    0.0,
                    1.0,
                    false,
                    false,
                    false,
                    gemm::Parallelism::None,
                );
            },
            Some((a, engine)) => {
                let n_pad = round_up(n, 2 * TILE);
                match (gather[0].unit_offset(), gather[1].unit_offset()) {
                    // SAFETY: both BF16 engines imply AVX-512 F/BW/BF16.
                    (Some(oy), Some(ox)) => unsafe {
                        let unit = UnitGather { offset: [oy, ox] };
                        im2col_vnni(src, kernel, unit, out_hw[1], p0, n, n_pad, vnni)
                    },
                    _ => {
                        cols.resize(k * n, 0.0);
                        im2col(src, kernel, gather, out_hw[1], p0, n, cols);
                        pack_right(cols, k, n, n_pad, vnni);
                    }
                }
                let kblocks = a.k / TILE_K;
                let b_len = kblocks * TILE * TILE_K;
                let mut tiles = Bf16Block::new(*engine);
                let mut block = [0.0f32; 1024];
                for mb in (0..a.m / TILE).step_by(2) {
                    let rows = [a.row_block(mb), a.row_block(mb + 1)];
                    let r0 = mb * TILE;
                    let init = [bias_tile(bias, r0, m), bias_tile(bias, r0 + TILE, m)];
                    for nb in (0..n_pad / TILE).step_by(2) {
                        let ops = Block32 {
                            a: rows,
                            b: [
                                &vnni[nb * b_len..][..b_len],
                                &vnni[(nb + 1) * b_len..][..b_len],
                            ],
                            kblocks,
                            init: [&init[0], &init[1]],
                        };
                        let c0 = nb * TILE;
                        if r0 + 2 * TILE <= m && c0 + 2 * TILE <= n {
                            // SAFETY: rows r0 .. r0 + 32 < m, columns c0 .. c0 + 32 ≤ n.
                            unsafe { tiles.block_32x32(&ops, out_at(r0, c0), pixels) };
                            continue;
                        }
                        // An edge block: through a scratch block.
                        // SAFETY: `block` holds 32 rows of 32.
                        unsafe { tiles.block_32x32(&ops, block.as_mut_ptr(), 2 * TILE) };
                        for r in 0..(2 * TILE).min(m.saturating_sub(r0)) {
                            let w = (2 * TILE).min(n - c0);
                            // SAFETY: row r0 + r < m, columns c0 .. c0 + w ≤ n.
                            unsafe {
                                let from = block[r * 2 * TILE..][..w].as_ptr();
                                std::ptr::copy_nonoverlapping(from, out_at(r0 + r, c0), w)
                            };
                        }
                    }
                }
            }
        }
        for row in 0..m {
            // SAFETY: as above.
            let o = unsafe { std::slice::from_raw_parts_mut(out_at(row, 0), n) };
            if let (None, Some(bias)) = (&packed, bias) {
                o.iter_mut().for_each(|v| *v += bias[row]);
            }
            if relu {
                // A select, not a branch, so that it runs 16 lanes at a time (the filtered
                // loop was scalar and mispredicted on every other value: a fifteenth of a
                // `vgg` step). NaN stays NaN (a diverging loss must still be seen).
                o.iter_mut()
                    .for_each(|v| *v = if *v < 0.0 { 0.0 } else { *v });
            }
        }
    };
    (0..batch * chunks).into_par_iter().for_each(|j| {
        SCRATCH.with_borrow_mut(|(cols, vnni)| job(cols, vnni, j / chunks, j % chunks))
    });
    // SAFETY: the jobs cover every (image, row, pixel) once: images × chunks of pixels × all
    // `m` rows (gemm with `read_dst = false`, or AMX blocks and edge copies), and have finished.
    unsafe { out.set_len(len) };
    out
}

/// `y = conv(x, w) + bias`, then `max(y, 0)` when `relu`: `x [batch, c_in, h, w]`,
/// `w [c_out, c_in, kh, kw]` → `[batch, c_out, ho, wo]`.
pub fn forward(
    x: &[f32],
    w: &[f32],
    bias: Option<&[f32]>,
    g: &ConvGeometry,
    relu: bool,
    engine: Engine,
) -> Vec<f32> {
    match engine {
        Engine::F32 => forward_from(x, Left::F32(w), bias, g, relu),
        bf16 => {
            let kernel = KernelMatrix::forward(w, g, bf16);
            forward_with(x, &kernel, bias, g, relu)
        }
    }
}

/// [`forward`] with the kernel already in its GEMM layout ([`KernelMatrix::forward`]).
pub fn forward_with(
    x: &[f32],
    kernel: &KernelMatrix,
    bias: Option<&[f32]>,
    g: &ConvGeometry,
    relu: bool,
) -> Vec<f32> {
    forward_from(x, kernel.left(), bias, g, relu)
}

fn forward_from(
    x: &[f32],
    left: Left<'_>,
    bias: Option<&[f32]>,
    g: &ConvGeometry,
    relu: bool,
) -> Vec<f32> {
    let src = ImageSource::new(x, g.c_in, g.input);
    let gather = Gather::forward(g);
    conv_gemm(
        src,
        g.batch,
        g.kernel,
        gather,
        g.out_hw(),
        left,
        g.c_out,
        bias,
        relu,
    )
}

/// `∂L/∂x [batch, c_in, h, w]` from `∂L/∂y [batch, c_out, ho, wo]`; with `relu_out` (the
/// output of a fused ReLU), from `∂L/∂y` where that output is positive.
pub fn input_grad(
    grad_out: &[f32],
    relu_out: Option<&[f32]>,
    w: &[f32],
    g: &ConvGeometry,
    engine: Engine,
) -> Vec<f32> {
    let kernel = KernelMatrix::input_grad(w, g, engine);
    input_grad_with(grad_out, relu_out, &kernel, g)
}

/// [`input_grad`] with the kernel already in its GEMM layout ([`KernelMatrix::input_grad`]).
pub fn input_grad_with(
    grad_out: &[f32],
    relu_out: Option<&[f32]>,
    kernel: &KernelMatrix,
    g: &ConvGeometry,
) -> Vec<f32> {
    let t = g.transposed();
    let src = ImageSource {
        gate: relu_out,
        ..ImageSource::new(grad_out, t.c_in, t.input)
    };
    let gather = Gather::transposed(g);
    conv_gemm(
        src,
        g.batch,
        g.kernel,
        gather,
        g.input,
        kernel.left(),
        g.c_in,
        None,
        false,
    )
}

/// `∂L/∂y` where the fused ReLU's output is positive, zero elsewhere.
pub fn relu_gate(grad_out: &[f32], relu_out: &[f32]) -> Vec<f32> {
    grad_out
        .iter()
        .zip(relu_out)
        .map(|(&g, &y)| if y > 0.0 { g } else { 0.0 })
        .collect()
}

/// `∂L/∂w [c_out, c_in, kh, kw]` from the input and `∂L/∂y`, in f32.
pub fn weight_grad(x: &[f32], grad_out: &[f32], g: &ConvGeometry) -> Vec<f32> {
    let k = g.taps();
    let out_hw = g.out_hw();
    let pixels = out_hw[0] * out_hw[1];
    let chunk = (CHUNK_BYTES / (4 * k)).clamp(1, pixels);
    let chunks = pixels.div_ceil(chunk);
    let gather = Gather::forward(g);
    (0..g.batch * chunks)
        .into_par_iter()
        .fold(
            || (vec![0.0f32; g.c_out * k], Vec::new()),
            |(mut acc, mut cols), j| {
                let (b, p0) = (j / chunks, (j % chunks) * chunk);
                let n = chunk.min(pixels - p0);
                cols.resize(k * n, 0.0);
                let src = ImageSource::new(x, g.c_in, g.input).image(b);
                im2col(src, g.kernel, gather, out_hw[1], p0, n, &mut cols);
                let go = &grad_out[(b * g.c_out) * pixels + p0..];
                // SAFETY: acc is [c_out, k]; grad_out rows of this image, columns p0 .. p0 + n;
                // cols [k, n] read transposed.
                unsafe {
                    gemm::gemm(
                        g.c_out,
                        k,
                        n,
                        acc.as_mut_ptr(),
                        1,
                        k as isize,
                        true,
                        go.as_ptr(),
                        1,
                        pixels as isize,
                        cols.as_ptr(),
                        n as isize,
                        1,
                        1.0,
                        1.0,
                        false,
                        false,
                        false,
                        gemm::Parallelism::None,
                    );
                }
                (acc, cols)
            },
        )
        .map(|(acc, _)| acc)
        .reduce(
            || vec![0.0f32; g.c_out * k],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            },
        )
}

/// `∂L/∂bias [c_out]`: the output gradient summed over images and pixels.
pub fn bias_grad(grad_out: &[f32], g: &ConvGeometry) -> Vec<f32> {
    let [ho, wo] = g.out_hw();
    let mut out = vec![0.0f32; g.c_out];
    for (i, plane) in grad_out.chunks(ho * wo).enumerate() {
        out[i % g.c_out] += plane.iter().map(|&v| v as f64).sum::<f64>() as f32;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bf16::{from_bf16, to_bf16};
    use crate::reference;
    use crate::{amx, dpbf16};

    /// Deterministic values in [-1, 1).
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    fn geometries() -> Vec<ConvGeometry> {
        let g = |batch, c_in, c_out, input, kernel, stride, padding| ConvGeometry {
            batch,
            c_in,
            c_out,
            input,
            kernel,
            stride,
            padding,
        };
        vec![
            g(1, 3, 64, [20, 20], [3, 3], [1, 1], [1, 1]), // VGG's first layer
            g(2, 37, 45, [11, 7], [3, 3], [1, 1], [1, 1]), // odd channels, non-square
            g(1, 5, 3, [9, 13], [1, 1], [1, 1], [0, 0]),   // 1×1
            g(2, 6, 17, [10, 9], [3, 2], [2, 3], [1, 0]),  // strides, uneven kernel
            g(1, 4, 33, [8, 8], [5, 5], [1, 1], [2, 2]),   // 5×5, pad 2
            g(1, 9, 10, [7, 7], [3, 3], [3, 3], [0, 0]),   // stride = kernel
            g(1, 70, 40, [6, 5], [3, 3], [1, 1], [1, 1]),  // taps not a multiple of 32
        ]
    }

    fn worst(a: &[f32], b: &[f32], scale: f32) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() / scale)
            .fold(0.0, f32::max)
    }

    /// Input, weight, bias and output gradient of case `i`.
    fn operands(g: &ConvGeometry, i: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let [ho, wo] = g.out_hw();
        (
            values(g.batch * g.c_in * g.input[0] * g.input[1], 1 + i),
            values(g.c_out * g.taps(), 100 + i),
            values(g.c_out, 200 + i),
            values(g.batch * g.c_out * ho * wo, 300 + i),
        )
    }

    fn rounded(v: &[f32]) -> Vec<f32> {
        v.iter().map(|&x| from_bf16(to_bf16(x))).collect()
    }

    #[test]
    fn f32_forward_and_both_gradients_match_plain_loops() {
        for (i, g) in geometries().into_iter().enumerate() {
            let [ho, wo] = g.out_hw();
            let (x, w, b, go) = operands(&g, i as u64);
            let y = forward(&x, &w, Some(&b), &g, false, Engine::F32);
            assert!(
                worst(&y, &reference::forward(&x, &w, Some(&b), &g), 1.0) < 1e-4,
                "{g:?}"
            );
            let dx = input_grad(&go, None, &w, &g, Engine::F32);
            assert!(
                worst(&dx, &reference::input_grad(&w, &go, &g), 1.0) < 1e-4,
                "dx {g:?}"
            );
            let dw = weight_grad(&x, &go, &g);
            assert!(
                worst(&dw, &reference::weight_grad(&x, &go, &g), 1.0) < 1e-3,
                "dw {g:?}"
            );
            let db = bias_grad(&go, &g);
            for co in 0..g.c_out {
                let s: f32 = (0..g.batch)
                    .flat_map(|bi| go[(bi * g.c_out + co) * ho * wo..][..ho * wo].iter())
                    .sum();
                assert!((db[co] - s).abs() < 1e-4, "db {g:?}");
            }
        }
    }

    /// Both BF16 engines multiply the bf16-rounded inputs exactly and sum in f32: against the
    /// plain loops on rounded inputs they agree to f32 summation error; against the f32 result,
    /// to bf16's. Where the CPU has neither, what must hold is that neither is chosen.
    #[test]
    fn bf16_forward_and_input_gradient_are_exact_products_of_rounded_inputs() {
        let engines: Vec<_> = Engine::available()
            .into_iter()
            .filter(|&e| e != Engine::F32)
            .collect();
        let preferred = if amx::available() {
            Engine::Bf16Amx
        } else if dpbf16::available() {
            Engine::Bf16Avx512
        } else {
            Engine::F32
        };
        assert_eq!(Engine::bf16_or_f32(), preferred);
        if engines.is_empty() {
            eprintln!("no BF16 engine on this CPU: only the fallback choice was checked");
        }
        for engine in engines {
            for (i, g) in geometries().into_iter().enumerate() {
                let (x, w, b, go) = operands(&g, i as u64);
                let y = forward(&x, &w, Some(&b), &g, false, engine);
                let exact = reference::forward(&rounded(&x), &rounded(&w), Some(&b), &g);
                assert!(worst(&y, &exact, 1.0) < 1e-4, "{engine:?} rounded {g:?}");
                let full = reference::forward(&x, &w, Some(&b), &g);
                let scale = (g.taps() as f32).sqrt();
                let err = worst(&y, &full, scale);
                assert!(
                    err < 1e-2 && err > 0.0,
                    "{engine:?} bf16 vs f32 {err} {g:?}"
                );
                let dx = input_grad(&go, None, &w, &g, engine);
                let exact_dx = reference::input_grad(&rounded(&w), &rounded(&go), &g);
                assert!(
                    worst(&dx, &exact_dx, 1.0) < 1e-4,
                    "{engine:?} dx rounded {g:?}"
                );
            }
        }
    }
}
