//! The loss-curve picture of a run: every term on a log scale, coloured, with a legend.

use std::path::Path;

use anyhow::Result;

use crate::viz::canvas::Canvas;

/// One named curve.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// (step, value) points.
    pub points: Vec<(f64, f64)>,
}

const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];

/// Draws `series` (positive values, log10 y axis) into a PNG at `path`.
pub fn plot_losses(series: &[Series], path: &Path) -> Result<()> {
    let (w, h) = (900u32, 520u32);
    let (left, right, top, bottom) = (70i32, 200i32, 20i32, 40i32);
    let mut c = Canvas::new(w, h, [255, 255, 255]);
    let pts = |s: &Series| {
        s.points
            .iter()
            .filter(|(_, v)| v.is_finite() && *v > 0.0)
            .map(|&(x, v)| (x, v.log10()))
            .collect::<Vec<_>>()
    };
    let all: Vec<(f64, f64)> = series.iter().flat_map(pts).collect();
    let (x0, x1, y0, y1) = if all.is_empty() {
        (0.0, 1.0, 0.0, 1.0)
    } else {
        let x0 = all.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let x1 = all.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        let y0 = all
            .iter()
            .map(|p| p.1)
            .fold(f64::INFINITY, f64::min)
            .floor();
        let y1 = all
            .iter()
            .map(|p| p.1)
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil();
        (
            x0,
            if x1 > x0 { x1 } else { x0 + 1.0 },
            y0,
            if y1 > y0 { y1 } else { y0 + 1.0 },
        )
    };
    let pw = w as i32 - left - right;
    let ph = h as i32 - top - bottom;
    let sx = |x: f64| left + ((x - x0) / (x1 - x0) * pw as f64).round() as i32;
    let sy = |y: f64| top + ph - ((y - y0) / (y1 - y0) * ph as f64).round() as i32;
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    // Decades on the y axis.
    let mut d = y0 as i32;
    while d as f64 <= y1 {
        let y = sy(d as f64);
        c.line(left, y, left + pw, y, grey);
        c.text(4, y - 5, &format!("1e{d}"), black, 2);
        d += 1;
    }
    // Steps on the x axis.
    for i in 0..=4 {
        let x = x0 + (x1 - x0) * i as f64 / 4.0;
        let px = sx(x);
        c.line(px, top, px, top + ph, grey);
        c.text(
            px - 10,
            top + ph + 8,
            &format!("{}", x.round() as i64),
            black,
            2,
        );
    }
    c.text(left + pw / 2 - 20, h as i32 - 14, "step", black, 2);
    c.rect_outline(left, top, pw, ph, black);
    for (i, s) in series.iter().enumerate() {
        let col = PALETTE[i % PALETTE.len()];
        let p = pts(s);
        for win in p.windows(2) {
            c.line(sx(win[0].0), sy(win[0].1), sx(win[1].0), sy(win[1].1), col);
        }
        if p.len() == 1 {
            c.fill_rect(sx(p[0].0) - 2, sy(p[0].1) - 2, 5, 5, col);
        }
        let ly = top + 10 + 22 * i as i32;
        c.fill_rect(left + pw + 12, ly, 20, 4, col);
        c.text(left + pw + 38, ly - 4, &s.name, black, 2);
    }
    c.save(path)
}
