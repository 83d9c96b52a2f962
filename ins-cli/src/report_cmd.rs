//! `ins-cli report`: one static HTML page for a stylized NeRF or IDR run (no server needed): the
//! painting, pretrained and stylized views side by side, the path animations, depth before and
//! after stylization, the loss curves and the consistency / style / content tables.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ins_core::imaging::RgbImage;
use serde_json::Value;

use ins_models::consistency::evaluate::{BASELINE_STEPS, FRAMES, REFERENCE_STEPS, REFERENCE_VIEWS};
use ins_models::consistency::{ConsistencyOptions, StylizedPair, evaluate};
use ins_models::mesh_export::{MeshFormat, MeshFrame, export_mesh};
use ins_models::run::MeshOptions;

#[derive(Args, Debug)]
pub struct Report {
    /// A stylized NeRF or IDR run. Its `consistency/` evaluation is used when present, and run first
    /// (with the options below) when not.
    #[arg(long)]
    run: PathBuf,
    /// Output folder: index.html with its pictures beside it.
    #[arg(long, default_value = "report")]
    out: PathBuf,
    /// Run the consistency evaluation again even if the run has one.
    #[arg(long)]
    refresh: bool,
    #[command(flatten)]
    eval: EvalOptions,
}

/// The options of the consistency evaluation a report runs when the run has none.
#[derive(Args, Debug)]
struct EvalOptions {
    /// Frames of the path.
    #[arg(long, default_value_t = FRAMES)]
    frames: usize,
    /// Frame size WxH (default: the run's training resolution).
    #[arg(long)]
    size: Option<String>,
    /// Include the per-view 2D baseline.
    #[arg(long)]
    baseline2d: bool,
    /// Optimisation steps per frame of the 2D baseline.
    #[arg(long, default_value_t = BASELINE_STEPS)]
    baseline_steps: usize,
    /// Views at which the texture on the object is measured.
    #[arg(long, default_value_t = REFERENCE_VIEWS)]
    reference_views: usize,
    /// Steps of the converged 2D reference per view.
    #[arg(long, default_value_t = REFERENCE_STEPS)]
    reference_steps: usize,
    #[command(flatten)]
    device: crate::common::DeviceArgs,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    #[command(flatten)]
    vgg: crate::common::VggArgs,
}

/// The files of the evaluation folder a report shows, as (source name, name in the report).
const COPIED: &[(&str, &str)] = &[
    ("painting.png", "painting.png"),
    ("stylized.gif", "stylized.gif"),
    ("pretrained.gif", "pretrained.gif"),
    ("baseline2d.gif", "baseline2d.gif"),
    ("depth_pretrained.png", "depth_pretrained.png"),
    ("depth_stylized.png", "depth_stylized.png"),
    ("strength_consistency.png", "strength_consistency.png"),
];

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn copy(from: &Path, to: &Path) -> Result<()> {
    std::fs::copy(from, to)
        .with_context(|| format!("copying {} to {}", from.display(), to.display()))?;
    Ok(())
}

/// Four frames around the path: pretrained above stylized (above the 2D baseline).
fn side_by_side(eval_dir: &Path, frames: usize) -> Result<RgbImage> {
    let picks: Vec<usize> = (0..4).map(|i| i * frames / 4).collect();
    let mut rows = Vec::new();
    for set in ["pretrained", "stylized", "baseline2d"] {
        let dir = eval_dir.join(set);
        if !dir.is_dir() {
            continue;
        }
        let row = picks
            .iter()
            .map(|i| RgbImage::load(&dir.join(format!("frame_{i:04}.png"))))
            .collect::<Result<Vec<_>>>()?;
        rows.push(RgbImage::hstack(&row));
    }
    Ok(RgbImage::vstack(&rows))
}

fn fmt(v: &Value) -> String {
    match v {
        Value::Number(n) => {
            let x = n.as_f64().unwrap_or(f64::NAN);
            if x.abs() >= 1000.0 || (x != 0.0 && x.abs() < 1e-3) {
                format!("{x:.3e}")
            } else {
                format!("{x:.4}")
            }
        }
        Value::Null => "–".into(),
        other => escape(&other.to_string()),
    }
}

/// The last metrics line of a run that has `key`.
pub(crate) fn last_with(run: &Path, key: &str) -> Option<Value> {
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).ok()?;
    text.lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .find(|v| v.get(key).is_some())
}

pub fn run(a: Report) -> Result<()> {
    let e = &a.eval;
    let options = ConsistencyOptions {
        frames: e.frames,
        size: e
            .size
            .as_deref()
            .map(crate::common::parse_size)
            .transpose()?,
        baseline2d: e.baseline2d,
        baseline_steps: e.baseline_steps,
        reference_views: e.reference_views,
        reference_steps: e.reference_steps,
        ..ConsistencyOptions::default()
    };
    let device = e.device.device()?;
    let report = write_report(
        &a.run, &a.out, a.refresh, &options, &e.vgg, e.quiet, &device,
    )?;
    println!("{}", report.index.display());
    Ok(())
}

/// A written report.
pub struct WrittenReport {
    /// Its page.
    pub index: PathBuf,
    /// The density level its mesh was cut at (NeRF runs with a mesh): a finer mesh of the same
    /// run reuses it instead of rendering views to find it again.
    pub mesh_level: Option<f32>,
}

/// Writes the report of the stylized run `run` into `out` (its `index.html`, with the pictures
/// beside it), first running the consistency evaluation with `options` when the run has none
/// or `refresh` asks for it.
pub fn write_report(
    run: &Path,
    out: &Path,
    refresh: bool,
    options: &ConsistencyOptions,
    vgg: &crate::common::VggArgs,
    quiet: bool,
    device: &burn::prelude::Device,
) -> Result<WrittenReport> {
    let eval_dir = run.join("consistency");
    let summary_path = eval_dir.join("summary.json");
    if refresh || !summary_path.is_file() {
        if !run.join("config.json").is_file() {
            bail!("{} is not a run folder (no config.json)", run.display());
        }
        eprintln!(
            "{} has no consistency evaluation yet: running it",
            run.display()
        );
        let pair = StylizedPair::load(run, device)?;
        let vgg = vgg.load(device)?;
        let mut progress = crate::consistency_cmd::CliProgress::new(quiet);
        evaluate(&pair, options, &vgg, device, &mut progress)?;
    }
    let summary: Value = serde_json::from_str(
        &std::fs::read_to_string(&summary_path)
            .with_context(|| format!("reading {}", summary_path.display()))?,
    )
    .with_context(|| format!("{} is not a consistency summary", summary_path.display()))?;
    let pretrained_run = PathBuf::from(
        summary["pretrained_run"]
            .as_str()
            .context("the summary names no pretrained run")?,
    );

    if out.exists() && !out.join("index.html").is_file() {
        let empty = std::fs::read_dir(&out)
            .map(|mut d| d.next().is_none())
            .unwrap_or(false);
        if !empty {
            bail!(
                "{} exists and is not a report (no index.html): choose another --out",
                out.display()
            );
        }
    }
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let mut shown = Vec::new();
    for (src, dst) in COPIED {
        let p = eval_dir.join(src);
        if p.is_file() {
            copy(&p, &out.join(dst))?;
            shown.push(*dst);
        }
    }
    let frames = summary["frames"].as_u64().unwrap_or(0) as usize;
    side_by_side(&eval_dir, frames)?.save(&out.join("views.png"))?;
    let mut curves = Vec::new();
    for (folder, name) in [
        (pretrained_run.as_path(), "loss_pretrain.png"),
        (run, "loss_stylize.png"),
    ] {
        let p = folder.join("loss_curve.png");
        if p.is_file() {
            copy(&p, &out.join(name))?;
            curves.push(name);
        }
    }
    let mesh = report_mesh(run, out, device);
    if let Err(e) = &mesh {
        eprintln!("the report shows no mesh: {e}");
    }
    let mut html = page(run, &pretrained_run, &summary, &shown, &curves);
    let at = html.find("<h2>Files</h2>").unwrap_or(html.len());
    html.insert_str(at, &mesh_section(&mesh));
    let index = out.join("index.html");
    ins_io::write_atomic(&index, html.as_bytes())?;
    let mesh_level = mesh
        .ok()
        .and_then(|m| m["level"].as_f64())
        .map(|l| l as f32);
    Ok(WrittenReport { index, mesh_level })
}

/// Samples along the longest side of the report's mesh: a few megabytes the page embeds.
const REPORT_MESH_RESOLUTION: usize = 128;

/// Exports the stylized run's surface into the report as `mesh.glb`, and as `mesh.js` (the same
/// bytes in base64: a page opened from disk may not fetch files); returns the exporter's summary.
fn report_mesh(run: &Path, out: &Path, device: &burn::prelude::Device) -> Result<Value> {
    let glb = out.join("mesh.glb");
    let options = MeshOptions {
        resolution: REPORT_MESH_RESOLUTION,
        level: None,
    };
    let summary = export_mesh(
        run,
        options,
        None,
        MeshFormat::Glb,
        MeshFrame::Scene,
        &glb,
        device,
    )?;
    let bytes = std::fs::read(&glb).with_context(|| format!("reading {}", glb.display()))?;
    use base64::Engine as _;
    let js = format!(
        "window.INS_MESH_GLB=\"{}\";\n",
        base64::engine::general_purpose::STANDARD.encode(&bytes)
    );
    ins_io::write_atomic(&out.join("mesh.js"), js.as_bytes())?;
    Ok(summary)
}

/// The 3D view of the mesh (or why there is none).
fn mesh_section(mesh: &Result<Value>) -> String {
    let mut h = String::from("<h2>The stylized surface as a mesh</h2>");
    match mesh {
        Ok(m) => {
            let _ = write!(
                h,
                "<p>Marching cubes of the stylized run's surface at {REPORT_MESH_RESOLUTION} \
                 samples along its longest side, coloured by the stylized radiance: {} vertices, \
                 {} triangles. Drag to turn it. The same file: <a href=\"mesh.glb\">mesh.glb</a> \
                 (glTF; Blender, three.js, Windows' 3D Viewer).</p>\
                 <canvas id=\"mesh\" width=\"480\" height=\"480\" data-mesh=\"pending\" \
                 style=\"border:1px solid #ccc;cursor:grab\"></canvas>\
                 <script src=\"mesh.js\"></script><script>{}</script>",
                m["vertices"],
                m["triangles"],
                include_str!("report_mesh.js")
            );
        }
        Err(e) => {
            let _ = write!(h, "<p>No mesh: {}</p>", escape(&format!("{e:#}")));
        }
    }
    h
}

/// The painting's texture on the object: nearest-neighbour feature distances per layer at the
/// reference views, the transfer ratios, and the strength/consistency picture.
fn texture_section(h: &mut String, s: &Value, picture: bool) {
    let Some(sets) = s["texture"]["sets"].as_array() else {
        return;
    };
    h.push_str(
        "<h2>The painting's texture on the object</h2><p>At a few views of the path, for each          position on the object, 1 − the best cosine similarity of its VGG feature to any          position of the painting (lower: nearer the painting), and the share of the way from          the pretrained frames to Gatys' method run to convergence on the same views that each          set went (the transfer ratio; 1: as far as the converged 2D result). relu1_2 and          relu2_2 mostly read colour (the palette), relu3_3 and relu4_3 strokes (the texture).         </p><table><tr><th>frames</th><th>relu1_2</th><th>relu2_2</th><th>relu3_3</th>         <th>relu4_3</th><th>palette transfer</th><th>texture transfer</th></tr>",
    );
    for set in sets {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(set["set"].as_str().unwrap_or("?")),
            fmt(&set["nn_relu1_2"]),
            fmt(&set["nn_relu2_2"]),
            fmt(&set["nn_relu3_3"]),
            fmt(&set["nn_relu4_3"]),
            fmt(&set["palette_transfer"]),
            fmt(&set["texture_transfer"])
        );
    }
    h.push_str("</table>");
    if picture {
        figure(
            h,
            "strength_consistency.png",
            "texture transfer against warp RMSE: strength and consistency at once",
        );
    }
}

fn figure(out: &mut String, src: &str, caption: &str) {
    let _ = write!(
        out,
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        escape(src),
        escape(caption),
        escape(caption)
    );
}

fn page(run: &Path, pretrained: &Path, s: &Value, shown: &[&str], curves: &[&str]) -> String {
    let has = |f: &str| shown.contains(&f);
    let mut h = String::new();
    let title = format!("INS-rs report: {}", run.display());
    let _ = write!(
        h,
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>\
         body{{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}}\
         figure{{display:inline-block;margin:0 1em 1em 0;vertical-align:top}}\
         img{{max-width:100%;min-width:160px;image-rendering:pixelated;border:1px solid #ccc}}\
         table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #bbb;padding:.3em .7em;text-align:right}}\
         th:first-child,td:first-child{{text-align:left}}#broken{{color:#b00}}\
         </style></head><body data-images=\"pending\">",
        escape(&title)
    );
    let _ = write!(
        h,
        "<h1>{}</h1><p>Stylized run <code>{}</code>, pretrained run <code>{}</code>, painting \
         <code>{}</code>; {} frames of a {} path at {}×{}.</p><p id=\"broken\"></p>",
        escape(&title),
        escape(&run.display().to_string()),
        escape(&pretrained.display().to_string()),
        escape(s["painting"].as_str().unwrap_or("?")),
        s["frames"],
        escape(s["path"].as_str().unwrap_or("default")),
        s["size"][0],
        s["size"][1]
    );
    h.push_str("<h2>Painting and views</h2>");
    if has("painting.png") {
        figure(&mut h, "painting.png", "the painting");
    }
    let rows = if has("baseline2d.gif") {
        "pretrained (top), stylized (middle), per-view 2D baseline (bottom)"
    } else {
        "pretrained (top), stylized (bottom)"
    };
    figure(
        &mut h,
        "views.png",
        &format!("four frames of the path: {rows}"),
    );
    h.push_str("<h2>Path animations</h2>");
    for (f, c) in [
        ("pretrained.gif", "pretrained"),
        ("stylized.gif", "stylized"),
        ("baseline2d.gif", "per-view 2D baseline"),
    ] {
        if has(f) {
            figure(&mut h, f, c);
        }
    }
    h.push_str("<h2>Depth before and after stylization</h2>");
    for (f, c) in [
        ("depth_pretrained.png", "pretrained depth"),
        ("depth_stylized.png", "stylized depth"),
    ] {
        if has(f) {
            figure(&mut h, f, c);
        }
    }
    let _ = write!(
        h,
        "<p>Median relative depth error of the stylized model on pixels opaque in both: \
         <b>{}</b>; opacity agreement: <b>{}</b>.</p>",
        fmt(&s["depth_rel_error_median"]),
        fmt(&s["opacity_agreement"])
    );
    h.push_str(
        "<h2>View consistency, style and content</h2><p>Masked RMSE (colours in [0, 1]) between \
         frame t warped into frame t+k by the pretrained depth (forward projection with a depth \
         test) and frame t+k; lower is more consistent. Gram distance to the painting \
         (relu1_2…relu4_3) and content distance (relu2_2) to the pretrained render, mean over \
         the frames.</p><table><tr><th>frames</th><th>RMSE k=1</th><th>RMSE k=7</th>\
         <th>Gram distance</th><th>content distance</th></tr>",
    );
    for set in s["sets"].as_array().into_iter().flatten() {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(set["set"].as_str().unwrap_or("?")),
            fmt(&set["rmse_k1"]),
            fmt(&set["rmse_k7"]),
            fmt(&set["gram_distance"]),
            fmt(&set["content_distance"])
        );
    }
    h.push_str("</table>");
    if s.get("baseline_over_stylized_k1").is_some() {
        let _ = write!(
            h,
            "<p>The 2D baseline's RMSE over the stylized run's: <b>{}×</b> at k=1, <b>{}×</b> \
             at k=7 ({} steps per frame).</p>",
            fmt(&s["baseline_over_stylized_k1"]),
            fmt(&s["baseline_over_stylized_k7"]),
            s["baseline2d_steps"]
        );
    }
    texture_section(&mut h, s, has("strength_consistency.png"));
    let (pre, sty) = (last_with(pretrained, "val_psnr"), last_with(run, "style"));
    if pre.is_some() || sty.is_some() {
        h.push_str(
            "<h2>Training</h2><table><tr><th>run</th><th>step</th><th>numbers at the end</th></tr>",
        );
        for (name, line, keys) in [
            ("pretraining", pre, &["val_psnr", "val_ssim"][..]),
            ("stylization", sty, &["style", "content", "geometry"][..]),
        ] {
            if let Some(l) = line {
                let cells: Vec<String> = keys
                    .iter()
                    .filter(|k| l.get(**k).is_some())
                    .map(|k| format!("{k} {}", fmt(&l[*k])))
                    .collect();
                let _ = write!(
                    h,
                    "<tr><td>{name}</td><td>{}</td><td>{}</td></tr>",
                    l["step"],
                    cells.join(", ")
                );
            }
        }
        h.push_str("</table>");
    }
    if !curves.is_empty() {
        h.push_str("<h2>Loss curves</h2>");
        for c in curves {
            let cap = if c.contains("pretrain") {
                "pretraining"
            } else {
                "stylization"
            };
            figure(&mut h, c, cap);
        }
    }
    let _ = write!(
        h,
        "<h2>Files</h2><p>Per pair and per view numbers: <code>{0}/pairs.jsonl</code>, \
         <code>{0}/views.jsonl</code>; the frames: <code>{0}/</code>.</p>",
        escape(&run.join("consistency").display().to_string())
    );
    // Marks the page once every picture has loaded or failed: a reader sees which failed, and a
    // headless browser can check `data-images` without a server.
    h.push_str(
        "<script>window.addEventListener('load',function(){var bad=[];\
         document.querySelectorAll('img').forEach(function(i){\
         if(!(i.complete&&i.naturalWidth>0))bad.push(i.getAttribute('src'));});\
         document.body.dataset.images=bad.length?'broken:'+bad.join(','):'ok';\
         if(bad.length)document.getElementById('broken').textContent=\
         'Pictures that did not load: '+bad.join(', ');});</script></body></html>\n",
    );
    h
}
