//! COLMAP's binary model files (little endian), read record by record with bounds checks.

use std::collections::BTreeMap;

use super::*;

/// A bounds-checked little-endian reader.
struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        match end {
            Some(e) => {
                let s = &self.b[self.at..e];
                self.at = e;
                Ok(s)
            }
            None => Err(format!(
                "truncated: {what} at byte {} runs past the end ({} bytes)",
                self.at,
                self.b.len()
            )),
        }
    }
    fn u64(&mut self, what: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn i64(&mut self, what: &str) -> Result<i64, String> {
        Ok(i64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn i32(&mut self, what: &str) -> Result<i32, String> {
        Ok(i32::from_le_bytes(
            self.take(4, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }
    fn f64(&mut self, what: &str) -> Result<f64, String> {
        let v = f64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default());
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("{what} is {v}"))
        }
    }
    /// A count of records of at least `min_size` bytes each, checked against the bytes left.
    fn count(&mut self, min_size: usize, what: &str) -> Result<usize, String> {
        let n = self.u64(what)?;
        let left = (self.b.len() - self.at) as u64;
        if n.saturating_mul(min_size as u64) > left {
            return Err(format!(
                "{what} = {n} but only {left} bytes follow: truncated or corrupt"
            ));
        }
        Ok(n as usize)
    }
    fn done(&self) -> Result<(), String> {
        if self.at == self.b.len() {
            Ok(())
        } else {
            Err(format!(
                "{} unexpected bytes after the last record",
                self.b.len() - self.at
            ))
        }
    }
}

fn id32(v: i32, what: &str) -> Result<u32, String> {
    u32::try_from(v).map_err(|_| format!("{what} {v} is negative"))
}

pub(super) fn parse_cameras_bin(b: &[u8]) -> Result<BTreeMap<u32, ColmapCamera>, String> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(24, "number of cameras")?;
    let mut out = BTreeMap::new();
    for i in 0..n {
        let what = format!("camera record {i}");
        let id = id32(c.i32(&what)?, "camera id")?;
        let model = CameraModel::from_id(c.i32(&what)?).map_err(|e| format!("camera {id}: {e}"))?;
        let width = dimension(c.u64(&what)?, "width")?;
        let height = dimension(c.u64(&what)?, "height")?;
        let params = (0..model.num_params())
            .map(|_| c.f64(&format!("camera {id} parameter")))
            .collect::<Result<Vec<_>, _>>()?;
        insert_camera(
            &mut out,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
        )?;
    }
    c.done()?;
    Ok(out)
}

pub(super) fn parse_images_bin(b: &[u8]) -> Result<Vec<ColmapImage>, String> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(64 + 1 + 8, "number of images")?;
    let mut out = Vec::new();
    for i in 0..n {
        let what = format!("image record {i}");
        let id = id32(c.i32(&what)?, "image id")?;
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = c.f64(&format!("image {id} rotation"))?;
        }
        let mut tvec = [0.0; 3];
        for t in &mut tvec {
            *t = c.f64(&format!("image {id} translation"))?;
        }
        let camera_id = id32(c.i32(&what)?, "camera id")?;
        let start = c.at;
        let len = b[start..]
            .iter()
            .position(|&x| x == 0)
            .ok_or_else(|| format!("image {id}: name not terminated"))?;
        let name = std::str::from_utf8(c.take(len, "name")?)
            .map_err(|_| format!("image {id}: name is not UTF-8"))?
            .to_string();
        c.take(1, "name terminator")?;
        let np = c.count(24, &format!("image {id}: number of 2D points"))?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            let x = c.f64("2D point x")?;
            let y = c.f64("2D point y")?;
            points2d.push(([x, y], c.i64("2D point's 3D id")?));
        }
        out.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    c.done()?;
    Ok(out)
}

pub(super) fn parse_points_bin(b: &[u8]) -> Result<Vec<ColmapPoint>, String> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(51, "number of points")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.u64("point id")?;
        let mut xyz = [0.0; 3];
        for v in &mut xyz {
            *v = c.f64(&format!("point {id} position"))?;
        }
        let rgb = [c.u8("colour")?, c.u8("colour")?, c.u8("colour")?];
        let error = c.f64(&format!("point {id} error"))?;
        let nt = c.count(8, &format!("point {id}: track length"))?;
        let mut track = Vec::with_capacity(nt);
        for _ in 0..nt {
            let img = id32(c.i32("track image id")?, "track image id")?;
            let idx = id32(c.i32("track 2D index")?, "track 2D index")?;
            track.push((img, idx));
        }
        out.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    c.done()?;
    Ok(out)
}

pub(super) fn cameras_bin(m: &ColmapModel) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((m.cameras.len() as u64).to_le_bytes());
    for cam in m.cameras.values() {
        b.extend((cam.id as i32).to_le_bytes());
        b.extend(cam.model.id().to_le_bytes());
        b.extend(u64::from(cam.width).to_le_bytes());
        b.extend(u64::from(cam.height).to_le_bytes());
        for p in &cam.params {
            b.extend(p.to_le_bytes());
        }
    }
    b
}

pub(super) fn images_bin(m: &ColmapModel) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((m.images.len() as u64).to_le_bytes());
    for img in &m.images {
        b.extend((img.id as i32).to_le_bytes());
        for v in img.qvec.iter().chain(&img.tvec) {
            b.extend(v.to_le_bytes());
        }
        b.extend((img.camera_id as i32).to_le_bytes());
        b.extend(img.name.as_bytes());
        b.push(0);
        b.extend((img.points2d.len() as u64).to_le_bytes());
        for (xy, id) in &img.points2d {
            b.extend(xy[0].to_le_bytes());
            b.extend(xy[1].to_le_bytes());
            b.extend(id.to_le_bytes());
        }
    }
    b
}

pub(super) fn points_bin(m: &ColmapModel) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((m.points.len() as u64).to_le_bytes());
    for p in &m.points {
        b.extend(p.id.to_le_bytes());
        for v in p.xyz {
            b.extend(v.to_le_bytes());
        }
        b.extend(p.rgb);
        b.extend(p.error.to_le_bytes());
        b.extend((p.track.len() as u64).to_le_bytes());
        for (img, idx) in &p.track {
            b.extend((*img as i32).to_le_bytes());
            b.extend((*idx as i32).to_le_bytes());
        }
    }
    b
}
