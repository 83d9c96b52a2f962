//! The stages of `ins-cli stylize`, kept in the output folder's `stylize.json`: what each stage
//! ran on (a fingerprint of its inputs and options, chained through the stages before it) and
//! whether it finished. A re-run keeps a finished stage whose fingerprint is unchanged,
//! continues an unfinished one from its checkpoint, and redoes a stage (and every stage after
//! it) whose inputs changed: new photos redo everything, another painting only what follows
//! the pretraining.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};

/// A stable 64-bit hash (FNV-1a) of bytes: the same on every machine and toolchain, so a
/// folder's fingerprints survive an upgrade.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fingerprint(u64);

impl Fingerprint {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0100_0000_01b3;

    /// The fingerprint of nothing yet.
    pub fn new() -> Self {
        Self(Self::OFFSET)
    }

    /// Mixes `bytes` in (with their length, so concatenations cannot collide by shifting).
    pub fn bytes(mut self, bytes: &[u8]) -> Self {
        for b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 = (self.0 ^ u64::from(*b)).wrapping_mul(Self::PRIME);
        }
        self
    }

    /// Mixes a string in.
    pub fn text(self, s: &str) -> Self {
        self.bytes(s.as_bytes())
    }

    /// Mixes in the contents of `files`, in order, with their names (a renamed photo is
    /// another capture: its name orders the views).
    pub fn files(mut self, files: &[PathBuf]) -> Result<Self> {
        for f in files {
            let bytes = std::fs::read(f).with_context(|| format!("reading {}", f.display()))?;
            let name = f.file_name().map(|n| n.to_string_lossy().into_owned());
            self = self.text(&name.unwrap_or_default()).bytes(&bytes);
        }
        Ok(self)
    }

    /// Hex digits, as the manifest records it.
    pub fn hex(self) -> String {
        format!("{:016x}", self.0)
    }
}

impl Default for Fingerprint {
    fn default() -> Self {
        Self::new()
    }
}

/// What the manifest remembers of one stage.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StageRecord {
    /// The fingerprint of what it ran on.
    pub inputs: String,
    /// Whether it ran to the end.
    pub finished: bool,
    /// How long it took, over all its attempts.
    pub seconds: f64,
}

/// What a stage does on this run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StageStart {
    /// Finished before on the same inputs: kept.
    Kept,
    /// Started before on the same inputs and stopped: continued.
    Resumed,
    /// Never run, or run on other inputs (its output is removed first).
    Fresh,
}

/// `stylize.json`: every stage's record, written atomically after each change.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct Manifest {
    /// By stage name.
    pub stages: BTreeMap<String, StageRecord>,
    #[serde(skip)]
    path: PathBuf,
}

impl Manifest {
    /// The file name in the output folder.
    pub const FILE: &'static str = "stylize.json";

    /// The manifest of the output folder `out` (empty when there is none yet).
    pub fn load(out: &Path) -> Result<Self> {
        let path = out.join(Self::FILE);
        let mut m: Self = if path.is_file() {
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            serde_json::from_str(&text).with_context(|| {
                format!(
                    "{}: not a stylize manifest (remove it to start the folder afresh)",
                    path.display()
                )
            })?
        } else {
            Self::default()
        };
        m.path = path;
        Ok(m)
    }

    /// What `stage` does given the fingerprint of its inputs.
    pub fn start_of(&self, stage: &str, inputs: Fingerprint) -> StageStart {
        match self.stages.get(stage) {
            Some(r) if r.inputs == inputs.hex() && r.finished => StageStart::Kept,
            Some(r) if r.inputs == inputs.hex() => StageStart::Resumed,
            _ => StageStart::Fresh,
        }
    }

    /// Records that `stage` runs on `inputs` (unfinished), keeping the time already spent on
    /// the same inputs.
    pub fn begin(&mut self, stage: &str, inputs: Fingerprint) -> Result<()> {
        let seconds = match self.stages.get(stage) {
            Some(r) if r.inputs == inputs.hex() => r.seconds,
            _ => 0.0,
        };
        self.stages.insert(
            stage.to_string(),
            StageRecord {
                inputs: inputs.hex(),
                finished: false,
                seconds,
            },
        );
        self.save()
    }

    /// Records that `stage` finished, after `seconds` more.
    pub fn finish(&mut self, stage: &str, seconds: f64) -> Result<()> {
        if let Some(r) = self.stages.get_mut(stage) {
            r.finished = true;
            r.seconds += seconds;
        }
        self.save()
    }

    /// Seconds recorded for `stage` (0 when never run).
    pub fn seconds(&self, stage: &str) -> f64 {
        self.stages.get(stage).map_or(0.0, |r| r.seconds)
    }

    fn save(&self) -> Result<()> {
        if let Some(dir) = self.path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        ins_io::write_atomic(&self.path, serde_json::to_string_pretty(self)?.as_bytes())?;
        Ok(())
    }
}

/// A stage's name as the checklist shows it.
pub fn describe(stage: &str, variant: &str) -> String {
    match stage {
        "poses" => "poses (structure from motion)".into(),
        "pretrain" => format!("pretrain ({variant})"),
        "stylize" => "stylize".into(),
        _ => "video, report, mesh".into(),
    }
}

/// Prints each stage's start and end with its place in the checklist and the time so far.
pub struct StageCounter<'a> {
    pub plan: Vec<&'a str>,
    pub started: Instant,
}

impl StageCounter<'_> {
    fn number(&self, stage: &str) -> String {
        let i = self.plan.iter().position(|s| *s == stage).unwrap_or(0);
        format!("[{}/{}]", i + 1, self.plan.len())
    }

    pub fn begin(&self, stage: &str, manifest: &Manifest, inputs: Fingerprint) -> StageStart {
        let start = manifest.start_of(stage, inputs);
        let how = match start {
            StageStart::Kept => format!(
                "kept (finished before, in {})",
                minutes(manifest.seconds(stage))
            ),
            StageStart::Resumed => "resuming where it stopped".into(),
            StageStart::Fresh => "starting".into(),
        };
        eprintln!("{} {stage}: {how}", self.number(stage));
        start
    }

    pub fn end(&self, stage: &str, manifest: &Manifest, next_estimate: Option<f64>) {
        let left = next_estimate
            .map(|s| format!("; the stylization should take about {}", minutes(s)))
            .unwrap_or_default();
        eprintln!(
            "{} {stage} done ({}; {} so far){left}",
            self.number(stage),
            minutes(manifest.seconds(stage)),
            minutes(self.started.elapsed().as_secs_f64())
        );
    }
}

/// `12 s`, `4.2 min`.
pub fn minutes(seconds: f64) -> String {
    if seconds < 90.0 {
        format!("{seconds:.0} s")
    } else {
        format!("{:.1} min", seconds / 60.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprints_are_stable_and_see_order_names_and_contents() {
        // Nothing mixed in yet: FNV-1a's offset basis.
        assert_eq!(Fingerprint::new().hex(), "cbf29ce484222325");
        let a = Fingerprint::new().text("ab").text("c");
        assert_eq!(a, Fingerprint::new().text("ab").text("c"));
        assert_ne!(a, Fingerprint::new().text("a").text("bc"));
        let dir = tempfile::tempdir().unwrap();
        let (x, y) = (dir.path().join("x.png"), dir.path().join("y.png"));
        std::fs::write(&x, b"one").unwrap();
        std::fs::write(&y, b"two").unwrap();
        let both = Fingerprint::new().files(&[x.clone(), y.clone()]).unwrap();
        assert_ne!(
            both,
            Fingerprint::new().files(&[y.clone(), x.clone()]).unwrap()
        );
        std::fs::write(&y, b"tw0").unwrap();
        assert_ne!(both, Fingerprint::new().files(&[x, y]).unwrap());
    }

    #[test]
    fn a_stage_is_kept_resumed_or_redone_by_its_fingerprint() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (Fingerprint::new().text("a"), Fingerprint::new().text("b"));
        let mut m = Manifest::load(dir.path()).unwrap();
        assert_eq!(m.start_of("pretrain", a), StageStart::Fresh);
        m.begin("pretrain", a).unwrap();
        m.finish("pretrain", 2.0).unwrap();
        m.begin("stylize", a).unwrap();
        // Read back from disk, as a re-run does.
        let mut m = Manifest::load(dir.path()).unwrap();
        assert_eq!(m.start_of("pretrain", a), StageStart::Kept);
        assert_eq!(m.start_of("stylize", a), StageStart::Resumed);
        assert_eq!(m.start_of("stylize", b), StageStart::Fresh);
        // Time spent on the same inputs adds up across attempts, not across inputs.
        m.finish("stylize", 3.0).unwrap();
        m.begin("stylize", a).unwrap();
        m.finish("stylize", 1.0).unwrap();
        assert_eq!(m.seconds("stylize"), 4.0);
        m.begin("stylize", b).unwrap();
        assert_eq!(m.seconds("stylize"), 0.0);
        std::fs::write(dir.path().join(Manifest::FILE), b"{").unwrap();
        let e = format!("{:#}", Manifest::load(dir.path()).unwrap_err());
        assert!(e.contains("stylize.json"), "{e}");
    }
}
