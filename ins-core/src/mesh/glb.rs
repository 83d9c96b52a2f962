//! Binary glTF 2.0 (`.glb`) output of a vertex-coloured mesh: what Blender, three.js,
//! `<model-viewer>` and Windows' 3D Viewer open without plug-ins (PLY needs them in the last
//! two). Written by hand because the container is two chunks and a page of JSON; the tests
//! read it back with the `gltf` crate, an independent reader that validates it.
//!
//! Layout: one buffer holding positions and normals (`f32` VEC3), colours (normalised
//! `u16` VEC4, *linear* as glTF defines vertex colours: the sRGB bytes are converted, and
//! 16 bits keep the dark tones that 8 linear bits would band) and `u32` indices. The
//! material is unlit (`KHR_materials_unlit`) and double-sided: the colours are baked
//! radiance, which a viewer's lighting would shade a second time. Vertices stay in the
//! scene's frame; the node's rotation turns the scene's up direction to glTF's +Y.

use std::io::{self, Write};

use super::triangle_mesh::Mesh;

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;

/// sRGB-encoded byte → linear value in `[0, 1]` (the IEC 61966-2-1 curve).
pub fn srgb_to_linear(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The rotation (quaternion `[x, y, z, w]`) that turns `up` onto +Y by the shortest arc.
pub fn up_to_y(up: [f32; 3]) -> [f32; 4] {
    let n = (up[0] * up[0] + up[1] * up[1] + up[2] * up[2]).sqrt();
    if !(n > 0.0) {
        return [0.0, 0.0, 0.0, 1.0];
    }
    let u = up.map(|v| v / n);
    // q = (u × ŷ, 1 + u·ŷ), normalised; antiparallel: half a turn about x.
    let (cx, cy, cz, w) = (-u[2], 0.0, u[0], 1.0 + u[1]);
    let len = (cx * cx + cy * cy + cz * cz + w * w).sqrt();
    if len < 1e-6 {
        return [1.0, 0.0, 0.0, 0.0];
    }
    [cx / len, cy / len, cz / len, w / len]
}

impl Mesh {
    /// Writes the mesh as binary glTF, vertex colours `colors` (sRGB bytes, one per vertex),
    /// the node rotated so that `up` (scene frame) points along glTF's +Y.
    ///
    /// Errors as [`Mesh::write_ply`] for inconsistent input, and for a mesh without
    /// triangles (glTF accessors cannot be empty).
    pub fn write_glb(
        &self,
        w: &mut impl Write,
        colors: &[[u8; 3]],
        up: [f32; 3],
    ) -> io::Result<()> {
        self.check(colors, "write_glb")?;
        if self.triangles.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "write_glb: the mesh has no triangles",
            ));
        }
        let nv = self.vertices.len();
        let nt = self.triangles.len();
        let (mut min, mut max) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &self.vertices {
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        let lens = [12 * nv, 12 * nv, 8 * nv, 12 * nt];
        let offsets = [0, lens[0], lens[0] + lens[1], lens[0] + lens[1] + lens[2]];
        let bin_len: usize = lens.iter().sum();
        let view = |i: usize, target: u32| serde_json::json!({"buffer": 0, "byteOffset": offsets[i], "byteLength": lens[i], "target": target});
        let json = serde_json::json!({
            "asset": {"version": "2.0", "generator": "ins-rs"},
            "extensionsUsed": ["KHR_materials_unlit"],
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "rotation": up_to_y(up)}],
            "meshes": [{"primitives": [{
                "attributes": {"POSITION": 0, "NORMAL": 1, "COLOR_0": 2},
                "indices": 3,
                "material": 0,
                "mode": 4
            }]}],
            "materials": [{
                "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "doubleSided": true,
                "extensions": {"KHR_materials_unlit": {}}
            }],
            "buffers": [{"byteLength": bin_len}],
            "bufferViews": [view(0, ARRAY_BUFFER), view(1, ARRAY_BUFFER), view(2, ARRAY_BUFFER), view(3, ELEMENT_ARRAY_BUFFER)],
            "accessors": [
                {"bufferView": 0, "componentType": FLOAT, "count": nv, "type": "VEC3", "min": min, "max": max},
                {"bufferView": 1, "componentType": FLOAT, "count": nv, "type": "VEC3"},
                {"bufferView": 2, "componentType": UNSIGNED_SHORT, "normalized": true, "count": nv, "type": "VEC4"},
                {"bufferView": 3, "componentType": UNSIGNED_INT, "count": 3 * nt, "type": "SCALAR"}
            ]
        });
        let mut json = serde_json::to_vec(&json).map_err(io::Error::other)?;
        while json.len() % 4 != 0 {
            json.push(b' ');
        }
        // bin_len is a multiple of 4: every section is.
        let total = 12 + 8 + json.len() + 8 + bin_len;
        let total = u32::try_from(total).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("write_glb: {total} bytes exceed glTF's 4 GiB"),
            )
        })?;
        let mut head = Vec::with_capacity(20);
        for v in [MAGIC, 2, total, json.len() as u32, CHUNK_JSON] {
            head.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&head)?;
        w.write_all(&json)?;
        w.write_all(&(bin_len as u32).to_le_bytes())?;
        w.write_all(&CHUNK_BIN.to_le_bytes())?;

        const CHUNK: usize = 1 << 16;
        let mut buf: Vec<u8> = Vec::with_capacity(CHUNK + 64);
        let flush = |buf: &mut Vec<u8>, w: &mut dyn Write, force: bool| -> io::Result<()> {
            if force || buf.len() >= CHUNK {
                w.write_all(buf)?;
                buf.clear();
            }
            Ok(())
        };
        for v in self.vertices.iter().chain(&self.normals) {
            for c in v {
                buf.extend_from_slice(&c.to_le_bytes());
            }
            flush(&mut buf, w, false)?;
        }
        for c in colors {
            for &b in c {
                let v = (srgb_to_linear(b) * 65535.0).round() as u16;
                buf.extend_from_slice(&v.to_le_bytes());
            }
            buf.extend_from_slice(&u16::MAX.to_le_bytes());
            flush(&mut buf, w, false)?;
        }
        for t in &self.triangles {
            for i in t {
                buf.extend_from_slice(&i.to_le_bytes());
            }
            flush(&mut buf, w, false)?;
        }
        flush(&mut buf, w, true)?;
        w.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
        // v' = v + 2w(q×v) + 2 q×(q×v)
        let (x, y, z, w) = (q[0], q[1], q[2], q[3]);
        let c1 = [
            y * v[2] - z * v[1],
            z * v[0] - x * v[2],
            x * v[1] - y * v[0],
        ];
        let c2 = [
            y * c1[2] - z * c1[1],
            z * c1[0] - x * c1[2],
            x * c1[1] - y * c1[0],
        ];
        [0, 1, 2].map(|k| v[k] + 2.0 * w * c1[k] + 2.0 * c2[k])
    }

    #[test]
    fn the_scene_up_direction_becomes_gltf_y() {
        for up in [
            [0.0, 0.0, 1.0],
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.3, -0.2, 0.9],
        ] {
            let q = up_to_y(up);
            let n = (up[0] * up[0] + up[1] * up[1] + up[2] * up[2]).sqrt();
            let r = rotate(q, up.map(|v| v / n));
            assert!(
                (r[0]).abs() < 1e-5 && (r[1] - 1.0).abs() < 1e-5 && r[2].abs() < 1e-5,
                "{up:?} → {r:?}"
            );
        }
        // Blender's convention for z-up scenes: (x, y, z) → (x, z, −y).
        let r = rotate(up_to_y([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]);
        assert!((r[2] + 1.0).abs() < 1e-5, "{r:?}");
    }

    #[test]
    fn srgb_curve_ends_and_midpoint() {
        assert_eq!(srgb_to_linear(0), 0.0);
        assert!((srgb_to_linear(255) - 1.0).abs() < 1e-6);
        // sRGB 188 is about 50 % linear.
        assert!((srgb_to_linear(188) - 0.5).abs() < 0.01);
    }

    #[test]
    fn inconsistent_or_empty_meshes_are_refused() {
        let mut out = Vec::new();
        let e = Mesh::default()
            .write_glb(&mut out, &[], [0.0, 0.0, 1.0])
            .unwrap_err();
        assert!(e.to_string().contains("no triangles"), "{e}");
        let m = Mesh {
            vertices: vec![[0.0; 3]; 3],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            triangles: vec![[0, 1, 2]],
        };
        let e = m
            .write_glb(&mut out, &[[0; 3]; 2], [0.0, 0.0, 1.0])
            .unwrap_err();
        assert!(e.to_string().contains("2 colors for 3 vertices"), "{e}");
        assert!(out.is_empty());
    }
}
