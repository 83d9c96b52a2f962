//! im2col: the input values each output pixel's kernel window reads, laid out as the right-hand
//! matrix of a GEMM (`[taps, pixels]`), one chunk of pixels at a time so the matrix never holds a
//! whole image (conv1_2 at 256² would be 150 MB).

use crate::geometry::Gather;

/// One image that im2col reads: `values [channels, h, w]`, and optionally a `gate` of the same
/// shape: a value counts only where its gate is positive (the ReLU's backward, fused: the gate
/// is the ReLU's output).
#[derive(Clone, Copy, Debug)]
pub struct ImageSource<'a> {
    /// The values.
    pub values: &'a [f32],
    /// Zero the values whose gate is not positive.
    pub gate: Option<&'a [f32]>,
    /// Channels.
    pub channels: usize,
    /// Height and width.
    pub hw: [usize; 2],
}

impl<'a> ImageSource<'a> {
    /// Ungated values of `channels × hw` images.
    pub fn new(values: &'a [f32], channels: usize, hw: [usize; 2]) -> Self {
        Self {
            values,
            gate: None,
            channels,
            hw,
        }
    }

    /// Image `b` of a batch held in `values` (and `gate`).
    pub fn image(self, b: usize) -> Self {
        let len = self.channels * self.hw[0] * self.hw[1];
        Self {
            values: &self.values[b * len..(b + 1) * len],
            gate: self.gate.map(|g| &g[b * len..(b + 1) * len]),
            ..self
        }
    }

    /// The value at flat index `i`, gated.
    #[inline]
    pub fn at(&self, i: usize) -> f32 {
        match self.gate {
            Some(g) if g[i] <= 0.0 => 0.0,
            _ => self.values[i],
        }
    }
}

/// Fills `cols` (`[channels·kh·kw, n]`, row-major) for output pixels `p0 .. p0 + n` of one image
/// `src`, reading through `gather`; taps outside the source are zeros.
pub fn im2col(
    src: ImageSource,
    kernel: [usize; 2],
    gather: [Gather; 2],
    out_w: usize,
    p0: usize,
    n: usize,
    cols: &mut [f32],
) {
    let [kh, kw] = kernel;
    let [h, w] = src.hw;
    debug_assert_eq!(cols.len(), src.channels * kh * kw * n);
    let mut row = 0;
    for c in 0..src.channels {
        let plane = c * h * w;
        for ky in 0..kh {
            for kx in 0..kw {
                let dst = &mut cols[row * n..(row + 1) * n];
                let mut p = p0;
                let mut i = 0;
                while i < n {
                    let (oy, ox0) = (p / out_w, p % out_w);
                    let run = (out_w - ox0).min(n - i);
                    match gather[0].source(oy, ky) {
                        None => dst[i..i + run].fill(0.0),
                        Some(iy) => {
                            let line = plane + iy * w;
                            for (j, d) in dst[i..i + run].iter_mut().enumerate() {
                                *d = match gather[1].source(ox0 + j, kx) {
                                    Some(ix) => src.at(line + ix),
                                    None => 0.0,
                                };
                            }
                        }
                    }
                    i += run;
                    p += run;
                }
                row += 1;
            }
        }
    }
}
