//! `ins-cli data …`: inspect scenes (summary, sanity checks, contact sheet), print the rays of
//! pixels, and write small analytic scenes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Subcommand;
use ins_scene::data::check::check_scene;
use ins_scene::data::colmap_model::Encoding;
use ins_scene::data::contact_sheet::contact_sheet;
use ins_scene::data::synthetic::{self, SynthOptions};
use ins_scene::data::{LoadOptions, Scene, SceneFormat, Split};
use ins_scene::geometry::Bounds;

/// Scene data commands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Summarize a scene folder (format detected), run geometric sanity checks and write a
    /// contact sheet of thumbnails with the bounding volume drawn in.
    Check {
        /// Scene folder (Blender, LLFF, DTU/IDR, COLMAP workspace or transforms.json capture).
        dir: PathBuf,
        #[command(flatten)]
        read: ReadArgs,
        /// Print the report as JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Where to write the contact sheet PNG [default: ./<scene>-contact.png].
        #[arg(long)]
        sheet: Option<PathBuf>,
        /// Do not write a contact sheet.
        #[arg(long, conflicts_with = "sheet")]
        no_sheet: bool,
    },
    /// Print one JSON line per pixel: the ray through its centre, in the scene frame (DTU: the
    /// unit-sphere frame; LLFF: the rescaled, recentred frame).
    Rays {
        /// Scene folder.
        dir: PathBuf,
        /// Split the view index counts in.
        #[arg(long, default_value = "train")]
        split: Split,
        /// View index within the split.
        #[arg(long)]
        view: usize,
        /// Pixel as COLUMN,ROW (integers; the ray goes through the centre (u+0.5, v+0.5)).
        #[arg(long = "pixel", required = true, value_parser = parse_pixel)]
        pixels: Vec<(u32, u32)>,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Write a small analytic scene (spheres, boxes, checker textures) in a dataset format.
    Synth {
        /// blender, llff, dtu, colmap or transforms.
        #[arg(long)]
        format: SceneFormat,
        /// Captures (colmap, transforms): `object` (around a tabletop in a room), `studio` (around
        /// the tabletop's objects before a plain backdrop) or `forward` (a forward-facing grid).
        /// DTU: `object` (the tabletop), `notched` (a block with a hollow corner that masks
        /// alone cannot carve, for checking that a surface keeps its concavities) or `domed`
        /// (the tabletop's objects inside a painted dome, for training without masks).
        #[arg(long, default_value = "object")]
        layout: String,
        /// COLMAP: write the model as text instead of binary.
        #[arg(long)]
        text: bool,
        /// transforms: every other photo cropped to portrait, with its own size and intrinsics
        /// (a capture that mixes orientations).
        #[arg(long)]
        mixed_orientations: bool,
        /// Output folder (created).
        #[arg(long)]
        out: PathBuf,
        /// Image width in pixels.
        #[arg(long, default_value_t = 64)]
        size: u32,
        /// Number of views (Blender: training views; val and test get a quarter each).
        #[arg(long, default_value_t = 10)]
        views: usize,
    },
    /// Pose a folder of plain photos with COLMAP's structure from motion (through pycolmap,
    /// installed on first use) and write a COLMAP workspace to train on.
    Sfm(crate::sfm_cmd::SfmArgs),
}

/// How a scene is read by the data commands.
#[derive(clap::Args, Debug)]
pub struct ReadArgs {
    /// Integer downscale factor applied when loading (pixels count in the downscaled image).
    #[arg(long, default_value_t = 1)]
    downscale: u32,
    /// Read the folder as this format instead of detecting it (blender, llff, dtu, colmap,
    /// transforms).
    #[arg(long)]
    format: Option<SceneFormat>,
    /// COLMAP: the folder of the photos the model names (default: images/ in the workspace).
    #[arg(long)]
    images: Option<PathBuf>,
}

impl ReadArgs {
    fn load(&self, dir: &Path, splits: Option<Vec<Split>>) -> Result<Scene> {
        let opts = LoadOptions {
            downscale: self.downscale,
            splits,
            image_dir: self.images.clone(),
            ..Default::default()
        };
        Ok(match self.format {
            Some(f) => Scene::load_as(f, dir, &opts)?,
            None => Scene::load(dir, &opts)?,
        })
    }
}

/// Runs a data command.
pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Check {
            dir,
            read,
            json,
            sheet,
            no_sheet,
        } => check(&dir, &read, json, sheet, no_sheet),
        DataCommand::Rays {
            dir,
            split,
            view,
            pixels,
            read,
        } => rays(&dir, split, view, &pixels, &read),
        DataCommand::Sfm(args) => crate::sfm_cmd::run(args),
        DataCommand::Synth {
            format,
            layout,
            text,
            mixed_orientations,
            out,
            size,
            views,
        } => {
            if mixed_orientations && format != SceneFormat::Transforms {
                bail!("--mixed-orientations is for --format transforms");
            }
            let opts = SynthOptions { size, views };
            let dtu_only = match layout.as_str() {
                "notched" => Some(("a notched block", synthetic::AnalyticScene::notched_block())),
                "domed" => Some(("objects inside a dome", synthetic::AnalyticScene::domed())),
                _ => None,
            };
            if let Some((what, scene)) = dtu_only {
                if format != SceneFormat::Dtu {
                    bail!("--layout {layout} is for --format dtu");
                }
                let s = synthetic::write_dtu_of(scene, &out, &opts)?;
                println!(
                    "wrote {what} as a dtu scene with {} views to {}",
                    s.views.len(),
                    out.display()
                );
                return Ok(());
            }
            let layout = match layout.as_str() {
                "object" => synthetic::CaptureLayout::ObjectCentred,
                "studio" => synthetic::CaptureLayout::Studio,
                "forward" => synthetic::CaptureLayout::ForwardFacing,
                other => {
                    bail!("--layout {other}: expected object, studio, forward, notched or domed")
                }
            };
            let encoding = if text {
                Encoding::Text
            } else {
                Encoding::Binary
            };
            let s = match format {
                SceneFormat::Colmap => synthetic::write_colmap(&out, &opts, layout, encoding)?,
                SceneFormat::Transforms => synthetic::write_transforms(&out, &opts, layout)?,
                _ => synthetic::write(format, &out, &opts)?,
            };
            if mixed_orientations {
                let cropped = synthetic::portrait_every_other(&out)?;
                println!("{} photos cropped to portrait", cropped.len());
            }
            println!(
                "wrote a {format} scene with {} views to {}",
                s.views.len(),
                out.display()
            );
            Ok(())
        }
    }
}

fn parse_pixel(s: &str) -> Result<(u32, u32), String> {
    let (u, v) = s
        .split_once(',')
        .ok_or_else(|| format!("pixel {s:?} is not COLUMN,ROW"))?;
    let p = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("pixel {s:?}: {t:?} is not a non-negative integer"))
    };
    Ok((p(u)?, p(v)?))
}

fn check(
    dir: &Path,
    read: &ReadArgs,
    json: bool,
    sheet: Option<PathBuf>,
    no_sheet: bool,
) -> Result<()> {
    let t = Instant::now();
    let scene = read.load(dir, None)?;
    let load_s = t.elapsed().as_secs_f64();
    let report = check_scene(&scene);
    let sheet_path = if no_sheet {
        None
    } else {
        let p = sheet.unwrap_or_else(|| PathBuf::from(format!("{}-contact.png", scene.name)));
        contact_sheet(&scene, 16, 200).save_png(&p)?;
        Some(p)
    };
    if json {
        let v = serde_json::json!({
            "summary": report.summary,
            "checks": report.checks,
            "load_seconds": load_s,
            "contact_sheet": sheet_path.as_ref().map(|p| p.display().to_string()),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let s = &report.summary;
        println!("scene    {} ({}) at {}", s.name, s.format, s.root);
        println!(
            "views    {}: train {}, val {}, test {}",
            s.views, s.train, s.val, s.test
        );
        println!(
            "images   {}×{}, focal {:.2} × {:.2} (fx {:.2}–{:.2} over views), principal point ({:.2}, {:.2})",
            s.width,
            s.height,
            s.focal[0],
            s.focal[1],
            s.focal_x_range[0],
            s.focal_x_range[1],
            s.principal_point[0],
            s.principal_point[1]
        );
        let range = if s.per_ray_range {
            "per ray, clipped to the bounding volume"
        } else {
            "fixed"
        };
        println!("depth    near {:.3}, far {:.3} ({range})", s.near, s.far);
        println!("frame    {}", s.frame);
        if let Some(edges) = &s.edges {
            println!("edges    {edges}");
        }
        if let Some(lens) = &s.lens {
            println!("lens     {lens}");
        }
        for note in &s.notes {
            println!("note     {note}");
        }
        match s.bounds {
            Bounds::Sphere { center, radius } => {
                println!("bounds   sphere centre {center:?} radius {radius}")
            }
            Bounds::Aabb { min, max } => println!(
                "bounds   box {} – {}",
                fmt3(min.to_array()),
                fmt3(max.to_array())
            ),
        }
        match s.mean_mask_coverage {
            Some(c) => println!(
                "masks    {} views, mean foreground {:.1}%",
                s.masks,
                100.0 * c
            ),
            None => println!("masks    none"),
        }
        println!(
            "cameras  {:.3}–{:.3} from the volume's centre; source→scene scale {:.4}",
            s.camera_distance[0], s.camera_distance[1], s.to_scene_scale
        );
        println!("loaded   in {load_s:.2} s");
        println!("checks");
        for c in &report.checks {
            let note = if c.note.is_empty() {
                String::new()
            } else {
                format!("  ({})", c.note)
            };
            println!(
                "  {:<4}  {}: {}/{}{note}",
                if c.ok { "ok" } else { "FAIL" },
                c.name,
                c.passed,
                c.total
            );
        }
        if let Some(p) = &sheet_path {
            println!("contact sheet: {}", p.display());
        }
    }
    if !report.all_ok() {
        let failed = report.checks.iter().filter(|c| !c.ok).count();
        bail!(
            "{failed} of {} checks failed for {}",
            report.checks.len(),
            dir.display()
        );
    }
    Ok(())
}

fn fmt3(v: [f32; 3]) -> String {
    format!("[{:.3}, {:.3}, {:.3}]", v[0], v[1], v[2])
}

fn rays(
    dir: &Path,
    split: Split,
    view: usize,
    pixels: &[(u32, u32)],
    read: &ReadArgs,
) -> Result<()> {
    let scene = read.load(dir, Some(vec![split]))?;
    let views = scene.split(split);
    let &index = views.get(view).with_context(|| {
        format!(
            "split {split} of {} has {} views; view {view} does not exist",
            dir.display(),
            views.len()
        )
    })?;
    let rays = scene.pixel_rays(index, pixels)?;
    for (i, &(u, v)) in pixels.iter().enumerate() {
        let line = serde_json::json!({
            "view": view,
            "pixel": [u, v],
            "origin": rays.origins[i],
            "direction": rays.directions[i],
            "near": rays.near[i],
            "far": rays.far[i],
        });
        println!("{line}");
    }
    Ok(())
}
