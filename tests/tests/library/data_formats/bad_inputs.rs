//! Missing and corrupt scene files: errors that name the file.

use super::*;

/// Loads `dir` and returns the error message, failing if it loaded.
pub(super) fn load_err(dir: &Path) -> String {
    match Scene::load(dir, &LoadOptions::default()) {
        Ok(_) => panic!("{} loaded but should not", dir.display()),
        Err(e) => e.to_string(),
    }
}

pub(super) fn assert_names(msg: &str, file: &str) {
    assert!(msg.contains(file), "error should name {file}: {msg}");
}

#[test]
fn bad_blender_inputs_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    assert_names(&load_err(&dir.path().join("absent")), "absent");
    assert_names(&load_err(dir.path()), &dir.path().display().to_string());

    let (d, _) = write(SceneFormat::Blender, 16, 2);
    let json = d.path().join("transforms_train.json");
    let good = std::fs::read_to_string(&json).unwrap();
    std::fs::write(&json, "{ \"camera_angle_x\": 0.6, \"frames\": [ {").unwrap();
    assert_names(&load_err(d.path()), "transforms_train.json");
    std::fs::write(&json, good.replace("camera_angle_x", "camera_angle_z")).unwrap();
    assert_names(&load_err(d.path()), "transforms_train.json");
    std::fs::write(&json, good.replace("transform_matrix", "matrix")).unwrap();
    assert_names(&load_err(d.path()), "transforms_train.json");
    std::fs::write(&json, &good).unwrap();

    // Mixed image sizes.
    let img = d.path().join("train").join("r_1.png");
    image::RgbaImage::new(20, 16).save(&img).unwrap();
    assert_names(&load_err(d.path()), "r_1.png");
    // Missing image, and a file that is not an image.
    std::fs::remove_file(&img).unwrap();
    assert_names(&load_err(d.path()), "r_1.png");
    std::fs::write(&img, b"not a png").unwrap();
    assert_names(&load_err(d.path()), "r_1.png");
}

#[test]
fn bad_llff_inputs_are_errors_naming_the_file() {
    let (d, _) = write(SceneFormat::Llff, 16, 3);
    let npy = d.path().join("poses_bounds.npy");
    let good = std::fs::read(&npy).unwrap();
    std::fs::write(&npy, b"\x93NUMPY garbage").unwrap();
    assert_names(&load_err(d.path()), "poses_bounds.npy");
    // A header that claims far more data than the file holds.
    let mut huge = good.clone();
    let key = b"'shape': (".as_slice();
    let start = huge
        .windows(key.len())
        .position(|w| w == key)
        .expect("shape in header")
        + key.len();
    let end = start
        + huge[start..]
            .iter()
            .position(|&b| b == b'\n')
            .expect("header end");
    let mut tail = b"99999999999, 17), }".to_vec();
    assert!(tail.len() <= end - start);
    tail.resize(end - start, b' ');
    huge[start..end].copy_from_slice(&tail);
    std::fs::write(&npy, &huge).unwrap();
    assert_names(&load_err(d.path()), "poses_bounds.npy");
    // Truncated data.
    std::fs::write(&npy, &good[..good.len() - 40]).unwrap();
    assert_names(&load_err(d.path()), "poses_bounds.npy");
    // Wrong shape.
    ins_scene::data::npy::write_npy(&npy, &[3, 15], &[1.0; 45]).unwrap();
    assert_names(&load_err(d.path()), "poses_bounds.npy");
    std::fs::write(&npy, &good).unwrap();
    // Counts that do not match.
    std::fs::remove_file(d.path().join("images").join("image002.png")).unwrap();
    let msg = load_err(d.path());
    assert_names(&msg, "images");
    assert_names(&msg, "poses_bounds.npy");
    // Mixed image sizes.
    image::RgbImage::new(10, 10)
        .save(d.path().join("images").join("image002.png"))
        .unwrap();
    assert_names(&load_err(d.path()), "image002.png");
}

#[test]
fn bad_dtu_inputs_are_errors_naming_the_file() {
    let (d, _) = write(SceneFormat::Dtu, 16, 3);
    let npz = d.path().join("cameras.npz");
    let good = std::fs::read(&npz).unwrap();
    std::fs::write(&npz, b"PK\x03\x04 not really a zip").unwrap();
    assert_names(&load_err(d.path()), "cameras.npz");
    // A valid zip whose entry is not a valid npy (the archive is stored uncompressed).
    let mut corrupt = good.clone();
    let at = corrupt
        .windows(5)
        .position(|w| w == b"descr")
        .expect("npy header in archive");
    corrupt[at..at + 5].copy_from_slice(b"xxxxx");
    std::fs::write(&npz, &corrupt).unwrap();
    assert_names(&load_err(d.path()), "cameras.npz");
    // Fewer cameras than images.
    let m = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ]
    .to_vec();
    let two: Vec<(String, Vec<usize>, Vec<f64>)> = (0..2)
        .flat_map(|i| {
            [
                (format!("world_mat_{i}"), vec![4, 4], m.clone()),
                (format!("scale_mat_{i}"), vec![4, 4], m.clone()),
            ]
        })
        .collect();
    ins_scene::data::npy::write_npz(&npz, &two).unwrap();
    assert_names(&load_err(d.path()), "cameras.npz");
    // A matrix of the wrong shape.
    let mut bad = two.clone();
    bad[0].1 = vec![2, 8];
    bad.push(("world_mat_2".into(), vec![4, 4], m.clone()));
    bad.push(("scale_mat_2".into(), vec![4, 4], m.clone()));
    ins_scene::data::npy::write_npz(&npz, &bad).unwrap();
    assert_names(&load_err(d.path()), "cameras.npz");
    std::fs::write(&npz, &good).unwrap();
    load(d.path());

    // A mask without its image.
    let extra = d.path().join("mask").join("003.png");
    std::fs::copy(d.path().join("mask").join("000.png"), &extra).unwrap();
    assert_names(&load_err(d.path()), &extra.display().to_string());
    std::fs::remove_file(&extra).unwrap();
    // A mask of the wrong size, an image of the wrong size.
    let mask1 = d.path().join("mask").join("001.png");
    let mask_good = std::fs::read(&mask1).unwrap();
    image::RgbImage::new(8, 8).save(&mask1).unwrap();
    assert_names(&load_err(d.path()), &mask1.display().to_string());
    std::fs::write(&mask1, mask_good).unwrap();
    let img2 = d.path().join("image").join("000002.png");
    image::RgbImage::new(8, 8).save(&img2).unwrap();
    assert_names(&load_err(d.path()), &img2.display().to_string());
    // Missing cameras.
    std::fs::remove_file(&npz).unwrap();
    assert!(
        Scene::load_as(SceneFormat::Dtu, d.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string()
            .contains("cameras.npz")
    );
}
