//! COLMAP's sparse model files, `cameras`, `images` and `points3D`, in both encodings
//! (`.bin`, little endian, and `.txt`), read and written exactly as COLMAP's
//! `Reconstruction::Read{Binary,Text}` / `Write*` lay them out.
//!
//! Counts in headers are never trusted for allocation: records are read one by one and a
//! count larger than the bytes left can hold is an error naming the file.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use crate::data::DataError;
use crate::distortion::Distortion;

/// A COLMAP camera model, with its id in the binary format and its parameter count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    /// `f, cx, cy`.
    SimplePinhole,
    /// `fx, fy, cx, cy`.
    Pinhole,
    /// `f, cx, cy, k`.
    SimpleRadial,
    /// `f, cx, cy, k1, k2`.
    Radial,
    /// `fx, fy, cx, cy, k1, k2, p1, p2`.
    Opencv,
    /// `fx, fy, cx, cy, k1, k2, k3, k4`.
    OpencvFisheye,
    /// `fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6`.
    FullOpencv,
}

/// COLMAP's models by id, name and parameter count; the ones after OPENCV_FISHEYE that this
/// reader refuses are listed so the message can name them.
const MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// What the reader says about a model it does not read.
pub const SUPPORTED_MODELS: &str =
    "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE, FULL_OPENCV";

impl CameraModel {
    const ALL: [CameraModel; 7] = [
        CameraModel::SimplePinhole,
        CameraModel::Pinhole,
        CameraModel::SimpleRadial,
        CameraModel::Radial,
        CameraModel::Opencv,
        CameraModel::OpencvFisheye,
        CameraModel::FullOpencv,
    ];

    /// COLMAP's id of the model.
    pub fn id(self) -> i32 {
        Self::ALL.iter().position(|&m| m == self).unwrap_or(0) as i32
    }

    /// COLMAP's name of the model.
    pub fn name(self) -> &'static str {
        MODELS[self.id() as usize].1
    }

    /// Number of parameters.
    pub fn num_params(self) -> usize {
        MODELS[self.id() as usize].2
    }

    fn from_id(id: i32) -> Result<Self, String> {
        match Self::ALL.get(usize::try_from(id).unwrap_or(usize::MAX)) {
            Some(&m) => Ok(m),
            None => Err(unsupported(
                MODELS
                    .iter()
                    .find(|m| m.0 == id)
                    .map_or(format!("model id {id}"), |m| m.1.to_string()),
            )),
        }
    }

    fn from_name(name: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| unsupported(name.to_string()))
    }
}

fn unsupported(what: String) -> String {
    format!(
        "camera model {what} is not supported (supported: {SUPPORTED_MODELS}; undistort the \
         images with COLMAP's image_undistorter to get PINHOLE cameras)"
    )
}

/// One camera (intrinsics shared by the images that name it).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Its id.
    pub id: u32,
    /// Its model.
    pub model: CameraModel,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// The model's parameters, in COLMAP's order.
    pub params: Vec<f64>,
}

impl ColmapCamera {
    /// `(fx, fy, cx, cy)` and the lens distortion. COLMAP's pixel convention is this project's:
    /// the centre of the top-left pixel is at (0.5, 0.5).
    pub fn intrinsics(&self) -> ([f64; 4], Distortion) {
        let p = &self.params;
        let poly = |k: [f64; 6], pp: [f64; 2]| Distortion::Polynomial { k, p: pp };
        match self.model {
            CameraModel::SimplePinhole => ([p[0], p[0], p[1], p[2]], Distortion::None),
            CameraModel::Pinhole => ([p[0], p[1], p[2], p[3]], Distortion::None),
            CameraModel::SimpleRadial => (
                [p[0], p[0], p[1], p[2]],
                poly([p[3], 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 2]),
            ),
            CameraModel::Radial => (
                [p[0], p[0], p[1], p[2]],
                poly([p[3], p[4], 0.0, 0.0, 0.0, 0.0], [0.0; 2]),
            ),
            CameraModel::Opencv => (
                [p[0], p[1], p[2], p[3]],
                poly([p[4], p[5], 0.0, 0.0, 0.0, 0.0], [p[6], p[7]]),
            ),
            CameraModel::OpencvFisheye => (
                [p[0], p[1], p[2], p[3]],
                Distortion::Fisheye {
                    k: [p[4], p[5], p[6], p[7]],
                },
            ),
            CameraModel::FullOpencv => (
                [p[0], p[1], p[2], p[3]],
                poly([p[4], p[5], p[8], p[9], p[10], p[11]], [p[6], p[7]]),
            ),
        }
    }
}

/// One registered image: its world-to-camera pose (OpenCV axes) and what it observes.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Its id.
    pub id: u32,
    /// World-to-camera rotation as a quaternion `(w, x, y, z)`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// The camera it was taken with.
    pub camera_id: u32,
    /// File name, relative to the image folder.
    pub name: String,
    /// Its 2D observations `(x, y, point3D id or -1)`.
    pub points2d: Vec<([f64; 2], i64)>,
}

/// One triangulated point.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// Its id.
    pub id: u64,
    /// Position in the model's world frame.
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels.
    pub error: f64,
    /// Observations `(image id, index of the 2D point)`.
    pub track: Vec<(u32, u32)>,
}

/// A sparse model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Images, in file order.
    pub images: Vec<ColmapImage>,
    /// Points (empty when `points3D` is absent).
    pub points: Vec<ColmapPoint>,
}

/// The model files' encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// `cameras.bin`, `images.bin`, `points3D.bin`.
    Binary,
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
}

impl Encoding {
    fn ext(self) -> &'static str {
        match self {
            Encoding::Binary => "bin",
            Encoding::Text => "txt",
        }
    }
}

/// The encoding of the model in `dir`: binary when `cameras.bin` is there, else text when
/// `cameras.txt` is.
pub fn model_encoding(dir: &Path) -> Option<Encoding> {
    if dir.join("cameras.bin").is_file() {
        Some(Encoding::Binary)
    } else if dir.join("cameras.txt").is_file() {
        Some(Encoding::Text)
    } else {
        None
    }
}

/// Reads the model in `dir` (binary preferred); `points3D` is optional.
pub fn read_model(dir: &Path) -> Result<ColmapModel, DataError> {
    let enc = model_encoding(dir)
        .ok_or_else(|| DataError::missing(&dir.join("cameras.bin"), "COLMAP cameras file"))?;
    let file = |stem: &str| dir.join(format!("{stem}.{}", enc.ext()));
    let read = |p: &Path| std::fs::read(p).map_err(|e| DataError::io(p, e));
    let (cams_path, imgs_path, pts_path) = (file("cameras"), file("images"), file("points3D"));
    let cams_bytes = read(&cams_path)?;
    let imgs_bytes = read(&imgs_path)?;
    fn wrap(p: &Path) -> impl Fn(String) -> DataError + '_ {
        move |msg| DataError::invalid(p, msg)
    }
    let (cameras, images) = match enc {
        Encoding::Binary => (
            parse_cameras_bin(&cams_bytes).map_err(wrap(&cams_path))?,
            parse_images_bin(&imgs_bytes).map_err(wrap(&imgs_path))?,
        ),
        Encoding::Text => (
            parse_cameras_txt(&text(&cams_bytes, &cams_path)?).map_err(wrap(&cams_path))?,
            parse_images_txt(&text(&imgs_bytes, &imgs_path)?).map_err(wrap(&imgs_path))?,
        ),
    };
    let points = if pts_path.is_file() {
        let bytes = read(&pts_path)?;
        match enc {
            Encoding::Binary => parse_points_bin(&bytes),
            Encoding::Text => parse_points_txt(&text(&bytes, &pts_path)?),
        }
        .map_err(wrap(&pts_path))?
    } else {
        Vec::new()
    };
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

fn text(bytes: &[u8], path: &Path) -> Result<String, DataError> {
    String::from_utf8(bytes.to_vec())
        .map_err(|_| DataError::invalid(path, "not UTF-8 text (a binary file named .txt?)"))
}

/// Writes `model` into `dir` in `encoding` (folder created).
pub fn write_model(model: &ColmapModel, dir: &Path, encoding: Encoding) -> Result<(), DataError> {
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let files: [(&str, Vec<u8>); 3] = match encoding {
        Encoding::Binary => [
            ("cameras", cameras_bin(model)),
            ("images", images_bin(model)),
            ("points3D", points_bin(model)),
        ],
        Encoding::Text => [
            ("cameras", cameras_txt(model).into_bytes()),
            ("images", images_txt(model).into_bytes()),
            ("points3D", points_txt(model).into_bytes()),
        ],
    };
    for (stem, bytes) in files {
        let p = dir.join(format!("{stem}.{}", encoding.ext()));
        std::fs::write(&p, bytes).map_err(|e| DataError::io(&p, e))?;
    }
    Ok(())
}

// ---- binary ----

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

fn dimension(v: u64, what: &str) -> Result<u32, String> {
    u32::try_from(v)
        .ok()
        .filter(|&d| d > 0 && d <= 1 << 16)
        .ok_or_else(|| format!("{what} {v} is not an image size"))
}

fn insert_camera(map: &mut BTreeMap<u32, ColmapCamera>, cam: ColmapCamera) -> Result<(), String> {
    let (f, _) = cam.intrinsics();
    if !(f[0] > 0.0 && f[1] > 0.0) {
        return Err(format!(
            "camera {}: focal length {} × {} is not positive",
            cam.id, f[0], f[1]
        ));
    }
    let id = cam.id;
    if map.insert(id, cam).is_some() {
        return Err(format!("camera {id} appears twice"));
    }
    Ok(())
}

fn parse_cameras_bin(b: &[u8]) -> Result<BTreeMap<u32, ColmapCamera>, String> {
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

fn parse_images_bin(b: &[u8]) -> Result<Vec<ColmapImage>, String> {
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

fn parse_points_bin(b: &[u8]) -> Result<Vec<ColmapPoint>, String> {
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

fn cameras_bin(m: &ColmapModel) -> Vec<u8> {
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

fn images_bin(m: &ColmapModel) -> Vec<u8> {
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

fn points_bin(m: &ColmapModel) -> Vec<u8> {
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

// ---- text ----

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

fn parse_cameras_txt(t: &str) -> Result<BTreeMap<u32, ColmapCamera>, String> {
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

fn parse_images_txt(t: &str) -> Result<Vec<ColmapImage>, String> {
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

fn parse_points_txt(t: &str) -> Result<Vec<ColmapPoint>, String> {
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

fn cameras_txt(m: &ColmapModel) -> String {
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

fn images_txt(m: &ColmapModel) -> String {
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

fn points_txt(m: &ColmapModel) -> String {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> ColmapModel {
        let mut cameras = BTreeMap::new();
        cameras.insert(
            1,
            ColmapCamera {
                id: 1,
                model: CameraModel::Opencv,
                width: 64,
                height: 48,
                params: vec![50.5, 51.25, 32.1, 23.9, -0.1, 0.01, 1e-3, -2e-4],
            },
        );
        let images = vec![ColmapImage {
            id: 3,
            qvec: [0.9, 0.1, -0.3, 0.2],
            tvec: [0.5, -1.0, 3.25],
            camera_id: 1,
            name: "img 001.png".into(),
            points2d: vec![([10.5, 20.25], 7), ([1.0, 2.0], -1)],
        }];
        let points = vec![ColmapPoint {
            id: 7,
            xyz: [0.1, 0.2, 0.3],
            rgb: [1, 2, 3],
            error: 0.5,
            track: vec![(3, 0)],
        }];
        ColmapModel {
            cameras,
            images,
            points,
        }
    }

    #[test]
    fn binary_and_text_round_trip() {
        let m = model();
        for enc in [Encoding::Binary, Encoding::Text] {
            let dir = tempfile::tempdir().unwrap();
            write_model(&m, dir.path(), enc).unwrap();
            assert_eq!(model_encoding(dir.path()), Some(enc));
            assert_eq!(read_model(dir.path()).unwrap(), m, "{enc:?}");
        }
    }

    #[test]
    fn unsupported_models_and_lying_counts_are_named() {
        let mut m = model();
        let dir = tempfile::tempdir().unwrap();
        write_model(&m, dir.path(), Encoding::Text).unwrap();
        let cams = dir.path().join("cameras.txt");
        let t = std::fs::read_to_string(&cams).unwrap();
        std::fs::write(&cams, t.replace("OPENCV", "THIN_PRISM_FISHEYE")).unwrap();
        let e = read_model(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("cameras.txt") && e.contains("THIN_PRISM_FISHEYE"),
            "{e}"
        );
        assert!(e.contains("not supported"), "{e}");

        m.images[0].name = "a.png".into();
        write_model(&m, dir.path(), Encoding::Binary).unwrap();
        let imgs = dir.path().join("images.bin");
        let mut b = std::fs::read(&imgs).unwrap();
        b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&imgs, &b).unwrap();
        let e = read_model(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("images.bin") && e.contains("number of images"),
            "{e}"
        );
    }
}
