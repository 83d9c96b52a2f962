//! An indexed triangle mesh: its area and enclosed volume (how the tests check marching
//! cubes against analytic shapes) and binary PLY output.

use std::io::{self, Write};

/// A triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Unit per-vertex normals (same length as `vertices`).
    pub normals: Vec<[f32; 3]>,
    /// Vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.tri_f64(t);
                0.5 * norm64(cross64(sub64(b, a), sub64(c, a)))
            })
            .sum()
    }

    /// Enclosed volume (signed, by the divergence theorem; positive for
    /// outward-oriented closed meshes).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.tri_f64(t);
                dot64(a, cross64(b, c))
            })
            .sum::<f64>()
            / 6.0
    }

    /// Writes a binary little-endian PLY (vertex `x y z`, `nx ny nz` as float,
    /// `red green blue` as uchar; face `list uchar int vertex_indices`) that
    /// MeshLab/Blender/Open3D open.
    ///
    /// `colors` is one `[u8; 3]` per vertex. Returns an error of kind
    /// [`io::ErrorKind::InvalidInput`] if `colors.len()` or `normals.len()` differs
    /// from `vertices.len()`, if a triangle index is out of range, or if there are
    /// more than `i32::MAX` vertices.
    pub fn write_ply(&self, w: &mut impl Write, colors: &[[u8; 3]]) -> io::Result<()> {
        self.check(colors, "write_ply")?;
        let nv = self.vertices.len();
        let header = format!(
            "ply\n\
             format binary_little_endian 1.0\n\
             comment written by marching_cubes\n\
             element vertex {nv}\n\
             property float x\n\
             property float y\n\
             property float z\n\
             property float nx\n\
             property float ny\n\
             property float nz\n\
             property uchar red\n\
             property uchar green\n\
             property uchar blue\n\
             element face {}\n\
             property list uchar int vertex_indices\n\
             end_header\n",
            self.triangles.len()
        );
        w.write_all(header.as_bytes())?;

        const CHUNK: usize = 1 << 16;
        let mut buf: Vec<u8> = Vec::with_capacity(CHUNK + 64);
        for ((p, n), c) in self.vertices.iter().zip(&self.normals).zip(colors) {
            for v in p.iter().chain(n.iter()) {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            buf.extend_from_slice(c);
            if buf.len() >= CHUNK {
                w.write_all(&buf)?;
                buf.clear();
            }
        }
        for t in &self.triangles {
            buf.push(3);
            for &i in t {
                buf.extend_from_slice(&(i as i32).to_le_bytes());
            }
            if buf.len() >= CHUNK {
                w.write_all(&buf)?;
                buf.clear();
            }
        }
        w.write_all(&buf)?;
        w.flush()
    }

    /// Checks that `colors` and the normals match the vertices, that triangles index existing
    /// vertices and that the count fits the formats' 32-bit indices; `what` names the writer.
    pub(super) fn check(&self, colors: &[[u8; 3]], what: &str) -> io::Result<()> {
        let nv = self.vertices.len();
        let invalid = |msg: String| io::Error::new(io::ErrorKind::InvalidInput, msg);
        if colors.len() != nv {
            return Err(invalid(format!(
                "{what}: {} colors for {nv} vertices",
                colors.len()
            )));
        }
        if self.normals.len() != nv {
            return Err(invalid(format!(
                "{what}: {} normals for {nv} vertices",
                self.normals.len()
            )));
        }
        if nv > i32::MAX as usize {
            return Err(invalid(format!("{what}: too many vertices ({nv})")));
        }
        if let Some(t) = self
            .triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= nv))
        {
            return Err(invalid(format!(
                "{what}: triangle {t:?} references a vertex >= {nv}"
            )));
        }
        Ok(())
    }

    pub(super) fn tri_f64(&self, t: &[u32; 3]) -> [[f64; 3]; 3] {
        t.map(|i| self.vertices[i as usize].map(f64::from))
    }
}

/// Small `f64` vector maths for areas, volumes and face normals.
pub(super) fn sub64(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(super) fn cross64(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub(super) fn dot64(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(super) fn norm64(a: [f64; 3]) -> f64 {
    dot64(a, a).sqrt()
}
