//! The mesh files: binary PLY and binary glTF written from marching-cubes meshes and read back
//! (PLY by hand, glTF by the `gltf` crate).

use super::marching_cubes::tests::{extract, sample, sphere, torus};
use super::triangle_mesh::Mesh;
use std::io;

fn parse_ply_header(bytes: &[u8]) -> (Vec<String>, usize) {
    let marker = b"end_header\n";
    let end = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .expect("no end_header")
        + marker.len();
    let text = std::str::from_utf8(&bytes[..end]).expect("header not ascii");
    (text.lines().map(str::to_owned).collect(), end)
}

#[test]
fn ply_round_trip() {
    let n = 24;
    let values = sample(n, -1.0, 1.0, sphere);
    let m = extract(n, &values, 0.0);
    let colors: Vec<[u8; 3]> = (0..m.vertices.len())
        .map(|i| [i as u8, (i * 7) as u8, 200])
        .collect();
    let mut out = Vec::new();
    m.write_ply(&mut out, &colors).unwrap();

    let (lines, body_start) = parse_ply_header(&out);
    assert_eq!(lines[0], "ply");
    assert_eq!(lines[1], "format binary_little_endian 1.0");
    let count = |name: &str| -> usize {
        let prefix = format!("element {name} ");
        lines
            .iter()
            .find_map(|l| l.strip_prefix(&prefix))
            .unwrap()
            .parse()
            .unwrap()
    };
    let (nv, nf) = (count("vertex"), count("face"));
    assert_eq!(nv, m.vertices.len());
    assert_eq!(nf, m.triangles.len());
    let props: Vec<&str> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("property "))
        .collect();
    assert_eq!(
        props,
        [
            "float x",
            "float y",
            "float z",
            "float nx",
            "float ny",
            "float nz",
            "uchar red",
            "uchar green",
            "uchar blue",
            "list uchar int vertex_indices"
        ]
    );
    assert_eq!(lines.last().unwrap(), "end_header");

    let body = &out[body_start..];
    let vsize = 6 * 4 + 3;
    assert_eq!(body.len(), nv * vsize + nf * (1 + 3 * 4));

    // Decode and compare everything.
    let f = |o: usize| f32::from_le_bytes(body[o..o + 4].try_into().unwrap());
    for (i, ((p, n), col)) in m.vertices.iter().zip(&m.normals).zip(&colors).enumerate() {
        let o = i * vsize;
        assert_eq!([f(o), f(o + 4), f(o + 8)], *p);
        assert_eq!([f(o + 12), f(o + 16), f(o + 20)], *n);
        assert_eq!(body[o + 24..o + 27], *col);
    }
    for (t, chunk) in m.triangles.iter().zip(body[nv * vsize..].chunks(13)) {
        assert_eq!(chunk[0], 3);
        let idx: Vec<u32> = chunk[1..]
            .chunks(4)
            .map(|c| i32::from_le_bytes(c.try_into().unwrap()) as u32)
            .collect();
        assert_eq!(idx, t);
    }

    // Empty mesh writes a valid header and nothing else.
    let mut out = Vec::new();
    Mesh::default().write_ply(&mut out, &[]).unwrap();
    let (lines, body_start) = parse_ply_header(&out);
    assert!(lines.contains(&"element vertex 0".to_owned()));
    assert!(lines.contains(&"element face 0".to_owned()));
    assert_eq!(out.len(), body_start);
}

#[test]
fn ply_rejects_bad_input() {
    let values = sample(12, -1.0, 1.0, sphere);
    let m = extract(12, &values, 0.0);
    let mut out = Vec::new();
    let colors = vec![[0u8; 3]; m.vertices.len() - 1];
    let err = m.write_ply(&mut out, &colors).unwrap_err();
    assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
    assert!(out.is_empty(), "nothing written on error");

    let mut bad = m.clone();
    bad.triangles.push([0, 1, bad.vertices.len() as u32]);
    let colors = vec![[0u8; 3]; m.vertices.len()];
    assert_eq!(
        bad.write_ply(&mut out, &colors).unwrap_err().kind(),
        io::ErrorKind::InvalidInput
    );
    let mut bad = m.clone();
    bad.normals.pop();
    assert_eq!(
        bad.write_ply(&mut out, &colors).unwrap_err().kind(),
        io::ErrorKind::InvalidInput
    );
}

/// A `.glb` read back by the `gltf` crate (which validates it): the same vertices, normals and
/// triangles, unit normals, the colours back through the sRGB curve, the same volume.
#[test]
fn glb_round_trip_through_an_independent_reader() {
    use crate::mesh::glb::srgb_to_linear;
    let n = 24;
    let values = sample(n, -1.0, 1.0, torus);
    let m = extract(n, &values, 0.0);
    let colors: Vec<[u8; 3]> = (0..m.vertices.len())
        .map(|i| [i as u8, (i * 7) as u8, 3])
        .collect();
    let mut out = Vec::new();
    m.write_glb(&mut out, &colors, [0.0, 0.0, 1.0]).unwrap();
    assert_eq!(out.len() % 4, 0);

    let glb = gltf::Gltf::from_slice(&out).expect("a valid glTF");
    let blob = glb.blob.as_deref().expect("a BIN chunk");
    let mesh = glb.meshes().next().expect("a mesh");
    let prim = mesh.primitives().next().expect("a primitive");
    assert_eq!(prim.mode(), gltf::mesh::Mode::Triangles);
    let reader = prim.reader(|_| Some(blob));
    let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    let nor: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
    let col: Vec<[u16; 4]> = reader.read_colors(0).unwrap().into_rgba_u16().collect();
    let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
    assert_eq!(pos, m.vertices);
    assert_eq!(nor, m.normals);
    assert_eq!(idx.len(), 3 * m.triangles.len());
    for n in &nor {
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((l - 1.0).abs() < 1e-4, "normal length {l}");
    }
    for (c, want) in col.iter().zip(&colors) {
        assert_eq!(c[3], u16::MAX);
        for k in 0..3 {
            let lin = c[k] as f32 / 65535.0;
            assert!(
                (lin - srgb_to_linear(want[k])).abs() < 1e-4,
                "{c:?} vs {want:?}"
            );
        }
    }
    let back = Mesh {
        vertices: pos,
        normals: nor,
        triangles: idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
    };
    assert!((back.volume() - m.volume()).abs() < 1e-9 * m.volume().abs().max(1.0));
    assert!(back.volume() > 0.0);
    // The material is unlit and the node turns the scene's +z to glTF's +y.
    let mat = glb.materials().next().unwrap();
    assert!(mat.unlit() && mat.double_sided());
    let node = glb.nodes().next().unwrap();
    let (_, r, _) = node.transform().decomposed();
    let s = std::f32::consts::FRAC_1_SQRT_2;
    assert!((r[0] + s).abs() < 1e-6 && (r[3] - s).abs() < 1e-6, "{r:?}");
}
