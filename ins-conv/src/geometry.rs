//! The shape of one 2D convolution (batch, channels, image, kernel, stride, padding), and the
//! index arithmetic that im2col needs for the forward pass and for the input gradient.

/// A stride-`stride`, zero-padded, undilated, ungrouped 2D convolution of an NCHW batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ConvGeometry {
    /// Batch size.
    pub batch: usize,
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Input height and width.
    pub input: [usize; 2],
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Stride along height and width.
    pub stride: [usize; 2],
    /// Zero padding on each side, along height and width.
    pub padding: [usize; 2],
}

impl ConvGeometry {
    /// Output height and width; `None` when the kernel does not fit the padded input.
    #[allow(clippy::needless_range_loop)] // `i` indexes five arrays alike
    pub fn output(&self) -> Option<[usize; 2]> {
        let mut out = [0; 2];
        for i in 0..2 {
            let padded = self.input[i] + 2 * self.padding[i];
            if self.kernel[i] == 0 || self.stride[i] == 0 || padded < self.kernel[i] {
                return None;
            }
            out[i] = (padded - self.kernel[i]) / self.stride[i] + 1;
        }
        Some(out)
    }

    /// Output height and width of a geometry already checked by [`ConvGeometry::output`].
    pub fn out_hw(&self) -> [usize; 2] {
        self.output()
            .expect("a convolution whose kernel fits its input")
    }

    /// Taps per output value: `c_in · kh · kw`.
    pub fn taps(&self) -> usize {
        self.c_in * self.kernel[0] * self.kernel[1]
    }

    /// The input gradient is a convolution too: of the output gradient, dilated by the stride,
    /// with the kernel flipped and its channels swapped. This is that convolution's geometry
    /// (its "input" is the output gradient, its output the input's size); the gather it needs is
    /// [`Gather::transposed`].
    pub fn transposed(&self) -> ConvGeometry {
        let [ho, wo] = self.out_hw();
        ConvGeometry {
            batch: self.batch,
            c_in: self.c_out,
            c_out: self.c_in,
            input: [ho, wo],
            kernel: self.kernel,
            stride: [1, 1],
            padding: [0, 0],
        }
    }
}

/// Where output position `o` and kernel tap `t` read along one axis: source index
/// `(o·a + t + c) / d`, valid when that division is exact and the result lies in `0..len`.
///
/// The forward pass reads `o·stride + t − pad` (`a = stride`, `c = −pad`, `d = 1`). The input
/// gradient, a convolution of the stride-dilated output gradient with the flipped kernel, reads
/// `(o + t + pad − k + 1) / stride` (`a = 1`, `d = stride`): only taps that land on a real
/// (undilated) sample contribute.
#[derive(Clone, Copy, Debug)]
pub struct Gather {
    a: isize,
    c: isize,
    d: isize,
    len: isize,
}

impl Gather {
    /// Gathers of the forward pass along height and width.
    pub fn forward(g: &ConvGeometry) -> [Gather; 2] {
        std::array::from_fn(|i| Gather {
            a: g.stride[i] as isize,
            c: -(g.padding[i] as isize),
            d: 1,
            len: g.input[i] as isize,
        })
    }

    /// Gathers of the input-gradient convolution (over the output gradient) along height and
    /// width, for the forward geometry `g`.
    pub fn transposed(g: &ConvGeometry) -> [Gather; 2] {
        let out = g.out_hw();
        std::array::from_fn(|i| Gather {
            a: 1,
            c: g.padding[i] as isize - g.kernel[i] as isize + 1,
            d: g.stride[i] as isize,
            len: out[i] as isize,
        })
    }

    /// `Some(c)` when this gather reads `o + t + c` (stride 1, no dilation).
    pub fn unit_offset(&self) -> Option<isize> {
        (self.a == 1 && self.d == 1).then_some(self.c)
    }

    /// The source index for output position `o` and tap `t`, if there is one.
    #[inline]
    pub fn source(&self, o: usize, t: usize) -> Option<usize> {
        let num = o as isize * self.a + t as isize + self.c;
        if num < 0 || num % self.d != 0 {
            return None;
        }
        let s = num / self.d;
        (s < self.len).then_some(s as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(
        input: [usize; 2],
        kernel: [usize; 2],
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> ConvGeometry {
        ConvGeometry {
            batch: 1,
            c_in: 1,
            c_out: 1,
            input,
            kernel,
            stride,
            padding,
        }
    }

    #[test]
    fn output_size_follows_the_usual_formula() {
        assert_eq!(
            geometry([7, 5], [3, 3], [1, 1], [1, 1]).output(),
            Some([7, 5])
        );
        assert_eq!(
            geometry([7, 6], [3, 2], [2, 3], [0, 1]).output(),
            Some([3, 3])
        );
        assert_eq!(geometry([2, 2], [5, 5], [1, 1], [1, 1]).output(), None);
    }

    /// Every (input, output, tap) triple the forward gather links is linked by the transposed
    /// gather the other way round, and no other.
    #[test]
    fn transposed_gather_inverts_the_forward_one() {
        for (n, k, s, p) in [
            (7, 3, 1, 1),
            (8, 3, 2, 1),
            (9, 5, 3, 2),
            (4, 1, 1, 0),
            (6, 2, 2, 0),
        ] {
            let g = geometry([n, 1], [k, 1], [s, 1], [p, 0]);
            let [fwd, _] = Gather::forward(&g);
            let [bwd, _] = Gather::transposed(&g);
            let out = g.out_hw()[0];
            let mut forward_links = vec![];
            for o in 0..out {
                for t in 0..k {
                    if let Some(i) = fwd.source(o, t) {
                        forward_links.push((i, o, t));
                    }
                }
            }
            let mut backward_links = vec![];
            for i in 0..n {
                for t_flipped in 0..k {
                    if let Some(o) = bwd.source(i, t_flipped) {
                        backward_links.push((i, o, k - 1 - t_flipped));
                    }
                }
            }
            forward_links.sort();
            backward_links.sort();
            assert_eq!(forward_links, backward_links, "n {n} k {k} s {s} p {p}");
        }
    }
}
