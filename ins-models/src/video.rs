//! Writing rendered frames: a folder of PNGs, an animated GIF, or an MP4 when ffmpeg is on PATH.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use ins_core::imaging::RgbImage;

/// Where frames go, from the output path's extension.
#[derive(Debug, Clone)]
pub enum FrameOutput {
    /// A folder of PNGs (a path without extension).
    Folder(PathBuf),
    /// An animated GIF.
    Gif(PathBuf),
    /// An H.264 MP4 through ffmpeg.
    Mp4(PathBuf),
}

impl FrameOutput {
    /// Chooses by extension: `.gif`, `.mp4`, none (folder); anything else is an error.
    pub fn for_path(p: &Path) -> Result<Self> {
        match p
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
        {
            None => Ok(Self::Folder(p.to_path_buf())),
            Some(e) if e == "gif" => Ok(Self::Gif(p.to_path_buf())),
            Some(e) if e == "mp4" => {
                if !ffmpeg_available() {
                    bail!(
                        "{}: writing MP4 needs ffmpeg on PATH; write a .gif or a folder instead",
                        p.display()
                    );
                }
                Ok(Self::Mp4(p.to_path_buf()))
            }
            Some(e) => bail!(
                "{}: several frames go to a folder (no extension), a .gif or a .mp4, not .{e}",
                p.display()
            ),
        }
    }
}

/// Whether `ffmpeg` runs.
pub fn ffmpeg_available() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success())
}

fn save_folder(frames: &[RgbImage], names: &[String], dir: &Path) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut out = Vec::new();
    for (f, n) in frames.iter().zip(names) {
        let p = dir.join(n);
        f.save(&p)?;
        out.push(p);
    }
    Ok(out)
}

/// Writes an animated GIF (looping, `fps` frames per second), atomically.
pub fn write_gif(frames: &[RgbImage], path: &Path, fps: u32) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    use image::{Delay, Frame, RgbaImage};
    ins_io::write_atomic_with(path, |tmp| -> Result<()> {
        let file =
            std::fs::File::create(tmp).with_context(|| format!("writing {}", path.display()))?;
        let mut enc = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
        enc.set_repeat(Repeat::Infinite)?;
        for f in frames {
            let rgba: Vec<u8> = f
                .data
                .chunks_exact(3)
                .flat_map(|p| [to_u8(p[0]), to_u8(p[1]), to_u8(p[2]), 255])
                .collect();
            let img =
                RgbaImage::from_raw(f.width as u32, f.height as u32, rgba).context("frame size")?;
            enc.encode_frame(Frame::from_parts(
                img,
                0,
                0,
                Delay::from_numer_denom_ms(1000, fps.max(1)),
            ))
            .with_context(|| format!("writing {}", path.display()))?;
        }
        Ok(())
    })
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Writes frames where `output` says; returns the files written.
pub fn write_frames(
    frames: &[RgbImage],
    names: &[String],
    output: &FrameOutput,
    fps: u32,
) -> Result<Vec<PathBuf>> {
    match output {
        FrameOutput::Folder(dir) => save_folder(frames, names, dir),
        FrameOutput::Gif(p) => {
            write_gif(frames, p, fps)?;
            Ok(vec![p.clone()])
        }
        FrameOutput::Mp4(p) => {
            let tmp = tempfile::tempdir().context("a temporary folder for frames")?;
            let names: Vec<String> = (0..frames.len()).map(|i| format!("f{i:05}.png")).collect();
            save_folder(frames, &names, tmp.path())?;
            let status = Command::new("ffmpeg")
                .args([
                    "-y",
                    "-loglevel",
                    "error",
                    "-framerate",
                    &fps.to_string(),
                    "-i",
                ])
                .arg(tmp.path().join("f%05d.png"))
                .args([
                    "-vf",
                    "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                    "-pix_fmt",
                    "yuv420p",
                    "-c:v",
                    "libx264",
                ])
                .arg(p)
                .status()
                .context("running ffmpeg")?;
            if !status.success() {
                bail!("ffmpeg failed writing {}", p.display());
            }
            Ok(vec![p.clone()])
        }
    }
}
