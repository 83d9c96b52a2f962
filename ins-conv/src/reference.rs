//! Plain loops: the definition the fast paths are tested against. The gradients are the
//! forward's loops run backwards (each product's contribution scattered), f64 sums.

use crate::geometry::ConvGeometry;

/// Calls `f(x_index, w_index, y_index)` for every product the convolution sums.
fn for_each_product(g: &ConvGeometry, mut f: impl FnMut(usize, usize, usize)) {
    let [h, wd] = g.input;
    let [ho, wo] = g.out_hw();
    let [kh, kw] = g.kernel;
    for b in 0..g.batch {
        for co in 0..g.c_out {
            for oy in 0..ho {
                for ox in 0..wo {
                    let yi = ((b * g.c_out + co) * ho + oy) * wo + ox;
                    for ci in 0..g.c_in {
                        for ky in 0..kh {
                            for kx in 0..kw {
                                let iy = (oy * g.stride[0] + ky) as isize - g.padding[0] as isize;
                                let ix = (ox * g.stride[1] + kx) as isize - g.padding[1] as isize;
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= wd as isize {
                                    continue;
                                }
                                let xi = ((b * g.c_in + ci) * h + iy as usize) * wd + ix as usize;
                                let wi = ((co * g.c_in + ci) * kh + ky) * kw + kx;
                                f(xi, wi, yi);
                            }
                        }
                    }
                }
            }
        }
    }
}

fn to_f32(v: Vec<f64>) -> Vec<f32> {
    v.into_iter().map(|x| x as f32).collect()
}

/// Direct convolution `[batch, c_out, ho, wo]`.
pub fn forward(x: &[f32], w: &[f32], bias: Option<&[f32]>, g: &ConvGeometry) -> Vec<f32> {
    let [ho, wo] = g.out_hw();
    let mut y: Vec<f64> = (0..g.batch * g.c_out * ho * wo)
        .map(|i| bias.map_or(0.0, |b| b[(i / (ho * wo)) % g.c_out] as f64))
        .collect();
    for_each_product(g, |xi, wi, yi| y[yi] += x[xi] as f64 * w[wi] as f64);
    to_f32(y)
}

/// `∂L/∂x` for `∂L/∂y = grad_out`.
pub fn input_grad(w: &[f32], grad_out: &[f32], g: &ConvGeometry) -> Vec<f32> {
    let mut dx = vec![0.0f64; g.batch * g.c_in * g.input[0] * g.input[1]];
    for_each_product(g, |xi, wi, yi| dx[xi] += grad_out[yi] as f64 * w[wi] as f64);
    to_f32(dx)
}

/// `∂L/∂w` for `∂L/∂y = grad_out`.
pub fn weight_grad(x: &[f32], grad_out: &[f32], g: &ConvGeometry) -> Vec<f32> {
    let mut dw = vec![0.0f64; g.c_out * g.taps()];
    for_each_product(g, |xi, wi, yi| dw[wi] += grad_out[yi] as f64 * x[xi] as f64);
    to_f32(dw)
}
