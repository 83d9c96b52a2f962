//! `ins-cli view`: a local web viewer of a run. A page (embedded in the binary) asks for
//! pictures over HTTP; a coarse one at once after each camera move, then a full one, which a
//! newer request cancels between bands of rows. Saved views and turntables go to the run's
//! `view/` folder, the only files the server reads back.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use clap::Args;
use ins_scene::viewpoints::ViewerPose;
use serde_json::json;
use tiny_http::{Header, Method, Request, Response, Server};

use crate::common::DeviceArgs;
use crate::counter::Counter;
use crate::viewer::source::{Mode, Source, ViewRequest};

const PAGE: &str = include_str!("viewer/index.html");
/// Largest picture side a request may ask for.
const MAX_SIDE: u32 = 4096;

#[derive(Args, Debug)]
pub struct View {
    /// Run folder written by `train siren|nerf|idr`.
    #[arg(long)]
    run: PathBuf,
    /// Port to serve on (0: any free port).
    #[arg(long, default_value_t = 7860)]
    port: u16,
    /// Address to bind (only this machine by default; 0.0.0.0 shares it on the network).
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// Stop after this many seconds (for scripts; default: run until interrupted).
    #[arg(long)]
    timeout: Option<u64>,
    /// Print a line per request on stderr: method, URL, status, milliseconds.
    #[arg(long)]
    log: bool,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn run(a: View) -> Result<()> {
    let device = a.device.device()?;
    eprintln!("loading {}", a.run.display());
    let source = Source::load(&a.run, &device)?;
    let server = Server::http((a.host.as_str(), a.port)).map_err(|e| {
        let taken = e
            .downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::AddrInUse);
        if taken {
            anyhow::anyhow!(
                "port {} on {} is in use (another viewer?): choose another with --port",
                a.port,
                a.host
            )
        } else {
            anyhow::anyhow!("cannot serve on {}:{}: {e}", a.host, a.port)
        }
    })?;
    let addr = server
        .server_addr()
        .to_ip()
        .context("the server has no IP address")?;
    println!("viewer at http://{addr}/ (Ctrl-C to stop)");
    let latest = Arc::new(AtomicU64::new(0));
    let (tx, rx) = std::sync::mpsc::channel::<Request>();
    {
        let latest = latest.clone();
        std::thread::spawn(move || {
            for rq in server.incoming_requests() {
                if let Some(seq) = query_value(rq.url(), "seq").and_then(|s| s.parse::<u64>().ok())
                {
                    latest.fetch_max(seq, Ordering::SeqCst);
                }
                if tx.send(rq).is_err() {
                    break;
                }
            }
        });
    }
    let deadline = a
        .timeout
        .map(|s| Instant::now() + std::time::Duration::from_secs(s));
    let viewer = Viewer {
        source,
        dir: a.run.clone(),
        device,
        latest,
        log: a.log,
    };
    loop {
        let rq = match deadline {
            Some(d) => match rx.recv_timeout(d.saturating_duration_since(Instant::now())) {
                Ok(rq) => rq,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => return Ok(()),
                Err(e) => bail!("the HTTP server stopped: {e}"),
            },
            None => rx.recv().context("the HTTP server stopped")?,
        };
        viewer.handle(rq);
    }
}

struct Viewer {
    source: Source,
    dir: PathBuf,
    device: Device,
    latest: Arc<AtomicU64>,
    log: bool,
}

type Reply = Response<std::io::Cursor<Vec<u8>>>;

fn header(k: &str, v: &str) -> Header {
    Header::from_bytes(k.as_bytes(), v.as_bytes()).expect("a valid header")
}

fn json_reply(status: u16, v: serde_json::Value) -> Reply {
    Response::from_data(v.to_string().into_bytes())
        .with_status_code(status)
        .with_header(header("Content-Type", "application/json"))
}

fn error_reply(status: u16, msg: &str) -> Reply {
    json_reply(status, json!({ "error": msg }))
}

/// The value of `key` in a URL's query string.
fn query_value(url: &str, key: &str) -> Option<String> {
    let q = url.split_once('?')?.1;
    q.split('&').find_map(|kv| {
        let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
        (k == key).then(|| v.replace("%2C", ",").replace("%2c", ","))
    })
}

impl Viewer {
    fn handle(&self, rq: Request) {
        let url = rq.url().to_string();
        let path = url.split('?').next().unwrap_or("").to_string();
        let started = Instant::now();
        let reply = match (rq.method(), path.as_str()) {
            (Method::Get, "/") => Response::from_data(PAGE.as_bytes().to_vec())
                .with_header(header("Content-Type", "text/html; charset=utf-8")),
            (Method::Get, "/api/info") => json_reply(200, self.source.info()),
            (Method::Get, "/api/render") => self.render(&url, started),
            (Method::Post, "/api/save") => self.save(&url),
            (Method::Post, "/api/turntable") => self.turntable(&url),
            (Method::Get, p) if p.starts_with("/files/") => self.file(&p["/files/".len()..]),
            _ => error_reply(404, &format!("no such page: {path}")),
        };
        let status = reply.status_code().0;
        let method = rq.method().to_string();
        let sent = rq.respond(reply);
        if self.log {
            let ms = started.elapsed().as_secs_f64() * 1e3;
            match sent {
                Ok(()) => eprintln!("{method} {url} {status} {ms:.0} ms"),
                Err(e) => eprintln!("{method} {url} {status} {ms:.0} ms, not sent: {e}"),
            }
        }
    }

    fn request(&self, url: &str) -> Result<ViewRequest> {
        let num = |k: &str, d: f32| -> Result<f32> {
            match query_value(url, k) {
                Some(v) => v
                    .parse::<f32>()
                    .with_context(|| format!("{k}={v:?} is not a number")),
                None => Ok(d),
            }
        };
        let side = |k: &str, d: f32| -> Result<u32> {
            let v = num(k, d)?;
            if !(1.0..=MAX_SIDE as f32).contains(&v) {
                bail!("{k}={v}: a size between 1 and {MAX_SIDE}");
            }
            Ok(v as u32)
        };
        let pose = self.source.clamp(ViewerPose {
            azimuth: num("az", 0.0)?,
            elevation: num("el", 0.0)?,
            distance: num("dist", 1.0)?,
            pan: [num("px", 0.0)?, num("py", 0.0)?],
        });
        let mix = match query_value(url, "mix").filter(|m| !m.is_empty()) {
            Some(m) => m
                .split(',')
                .map(|x| {
                    x.parse::<f32>()
                        .with_context(|| format!("mix weight {x:?}"))
                })
                .collect::<Result<Vec<_>>>()?,
            None => Vec::new(),
        };
        Ok(ViewRequest {
            width: side("w", 200.0)?,
            height: side("h", 200.0)?,
            pose,
            mix,
            mode: Mode::parse(&query_value(url, "mode").unwrap_or_default())?,
        })
    }

    fn render(&self, url: &str, started: Instant) -> Reply {
        let seq = query_value(url, "seq").and_then(|s| s.parse::<u64>().ok());
        let stale = || seq.is_some_and(|s| self.latest.load(Ordering::SeqCst) > s);
        if stale() {
            return error_reply(409, "superseded by a newer view");
        }
        let req = match self.request(url) {
            Ok(r) => r,
            Err(e) => return error_reply(400, &format!("{e:#}")),
        };
        match self.source.render(&req, &self.device, &stale) {
            Ok(Some(img)) => match img.encode_png() {
                Ok(png) => Response::from_data(png)
                    .with_header(header("Content-Type", "image/png"))
                    .with_header(header("Cache-Control", "no-store"))
                    .with_header(header(
                        "X-Render-Ms",
                        &format!("{:.0}", started.elapsed().as_secs_f64() * 1e3),
                    )),
                Err(e) => error_reply(500, &format!("{e:#}")),
            },
            Ok(None) => error_reply(409, "superseded by a newer view"),
            Err(e) => error_reply(500, &format!("{e:#}")),
        }
    }

    fn view_dir(&self) -> Result<PathBuf> {
        let dir = self.dir.join("view");
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        Ok(dir)
    }

    /// The mix as a file-name part (`0.25-0.75`), or `default`.
    fn mix_tag(req: &ViewRequest) -> String {
        if req.mix.is_empty() {
            "default".into()
        } else {
            req.mix
                .iter()
                .map(|m| format!("{m}"))
                .collect::<Vec<_>>()
                .join("-")
        }
    }

    fn save(&self, url: &str) -> Reply {
        let run = || -> Result<serde_json::Value> {
            let req = self.request(url)?;
            let img = self
                .source
                .render(&req, &self.device, &|| false)?
                .context("a save is never cancelled")?;
            let dir = self.view_dir()?;
            let p = &req.pose;
            let orbit = format!(
                "{},{},{},{},{}",
                p.azimuth, p.elevation, p.distance, p.pan[0], p.pan[1]
            );
            let mode = match req.mode {
                Mode::Color => "",
                Mode::Depth => "-depth",
                Mode::Normals => "-normals",
                Mode::Silhouette => "-silhouette",
            };
            let name = format!(
                "view-{}x{}-{}-{}{mode}.png",
                req.width,
                req.height,
                orbit.replace(',', "_"),
                Self::mix_tag(&req)
            );
            let out = dir.join(&name);
            img.save(&out)?;
            let mix = if req.mix.is_empty() {
                String::new()
            } else {
                format!(
                    " --mix {}",
                    req.mix
                        .iter()
                        .map(|m| m.to_string())
                        .collect::<Vec<_>>()
                        .join(",")
                )
            };
            let command = match &self.source {
                Source::Scene { variant, .. } if req.mode == Mode::Color => Some(format!(
                    "ins-cli render {variant} --run {} --orbit={orbit} --size {}x{}{mix} --out {}",
                    self.dir.display(),
                    req.width,
                    req.height,
                    out.display()
                )),
                _ => None,
            };
            Ok(json!({"path": out, "file": format!("/files/{name}"), "command": command}))
        };
        match run() {
            Ok(v) => json_reply(200, v),
            Err(e) => error_reply(400, &format!("{e:#}")),
        }
    }

    fn turntable(&self, url: &str) -> Reply {
        let run = || -> Result<serde_json::Value> {
            let req = self.request(url)?;
            let Source::Scene { run, .. } = &self.source else {
                bail!("a SIREN run is an image: there is no turntable");
            };
            let frames = query_value(url, "frames")
                .map(|f| f.parse::<usize>().context("frames"))
                .transpose()?
                .unwrap_or(60)
                .clamp(2, 720);
            let scene = run.scene();
            let cams = ins_scene::paths::path_for_scene(scene, None, frames)
                .context("the scene has no cameras")?;
            let code = run.code(
                if req.mix.is_empty() {
                    None
                } else {
                    Some(&req.mix)
                },
                &self.device,
            )?;
            let mut pictures = Vec::with_capacity(cams.len());
            let mut counter = Counter::new("turntable", cams.len());
            for (i, c) in cams.iter().enumerate() {
                let cam = c.resized(req.width, req.height);
                pictures.push(run.frame(&cam, code.clone(), &self.device)?.image);
                counter.done(i + 1);
            }
            let name = format!("turntable-{}.gif", Self::mix_tag(&req));
            let out = self.view_dir()?.join(&name);
            ins_models::video::write_frames(
                &pictures,
                &[],
                &ins_models::video::FrameOutput::for_path(&out)?,
                12,
            )?;
            Ok(json!({"path": out, "file": format!("/files/{name}")}))
        };
        match run() {
            Ok(v) => json_reply(200, v),
            Err(e) => error_reply(400, &format!("{e:#}")),
        }
    }

    /// A file of the run's `view/` folder; nothing outside it.
    fn file(&self, name: &str) -> Reply {
        let dir = self.dir.join("view");
        let inside = |p: &Path| -> Option<PathBuf> {
            let (d, f) = (dir.canonicalize().ok()?, p.canonicalize().ok()?);
            f.starts_with(&d).then_some(f)
        };
        if name.is_empty()
            || name.contains(['/', '\\'])
            || name.contains("..")
            || name.contains('%')
        {
            return error_reply(403, "only files of the run's view/ folder are served");
        }
        let Some(p) = inside(&dir.join(name)) else {
            return error_reply(404, &format!("no file {name} in the run's view/ folder"));
        };
        match std::fs::read(&p) {
            Ok(bytes) => {
                let kind = match p.extension().and_then(|e| e.to_str()) {
                    Some("png") => "image/png",
                    Some("gif") => "image/gif",
                    _ => "application/octet-stream",
                };
                Response::from_data(bytes).with_header(header("Content-Type", kind))
            }
            Err(e) => error_reply(404, &format!("{name}: {e}")),
        }
    }
}
