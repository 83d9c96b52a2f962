//! COLMAP's sparse model files, `cameras`, `images` and `points3D`, in both encodings
//! (`.bin`, little endian, and `.txt`), read and written exactly as COLMAP's
//! `Reconstruction::Read{Binary,Text}` / `Write*` lay them out.
//!
//! Counts in headers are never trusted for allocation: records are read one by one and a
//! count larger than the bytes left can hold is an error naming the file.

use std::collections::BTreeMap;
use std::path::Path;

use crate::data::DataError;
use crate::distortion::Distortion;

mod binary;
mod text;

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
            binary::parse_cameras_bin(&cams_bytes).map_err(wrap(&cams_path))?,
            binary::parse_images_bin(&imgs_bytes).map_err(wrap(&imgs_path))?,
        ),
        Encoding::Text => (
            text::parse_cameras_txt(&text(&cams_bytes, &cams_path)?).map_err(wrap(&cams_path))?,
            text::parse_images_txt(&text(&imgs_bytes, &imgs_path)?).map_err(wrap(&imgs_path))?,
        ),
    };
    let points = if pts_path.is_file() {
        let bytes = read(&pts_path)?;
        match enc {
            Encoding::Binary => binary::parse_points_bin(&bytes),
            Encoding::Text => text::parse_points_txt(&text(&bytes, &pts_path)?),
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
            ("cameras", binary::cameras_bin(model)),
            ("images", binary::images_bin(model)),
            ("points3D", binary::points_bin(model)),
        ],
        Encoding::Text => [
            ("cameras", text::cameras_txt(model).into_bytes()),
            ("images", text::images_txt(model).into_bytes()),
            ("points3D", text::points_txt(model).into_bytes()),
        ],
    };
    for (stem, bytes) in files {
        let p = dir.join(format!("{stem}.{}", encoding.ext()));
        std::fs::write(&p, bytes).map_err(|e| DataError::io(&p, e))?;
    }
    Ok(())
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
