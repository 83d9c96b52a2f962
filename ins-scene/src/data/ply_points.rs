//! The vertices of a PLY point cloud (nerfstudio's `sparse_pc.ply`, named by `ply_file_path`
//! in its `transforms.json`): ASCII or binary little-endian, `x y z` as float or double among
//! any other per-vertex properties. Only positions are read; they place a capture's near plane
//! and box the way COLMAP's points do.

use std::path::Path;

use glam::DVec3;

use super::DataError;

/// Size in bytes of a PLY scalar type, `None` for types this reader does not know.
fn type_size(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// Reads the vertex positions of the PLY file at `path`.
pub fn read_ply_points(path: &Path) -> Result<Vec<DVec3>, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    parse(&bytes).map_err(|msg| DataError::invalid(path, msg))
}

fn parse(bytes: &[u8]) -> Result<Vec<DVec3>, String> {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or("no end_header line: not a PLY file")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let body = &bytes[end + 11..];
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("does not start with `ply`".into());
    }
    let mut ascii = None;
    let mut count = 0usize;
    let mut in_vertex = false;
    let mut seen_vertex = false;
    // (offset in bytes, type) of x, y, z, and the record size.
    let mut props: Vec<(String, String)> = Vec::new();
    for l in lines {
        let t: Vec<&str> = l.split_whitespace().collect();
        match t.as_slice() {
            ["format", "ascii", _] => ascii = Some(true),
            ["format", "binary_little_endian", _] => ascii = Some(false),
            ["format", f, _] => return Err(format!("PLY format {f} is not supported")),
            ["element", "vertex", n] => {
                if seen_vertex {
                    return Err("two vertex elements".into());
                }
                count = n.parse().map_err(|_| format!("vertex count {n:?}"))?;
                in_vertex = true;
                seen_vertex = true;
            }
            ["element", ..] => {
                if in_vertex || !seen_vertex {
                    in_vertex = false;
                    if !seen_vertex {
                        return Err("elements before the vertices are not supported".into());
                    }
                }
            }
            ["property", "list", ..] if in_vertex => {
                return Err("list properties on vertices are not supported".into());
            }
            ["property", ty, name] if in_vertex => props.push((ty.to_string(), name.to_string())),
            _ => {}
        }
    }
    let ascii = ascii.ok_or("no format line")?;
    let index = |n: &str| {
        props
            .iter()
            .position(|p| p.1 == n)
            .ok_or(format!("vertices have no {n} property"))
    };
    let (ix, iy, iz) = (index("x")?, index("y")?, index("z")?);
    let mut out = Vec::new();
    if ascii {
        let text = std::str::from_utf8(body).map_err(|_| "body is not text")?;
        for (i, l) in text.lines().take(count).enumerate() {
            let v: Vec<&str> = l.split_whitespace().collect();
            let num = |k: usize| -> Result<f64, String> {
                let s = v.get(k).ok_or(format!("vertex {i}: too few values"))?;
                s.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or(format!("vertex {i}: {s:?} is not a finite number"))
            };
            out.push(DVec3::new(num(ix)?, num(iy)?, num(iz)?));
        }
        if out.len() != count {
            return Err(format!("{count} vertices declared, {} present", out.len()));
        }
        return Ok(out);
    }
    let sizes = props
        .iter()
        .map(|(t, n)| type_size(t).ok_or(format!("property {n} has unknown type {t}")))
        .collect::<Result<Vec<_>, _>>()?;
    let record: usize = sizes.iter().sum();
    if count.saturating_mul(record) > body.len() {
        return Err(format!(
            "{count} vertices of {record} bytes declared but only {} bytes follow",
            body.len()
        ));
    }
    let offset = |k: usize| sizes[..k].iter().sum::<usize>();
    let value = |rec: &[u8], k: usize| -> Result<f64, String> {
        let o = offset(k);
        let v = match props[k].0.as_str() {
            "float" | "float32" => {
                f32::from_le_bytes(rec[o..o + 4].try_into().unwrap_or_default()) as f64
            }
            "double" | "float64" => {
                f64::from_le_bytes(rec[o..o + 8].try_into().unwrap_or_default())
            }
            t => return Err(format!("position type {t} is not float or double")),
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("a position is {v}"))
        }
    };
    out.reserve(count);
    for rec in body.chunks_exact(record.max(1)).take(count) {
        out.push(DVec3::new(
            value(rec, ix)?,
            value(rec, iy)?,
            value(rec, iz)?,
        ));
    }
    Ok(out)
}

/// Writes `points` as an ASCII PLY (what nerfstudio writes).
pub fn write_ply_points(path: &Path, points: &[DVec3]) -> Result<(), DataError> {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uint8 red\nproperty uint8 green\nproperty uint8 blue\nend_header\n",
        points.len()
    );
    for p in points {
        s.push_str(&format!(
            "{} {} {} 128 128 128\n",
            p.x as f32, p.y as f32, p.z as f32
        ));
    }
    std::fs::write(path, s).map_err(|e| DataError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_points_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let pts = vec![DVec3::new(1.0, -2.0, 3.5), DVec3::new(0.25, 0.5, -0.75)];
        let p = dir.path().join("a.ply");
        write_ply_points(&p, &pts).unwrap();
        assert_eq!(read_ply_points(&p).unwrap(), pts);
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty uchar r\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec();
        for q in &pts {
            bin.push(7);
            for v in q.to_array() {
                bin.extend(v.to_le_bytes());
            }
        }
        let b = dir.path().join("b.ply");
        std::fs::write(&b, &bin).unwrap();
        assert_eq!(read_ply_points(&b).unwrap(), pts);
        std::fs::write(&b, &bin[..bin.len() - 5]).unwrap();
        let e = read_ply_points(&b).unwrap_err().to_string();
        assert!(e.contains("b.ply") && e.contains("declared"), "{e}");
    }
}
