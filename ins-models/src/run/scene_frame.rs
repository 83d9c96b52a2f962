//! `scene.json`: how a run's scene was read and framed, written when its field is first trained
//! and checked whenever the scene is read again for the run (stylizing from it, rendering it),
//! so a field is never queried in a frame other than the one it learnt in. Captures are framed
//! by this program (centre, scale, the unit sphere of a surface run), from files that can
//! change and by rules a newer version may change.

use std::path::Path;

use anyhow::{Context, Result, bail};
use ins_scene::data::Scene;

/// Writes `scene.json`: the scene's summary (format, frame, bounds) and the similarity from the
/// capture's world frame to the scene frame (through a temporary file, so a killed run leaves
/// the old one or the new one).
pub fn write_scene_frame(scene: &Scene, path: &Path) -> Result<()> {
    let doc = serde_json::json!({
        "summary": ins_scene::data::check::summarize(scene),
        "to_scene": scene.to_scene,
        "forward_facing": scene.forward_facing,
        "contraction": scene.contraction,
        "bounds": scene.bounds,
    });
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(&doc)?)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Refuses a scene framed otherwise than the `scene.json` its run wrote when it trained (a
/// capture whose files changed, or whose framing a newer version chooses differently): the
/// field would be queried in the wrong place and render noise. Runs from before `scene.json`
/// pass unchecked.
pub fn check_scene_frame(scene: &Scene, path: &Path) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let recorded: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let now = serde_json::json!({
        "to_scene": scene.to_scene,
        "forward_facing": scene.forward_facing,
        "contraction": scene.contraction,
        "bounds": scene.bounds,
    });
    let close = |a: &serde_json::Value, b: &serde_json::Value| -> bool {
        match (a, b) {
            (serde_json::Value::Number(x), serde_json::Value::Number(y)) => {
                let (x, y) = (
                    x.as_f64().unwrap_or(f64::NAN),
                    y.as_f64().unwrap_or(f64::NAN),
                );
                (x - y).abs() <= 1e-4 * x.abs().max(y.abs()).max(1.0)
            }
            _ => a == b,
        }
    };
    fn leaves(v: &serde_json::Value, out: &mut Vec<serde_json::Value>) {
        match v {
            serde_json::Value::Array(a) => a.iter().for_each(|x| leaves(x, out)),
            serde_json::Value::Object(o) => o.values().for_each(|x| leaves(x, out)),
            x => out.push(x.clone()),
        }
    }
    for key in ["to_scene", "forward_facing", "contraction", "bounds"] {
        if recorded.get(key).is_none() {
            // Written before the key was recorded (the bounds were added later).
            continue;
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        leaves(&recorded[key], &mut a);
        leaves(&now[key], &mut b);
        if a.len() != b.len() || a.iter().zip(&b).any(|(x, y)| !close(x, y)) {
            bail!(
                "{}: the scene is framed differently now than when this run trained ({key}: {} \
                 then, {} now; recorded in {}); its files changed, or this version frames such \
                 captures otherwise: pretrain again",
                scene.root.display(),
                recorded[key],
                now[key],
                path.display()
            );
        }
    }
    Ok(())
}
