//! Run configurations: one struct per command is both its clap flags and its `config.json`.
//!
//! A config is made of argument groups (`crate::run::args`) flattened both into the clap flags
//! and into one flat JSON object. Defaults live once, in the clap attributes
//! ([`clap_defaults`]). A `--config FILE` supplies values that explicit flags override
//! ([`merge_with_file`]); unknown fields in a file are refused with their name ([`read_json`]
//! checks the keys itself: serde's `deny_unknown_fields` does not combine with `flatten`).
//! Every field whose flag takes a path is stored absolute, found by its type ([`path_fields`]),
//! so a path flag cannot be forgotten. A run's `config.json` also names the variant that wrote
//! it ([`VARIANT_FIELD`]), which is how any run folder is loaded (`crate::run::any`).

use std::path::Path;

use anyhow::{Context, Result};
use clap::parser::ValueSource;
use clap::{ArgMatches, Args, FromArgMatches};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// A config struct with every field at its clap default.
pub fn clap_defaults<T: Args + FromArgMatches>() -> T {
    let cmd = T::augment_args(clap::Command::new("defaults").no_binary_name(true));
    let matches = cmd
        .try_get_matches_from(std::iter::empty::<String>())
        .unwrap_or_else(|e| panic!("a config struct has a required flag: {e}"));
    T::from_arg_matches(&matches).unwrap_or_else(|e| panic!("config defaults: {e}"))
}

/// The fields a config of type `T` has: the keys of its defaults as JSON.
fn known_fields<T: Serialize + Default>() -> Vec<String> {
    match serde_json::to_value(T::default()) {
        Ok(serde_json::Value::Object(fields)) => fields.keys().cloned().collect(),
        _ => Vec::new(),
    }
}

/// The field of a run's `config.json` that names the variant that wrote it (`"nerf"`).
pub const VARIANT_FIELD: &str = "variant";

/// Reads a JSON config, naming the file and, for an unknown or malformed field, the field. The
/// [`VARIANT_FIELD`] a run folder's config carries is not one of `T`'s fields: see
/// [`check_variant`].
pub fn read_json<T: Serialize + DeserializeOwned + Default>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut value: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{}: malformed config", path.display()))?;
    let serde_json::Value::Object(fields) = &mut value else {
        anyhow::bail!("{}: malformed config (not a JSON object)", path.display());
    };
    fields.remove(VARIANT_FIELD);
    let known = known_fields::<T>();
    if let Some(unknown) = fields.keys().find(|k| !known.contains(k)) {
        let mut known = known;
        known.sort();
        anyhow::bail!(
            "{}: malformed config: unknown field `{unknown}` (known fields: {})",
            path.display(),
            known.join(", ")
        );
    }
    serde_json::from_value(value).with_context(|| format!("{}: malformed config", path.display()))
}

/// The fields of `T` that name files or folders: those whose flag parses a path (a path, an
/// optional path or a list of paths).
pub fn path_fields<T: Args>() -> Vec<String> {
    let cmd = T::augment_args(clap::Command::new("paths"));
    cmd.get_arguments()
        .filter(|a| a.get_value_parser().type_id() == std::any::TypeId::of::<std::path::PathBuf>())
        .map(|a| a.get_id().to_string())
        .collect()
}

/// `cfg` as JSON with its [`path_fields`] made absolute (against the current directory), so
/// that a run folder can be evaluated, rendered, resumed or stylized from any directory.
fn with_absolute_paths<T: Serialize + Args>(cfg: &T) -> Result<serde_json::Value> {
    fn absolute(p: &mut String) -> Result<()> {
        let path = Path::new(p.as_str());
        let abs = path
            .canonicalize()
            .or_else(|_| std::path::absolute(path))
            .with_context(|| format!("making {p} an absolute path"))?;
        *p = abs.to_string_lossy().into_owned();
        Ok(())
    }
    let mut value = serde_json::to_value(cfg)?;
    if let serde_json::Value::Object(fields) = &mut value {
        for key in path_fields::<T>() {
            match fields.get_mut(&key) {
                Some(serde_json::Value::String(p)) => absolute(p)?,
                Some(serde_json::Value::Array(items)) => {
                    for item in items {
                        if let serde_json::Value::String(p) = item {
                            absolute(p)?;
                        }
                    }
                }
                _ => {}
            }
        }
    }
    Ok(value)
}

/// Checks that the config file at `path` is one of the variant `key` (`"nerf"`) when it names
/// one: a run folder's config records its variant, and another variant's config is refused by
/// name rather than field by field. A file without the field (written by hand, or by a run
/// before the field existed) passes.
pub fn check_variant(path: &Path, key: &str) -> Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{}: malformed config", path.display()))?;
    match value.get(VARIANT_FIELD) {
        None => Ok(()),
        Some(serde_json::Value::String(k)) if k == key => Ok(()),
        Some(other) => anyhow::bail!(
            "{} names the variant {other}, not \"{key}\"",
            path.display()
        ),
    }
}

/// Writes a run's `config.json` into `out`, paths absolute, with the variant `key` that wrote
/// it; or, resuming, checks that the run was started with the same configuration (a resumed
/// run with other options would silently be another run).
pub fn write_run_config<T>(cfg: &T, key: &str, out: &Path, resume: bool) -> Result<()>
where
    T: Serialize + DeserializeOwned + PartialEq + Default + Args,
{
    let path = out.join("config.json");
    let mut value = with_absolute_paths(cfg)?;
    if resume && path.exists() {
        let saved: T = read_json(&path)?;
        if with_absolute_paths(&saved)? != value {
            anyhow::bail!(
                "{}: the run was started with another configuration; resume with the same options (or --config {})",
                path.display(),
                path.display()
            );
        }
    }
    if let serde_json::Value::Object(fields) = &mut value {
        fields.insert(VARIANT_FIELD.into(), key.into());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    ins_io::write_atomic(&path, serde_json::to_string_pretty(&value)?.as_bytes())?;
    Ok(())
}

/// The configuration a command runs with: `cli` (parsed flags, defaults included) where a flag
/// was given on the command line, the `file`'s value otherwise (or the default when the file
/// does not set it).
pub fn merge_with_file<T>(cli: T, matches: &ArgMatches, file: Option<&Path>) -> Result<T>
where
    T: Serialize + DeserializeOwned + Default,
{
    let Some(file) = file else { return Ok(cli) };
    let from_file: T = read_json(file)?;
    let serde_json::Value::Object(mut merged) = serde_json::to_value(&from_file)? else {
        anyhow::bail!("config structs serialize to objects");
    };
    let serde_json::Value::Object(flags) = serde_json::to_value(&cli)? else {
        anyhow::bail!("config structs serialize to objects");
    };
    for (key, value) in flags {
        let given = matches.ids().any(|id| {
            id.as_str() == key && matches.value_source(&key) == Some(ValueSource::CommandLine)
        });
        if given {
            merged.insert(key, value);
        }
    }
    serde_json::from_value(serde_json::Value::Object(merged))
        .with_context(|| format!("{}: the merged configuration is invalid", file.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use serde::Deserialize;
    use std::path::PathBuf;

    /// A group flattened into [`Demo`], as the run configs' groups are.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, clap::Args)]
    #[serde(default)]
    struct Group {
        #[arg(long, default_value_t = 0.5)]
        lr: f64,
        #[arg(long = "style")]
        styles: Vec<PathBuf>,
    }
    impl Default for Group {
        fn default() -> Self {
            clap_defaults()
        }
    }

    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, clap::Args)]
    #[serde(default)]
    struct Demo {
        #[arg(long, default_value_t = 3)]
        steps: usize,
        /// A string, not a path: stored as given.
        #[arg(long)]
        label: Option<String>,
        #[command(flatten)]
        #[serde(flatten)]
        group: Group,
    }
    impl Default for Demo {
        fn default() -> Self {
            clap_defaults()
        }
    }

    #[derive(Parser)]
    struct Cmd {
        #[command(flatten)]
        demo: Demo,
    }

    fn parse(args: &[&str]) -> (Demo, ArgMatches) {
        use clap::CommandFactory;
        let m = Cmd::command().get_matches_from(std::iter::once("x").chain(args.iter().copied()));
        (Cmd::from_arg_matches(&m).unwrap().demo, m)
    }

    fn demo(steps: usize, lr: f64, styles: &[&str]) -> Demo {
        Demo {
            steps,
            label: None,
            group: Group {
                lr,
                styles: styles.iter().map(PathBuf::from).collect(),
            },
        }
    }

    #[test]
    fn flags_override_the_file_and_the_file_overrides_defaults() {
        assert_eq!(Demo::default(), demo(3, 0.5, &[]));
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("c.json");
        std::fs::write(&f, r#"{"steps": 7, "styles": ["a.png"]}"#).unwrap();
        let (cli, m) = parse(&["--lr", "0.1"]);
        let got = merge_with_file(cli, &m, Some(&f)).unwrap();
        assert_eq!(got, demo(7, 0.1, &["a.png"]));
        let (cli, m) = parse(&["--steps", "2", "--style", "b.png"]);
        let got = merge_with_file(cli, &m, Some(&f)).unwrap();
        assert_eq!(got, demo(2, 0.5, &["b.png"]));
    }

    #[test]
    fn run_configs_keep_absolute_paths_and_resume_from_relative_ones() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let mut cfg = demo(3, 0.5, &["some/style.png"]);
        cfg.label = Some("some/label".into());
        write_run_config(&cfg, "demo", &out, false).unwrap();
        let saved: Demo = read_json(&out.join("config.json")).unwrap();
        let expected = std::env::current_dir().unwrap().join("some/style.png");
        assert_eq!(saved.group.styles, vec![expected]);
        // Found by type: a path inside a flattened group is made absolute, a string is not.
        assert_eq!(saved.label.as_deref(), Some("some/label"));
        // The same relative options resume the run; other ones are refused.
        write_run_config(&cfg, "demo", &out, true).unwrap();
        let other = Demo { steps: 4, ..cfg };
        let e = format!(
            "{:#}",
            write_run_config(&other, "demo", &out, true).unwrap_err()
        );
        assert!(e.contains("another configuration"), "{e}");
    }

    #[test]
    fn unknown_fields_are_refused_by_name_also_beside_flattened_groups() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("c.json");
        std::fs::write(&f, r#"{"steps": 7, "lr": 0.1, "stpes": 9}"#).unwrap();
        let (cli, m) = parse(&[]);
        let e = format!("{:#}", merge_with_file(cli, &m, Some(&f)).unwrap_err());
        assert!(e.contains("stpes") && e.contains("c.json"), "{e}");
        std::fs::write(&f, r#"{"steps": 7, "lr": 0.1}"#).unwrap();
        let got: Demo = read_json(&f).unwrap();
        assert_eq!(got, demo(7, 0.1, &[]));
    }

    #[test]
    fn every_path_flag_of_the_run_configs_is_a_path_field() {
        let nerf = path_fields::<crate::nerf::NerfRunConfig>();
        let idr = path_fields::<crate::idr::IdrRunConfig>();
        let siren = path_fields::<crate::siren::SirenRunConfig>();
        for f in ["scene", "from", "styles"] {
            assert!(
                nerf.contains(&f.to_string()) && idr.contains(&f.to_string()),
                "{f}"
            );
        }
        assert!(siren.contains(&"content".to_string()) && siren.contains(&"styles".to_string()));
        assert!(!nerf.contains(&"steps".to_string()));
    }
}
