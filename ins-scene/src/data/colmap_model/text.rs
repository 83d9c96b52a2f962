//! COLMAP's text model files: `#` comments, one record per line (two per image).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::*;

/// Non-comment, non-blank lines with their 1-based line numbers.
fn data_lines(t: &str) -> impl Iterator<Item = (usize, &str)> {
    t.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn field<T: std::str::FromStr>(tok: Option<&str>, what: &str, line: usize) -> Result<T, String> {
    let s = tok.ok_or_else(|| format!("line {line}: missing {what}"))?;
    s.parse()
        .map_err(|_| format!("line {line}: {what} {s:?} is not a valid number"))
}

fn finite(v: f64, what: &str, line: usize) -> Result<f64, String> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("line {line}: {what} is {v}"))
    }
}

pub(super) fn parse_cameras_txt(t: &str) -> Result<BTreeMap<u32, ColmapCamera>, String> {
    let mut out = BTreeMap::new();
    for (ln, l) in data_lines(t) {
        let mut it = l.split_whitespace();
        let id: u32 = field(it.next(), "camera id", ln)?;
        let name = it
            .next()
            .ok_or_else(|| format!("line {ln}: missing model"))?;
        let model = CameraModel::from_name(name).map_err(|e| format!("line {ln}: {e}"))?;
        let width = dimension(field(it.next(), "width", ln)?, "width")?;
        let height = dimension(field(it.next(), "height", ln)?, "height")?;
        let params = (0..model.num_params())
            .map(|_| finite(field(it.next(), "parameter", ln)?, "parameter", ln))
            .collect::<Result<Vec<_>, _>>()?;
        if it.next().is_some() {
            return Err(format!(
                "line {ln}: more than the {} parameters of {name}",
                model.num_params()
            ));
        }
        insert_camera(
            &mut out,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
        )
        .map_err(|e| format!("line {ln}: {e}"))?;
    }
    Ok(out)
}

pub(super) fn parse_images_txt(t: &str) -> Result<Vec<ColmapImage>, String> {
    // Two lines per image; the second (observations) may be blank, so comments are skipped
    // but blank lines are not.
    let lines: Vec<(usize, &str)> = t
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.starts_with('#'))
        .collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let (ln, l) = lines[i];
        if l.is_empty() {
            i += 1;
            continue;
        }
        let mut it = l.split_whitespace();
        let id: u32 = field(it.next(), "image id", ln)?;
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = finite(field(it.next(), "quaternion", ln)?, "quaternion", ln)?;
        }
        let mut tvec = [0.0; 3];
        for v in &mut tvec {
            *v = finite(field(it.next(), "translation", ln)?, "translation", ln)?;
        }
        let camera_id: u32 = field(it.next(), "camera id", ln)?;
        let name = it.collect::<Vec<_>>().join(" ");
        if name.is_empty() {
            return Err(format!("line {ln}: missing image name"));
        }
        let obs = lines.get(i + 1).map_or("", |x| x.1);
        let toks: Vec<&str> = obs.split_whitespace().collect();
        if !toks.len().is_multiple_of(3) {
            return Err(format!(
                "line {}: observations are not (X, Y, POINT3D_ID) triples",
                ln + 1
            ));
        }
        let mut points2d = Vec::with_capacity(toks.len() / 3);
        for c in toks.chunks_exact(3) {
            let x = finite(field(Some(c[0]), "2D x", ln + 1)?, "2D x", ln + 1)?;
            let y = finite(field(Some(c[1]), "2D y", ln + 1)?, "2D y", ln + 1)?;
            points2d.push(([x, y], field(Some(c[2]), "3D point id", ln + 1)?));
        }
        out.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
        i += 2;
    }
    Ok(out)
}

pub(super) fn parse_points_txt(t: &str) -> Result<Vec<ColmapPoint>, String> {
    let mut out = Vec::new();
    for (ln, l) in data_lines(t) {
        let mut it = l.split_whitespace();
        let id: u64 = field(it.next(), "point id", ln)?;
        let mut xyz = [0.0; 3];
        for v in &mut xyz {
            *v = finite(field(it.next(), "position", ln)?, "position", ln)?;
        }
        let mut rgb = [0u8; 3];
        for v in &mut rgb {
            *v = field(it.next(), "colour", ln)?;
        }
        let error = finite(field(it.next(), "error", ln)?, "error", ln)?;
        let rest: Vec<&str> = it.collect();
        if !rest.len().is_multiple_of(2) {
            return Err(format!(
                "line {ln}: track is not (IMAGE_ID, POINT2D_IDX) pairs"
            ));
        }
        let track = rest
            .chunks_exact(2)
            .map(|c| {
                Ok((
                    field(Some(c[0]), "track image id", ln)?,
                    field(Some(c[1]), "track index", ln)?,
                ))
            })
            .collect::<Result<Vec<_>, String>>()?;
        out.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    Ok(out)
}

/// Shortest text that parses back to the same `f64` (Rust's `Display` round-trips).
fn num(v: f64) -> String {
    format!("{v}")
}

pub(super) fn cameras_txt(m: &ColmapModel) -> String {
    let mut s = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    let _ = writeln!(s, "# Number of cameras: {}", m.cameras.len());
    for c in m.cameras.values() {
        let params: Vec<String> = c.params.iter().map(|&p| num(p)).collect();
        let _ = writeln!(
            s,
            "{} {} {} {} {}",
            c.id,
            c.model.name(),
            c.width,
            c.height,
            params.join(" ")
        );
    }
    s
}

pub(super) fn images_txt(m: &ColmapModel) -> String {
    let mut s = String::from(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    let _ = writeln!(s, "# Number of images: {}", m.images.len());
    for img in &m.images {
        let pose: Vec<String> = img.qvec.iter().chain(&img.tvec).map(|&v| num(v)).collect();
        let _ = writeln!(
            s,
            "{} {} {} {}",
            img.id,
            pose.join(" "),
            img.camera_id,
            img.name
        );
        let obs: Vec<String> = img
            .points2d
            .iter()
            .map(|(xy, id)| format!("{} {} {id}", num(xy[0]), num(xy[1])))
            .collect();
        let _ = writeln!(s, "{}", obs.join(" "));
    }
    s
}

pub(super) fn points_txt(m: &ColmapModel) -> String {
    let mut s = String::from(
        "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n",
    );
    let _ = writeln!(s, "# Number of points: {}", m.points.len());
    for p in &m.points {
        let track: Vec<String> = p.track.iter().map(|(i, j)| format!("{i} {j}")).collect();
        let _ = writeln!(
            s,
            "{} {} {} {} {} {} {} {} {}",
            p.id,
            num(p.xyz[0]),
            num(p.xyz[1]),
            num(p.xyz[2]),
            p.rgb[0],
            p.rgb[1],
            p.rgb[2],
            num(p.error),
            track.join(" ")
        );
    }
    s
}
