//! Run configurations: one struct per command is both its clap flags and its `config.json`.
//!
//! Defaults live once, in the clap attributes ([`clap_defaults`]). A `--config FILE` supplies
//! values that explicit flags override ([`merge_with_file`]); unknown fields in the file are
//! refused with their name (the structs use `deny_unknown_fields`).

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

/// Reads a JSON config, naming the file and, for an unknown or malformed field, the field.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: malformed config", path.display()))
}

/// Config fields that name files or folders (a string or a list of strings).
const PATH_FIELDS: [&str; 4] = ["scene", "from", "styles", "content"];

/// `cfg` as JSON with its [`PATH_FIELDS`] made absolute (against the current directory), so
/// that a run folder can be evaluated, rendered, resumed or stylized from any directory.
fn with_absolute_paths<T: Serialize>(cfg: &T) -> Result<serde_json::Value> {
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
        for key in PATH_FIELDS {
            match fields.get_mut(key) {
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

/// Writes a run's `config.json` into `out`, paths absolute, or, resuming, checks that the run
/// was started with the same configuration (a resumed run with other options would silently be
/// another run).
pub fn write_run_config<T>(cfg: &T, out: &Path, resume: bool) -> Result<()>
where
    T: Serialize + DeserializeOwned + PartialEq,
{
    let path = out.join("config.json");
    let value = with_absolute_paths(cfg)?;
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
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    ins_io::write_atomic(&path, serde_json::to_string_pretty(&value)?.as_bytes())?;
    Ok(())
}

/// The configuration a command runs with: `cli` (parsed flags, defaults included) where a flag
/// was given on the command line, the `file`'s value otherwise (or the default when the file
/// does not set it).
pub fn merge_with_file<T>(cli: T, matches: &ArgMatches, file: Option<&Path>) -> Result<T>
where
    T: Serialize + DeserializeOwned,
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

    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, clap::Args)]
    #[serde(default, deny_unknown_fields)]
    struct Demo {
        #[arg(long, default_value_t = 3)]
        steps: usize,
        #[arg(long, default_value_t = 0.5)]
        lr: f64,
        #[arg(long = "style")]
        styles: Vec<String>,
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

    #[test]
    fn flags_override_the_file_and_the_file_overrides_defaults() {
        assert_eq!(
            Demo::default(),
            Demo {
                steps: 3,
                lr: 0.5,
                styles: vec![]
            }
        );
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("c.json");
        std::fs::write(&f, r#"{"steps": 7, "styles": ["a.png"]}"#).unwrap();
        let (cli, m) = parse(&["--lr", "0.1"]);
        let got = merge_with_file(cli, &m, Some(&f)).unwrap();
        assert_eq!(
            got,
            Demo {
                steps: 7,
                lr: 0.1,
                styles: vec!["a.png".into()]
            }
        );
        let (cli, m) = parse(&["--steps", "2", "--style", "b.png"]);
        let got = merge_with_file(cli, &m, Some(&f)).unwrap();
        assert_eq!(
            got,
            Demo {
                steps: 2,
                lr: 0.5,
                styles: vec!["b.png".into()]
            }
        );
    }

    #[test]
    fn run_configs_keep_absolute_paths_and_resume_from_relative_ones() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let cfg = Demo {
            steps: 3,
            lr: 0.5,
            styles: vec!["some/style.png".into()],
        };
        write_run_config(&cfg, &out, false).unwrap();
        let saved: Demo = read_json(&out.join("config.json")).unwrap();
        let expected = std::env::current_dir().unwrap().join("some/style.png");
        assert_eq!(saved.styles, vec![expected.to_string_lossy().into_owned()]);
        // The same relative options resume the run; other ones are refused.
        write_run_config(&cfg, &out, true).unwrap();
        let other = Demo { steps: 4, ..cfg };
        let e = format!("{:#}", write_run_config(&other, &out, true).unwrap_err());
        assert!(e.contains("another configuration"), "{e}");
    }

    #[test]
    fn unknown_fields_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("c.json");
        std::fs::write(&f, r#"{"steps": 7, "stpes": 9}"#).unwrap();
        let (cli, m) = parse(&[]);
        let e = format!("{:#}", merge_with_file(cli, &m, Some(&f)).unwrap_err());
        assert!(e.contains("stpes") && e.contains("c.json"), "{e}");
    }
}
