//! The figures of a run: the loss curves (one row per phase; losses on a log axis on the left,
//! PSNR (dB, its own linear axis) on the right when the phase logs one), and the
//! strength/consistency picture of a stylized run's evaluation. Text is drawn with an
//! embedded font (a Latin subset of DejaVu Sans), so the figure looks the same on any machine.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Once;

use anyhow::{Result, anyhow};
use plotters::prelude::*;

/// A subset of DejaVu Sans (Bitstream Vera licence, `assets/LICENSE-DejaVu.txt`).
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans-subset.ttf");
const FAMILY: &str = "ins-sans";

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is part of the binary; failing to parse it is a build defect.
        plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
            .unwrap_or_else(|_| panic!("the embedded plot font does not parse"));
    });
}

/// Curves of one phase: losses (log axis) and PSNR-like metrics (dB).
#[derive(Default, Debug)]
struct PhaseCurves {
    name: String,
    losses: BTreeMap<String, Vec<(f64, f64)>>,
    psnr: BTreeMap<String, Vec<(f64, f64)>>,
}

/// Splits the metrics history into phases, in the order they ran. The loss panel shows the
/// weighted total and the `terms` (the task's loss terms); PSNRs go to their own axis; other
/// metrics (ray counts, hit rates, SSIM) stay in `metrics.jsonl`, off a log axis of losses.
fn phases(history: &[serde_json::Value], terms: &[&str]) -> Vec<PhaseCurves> {
    let mut out: Vec<PhaseCurves> = Vec::new();
    for rec in history {
        let Some(obj) = rec.as_object() else { continue };
        let Some(step) = obj.get("step").and_then(|s| s.as_f64()) else {
            continue;
        };
        let phase = obj.get("phase").and_then(|p| p.as_str()).unwrap_or("");
        if out.last().is_none_or(|p| p.name != phase) {
            out.push(PhaseCurves {
                name: phase.to_string(),
                ..Default::default()
            });
        }
        let cur = out.last_mut().expect("pushed above");
        for (k, v) in obj {
            let is_loss = k == "loss" || terms.contains(&k.as_str());
            if !is_loss && !k.ends_with("psnr") {
                continue;
            }
            let Some(v) = v.as_f64().filter(|v| v.is_finite()) else {
                continue;
            };
            if k.ends_with("psnr") {
                cur.psnr.entry(k.clone()).or_default().push((step, v));
            } else if v > 0.0 {
                let name = if k == "loss" { "total (weighted)" } else { k };
                cur.losses
                    .entry(name.to_string())
                    .or_default()
                    .push((step, v));
            }
        }
    }
    out
}

fn range(series: &BTreeMap<String, Vec<(f64, f64)>>) -> Option<((f64, f64), (f64, f64))> {
    let pts = series.values().flatten();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut any = false;
    for &(x, y) in pts {
        any = true;
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !any {
        return None;
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    Some(((x0, x1), (y0, y1)))
}

fn draw_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing the loss curve: {e:?}")
}

/// Draws the history of a run (records of `metrics.jsonl`) into a PNG at `path`, atomically.
pub fn plot_history(history: &[serde_json::Value], terms: &[&str], path: &Path) -> Result<()> {
    register_font();
    let phases = phases(history, terms);
    let rows = phases.len().max(1) as u32;
    let (w, h) = (1100u32, 330 * rows + 10);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let areas = root.margin(5, 5, 5, 5).split_evenly((rows as usize, 1));
        for (area, phase) in areas.iter().zip(&phases) {
            let (left, right) = if phase.psnr.is_empty() {
                (area.clone(), None)
            } else {
                let (l, r) = area.split_horizontally(w * 62 / 100);
                (l, Some(r))
            };
            draw_losses(&left, phase)?;
            if let Some(r) = right {
                draw_psnr(&r, phase)?;
            }
        }
        if phases.is_empty() {
            root.draw(&Text::new(
                "no metrics logged yet",
                (20, 20),
                (FAMILY, 18).into_font(),
            ))
            .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("plot buffer size"))?;
    ins_io::write_atomic_with(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(|e| anyhow!("writing {}: {e}", path.display()))
    })
}

const COLORS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

fn draw_losses<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    phase: &PhaseCurves,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let Some(((x0, x1), (y0, y1))) = range(&phase.losses) else {
        return Ok(());
    };
    let (y0, y1) = (y0 * 0.8, y1 * 1.25);
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{}: losses", phase.name), (FAMILY, 18).into_font())
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc("value (log scale)")
        .label_style((FAMILY, 13).into_font())
        .axis_desc_style((FAMILY, 14).into_font())
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()
        .map_err(draw_err)?;
    for (i, (name, pts)) in phase.losses.iter().enumerate() {
        let c = COLORS[i % COLORS.len()];
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
            .map_err(draw_err)?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .label_font((FAMILY, 14).into_font())
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_err)?;
    Ok(())
}

fn draw_psnr<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    phase: &PhaseCurves,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let Some(((x0, x1), (y0, y1))) = range(&phase.psnr) else {
        return Ok(());
    };
    let pad = ((y1 - y0) * 0.1).max(0.5);
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{}: PSNR", phase.name), (FAMILY, 18).into_font())
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d(x0..x1, (y0 - pad)..(y1 + pad))
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc("dB")
        .label_style((FAMILY, 13).into_font())
        .axis_desc_style((FAMILY, 14).into_font())
        .draw()
        .map_err(draw_err)?;
    for (i, (name, pts)) in phase.psnr.iter().enumerate() {
        let c = COLORS[(i + 3) % COLORS.len()];
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
            .map_err(draw_err)?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
        if pts.len() < 30 {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(draw_err)?;
        }
    }
    chart
        .configure_series_labels()
        .label_font((FAMILY, 14).into_font())
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(draw_err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phases_split_and_psnr_goes_to_its_own_axis() {
        let h: Vec<serde_json::Value> = vec![
            serde_json::json!({"step": 9, "phase": "fit", "mse": 0.1, "psnr": 10.0, "loss": 0.1, "lr": 1e-3, "ms": 3.0}),
            serde_json::json!({"step": 19, "phase": "fit", "mse": 0.01, "psnr": 20.0, "loss": 0.01, "lr": 1e-3, "ms": 3.0}),
            serde_json::json!({"step": 29, "phase": "stylize", "style": 2.0, "content": 1.0, "loss": 5.0, "rays": 4096.0}),
        ];
        let terms = ["mse", "style", "content"];
        let p = phases(&h, &terms);
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].psnr["psnr"], vec![(9.0, 10.0), (19.0, 20.0)]);
        assert!(p[0].losses.contains_key("mse") && !p[0].losses.contains_key("lr"));
        assert!(
            p[1].psnr.is_empty() && p[1].losses.len() == 3,
            "rays is not a loss"
        );
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("curve.png");
        plot_history(&h, &terms, &out).unwrap();
        let img = image::open(&out).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1100, 670));
        // Something besides the white background was drawn in both rows.
        let dark = |y0: u32, y1: u32| {
            (y0..y1)
                .flat_map(|y| (0..1100).map(move |x| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
                .count()
        };
        assert!(dark(0, 330) > 1000 && dark(340, 670) > 1000);
    }
}

/// One set of frames on the strength/consistency picture.
#[derive(Debug, Clone)]
pub struct StrengthPoint {
    /// `stylized`, `baseline2d`, `pretrained`.
    pub set: String,
    /// Texture transfer (0: the pretrained frames, 1: the converged 2D reference).
    pub texture: f64,
    /// Masked warp RMSE at k = 1 and k = 7.
    pub rmse: [Option<f64>; 2],
}

/// Draws texture transfer (x) against warp RMSE (y; circles k = 1, triangles k = 7) for each set,
/// into a PNG at `path`: strength and consistency in one picture, the better corner bottom
/// right.
pub fn plot_strength_consistency(points: &[StrengthPoint], path: &Path) -> Result<()> {
    register_font();
    let (w, h) = (760u32, 480u32);
    let xs = points.iter().map(|p| p.texture);
    let x1 = xs.clone().fold(1.1f64, f64::max) + 0.1;
    let x0 = xs.fold(-0.1f64, f64::min) - 0.05;
    let y1 = points
        .iter()
        .flat_map(|p| p.rmse.iter().flatten().copied())
        .fold(0.0f64, f64::max)
        * 1.2
        + 1e-3;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "texture transfer against view consistency",
                (FAMILY, 18).into_font(),
            )
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, 0.0..y1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("texture transfer (0: unstylized, 1: Gatys converged)")
            .y_desc("warp RMSE (lower: more consistent)")
            .label_style((FAMILY, 13).into_font())
            .axis_desc_style((FAMILY, 14).into_font())
            .draw()
            .map_err(draw_err)?;
        for (i, p) in points.iter().enumerate() {
            let c = COLORS[i % COLORS.len()];
            let x = p.texture;
            if let Some(y) = p.rmse[0] {
                chart
                    .draw_series(std::iter::once(Circle::new((x, y), 7, c.filled())))
                    .map_err(draw_err)?
                    .label(format!("{}: circle k=1, triangle k=7", p.set))
                    .legend(move |(x, y)| Circle::new((x + 8, y), 6, c.filled()));
            }
            if let Some(y) = p.rmse[1] {
                chart
                    .draw_series(std::iter::once(TriangleMarker::new((x, y), 8, c.filled())))
                    .map_err(draw_err)?;
            }
        }
        chart
            .configure_series_labels()
            .label_font((FAMILY, 14).into_font())
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("plot buffer size"))?;
    ins_io::write_atomic_with(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(|e| anyhow!("writing {}: {e}", path.display()))
    })
}
