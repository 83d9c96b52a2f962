//! Tests of marching cubes (its tables; area, volume and topology of analytic surfaces;
//! watertight random fields; degenerate, NaN and single-cube inputs) and of the PLY files.

use super::*;
use crate::mesh::triangle_mesh::dot64;
use std::collections::HashMap;
use std::f64::consts::PI;

/// Samples `f` on `[lo, hi]^3` at `n^3`, exactly as the module places samples.
pub(crate) fn sample(n: usize, lo: f32, hi: f32, f: impl Fn([f32; 3]) -> f32) -> Vec<f32> {
    let c = |i: usize| lo + (hi - lo) * (i as f32) / ((n - 1) as f32);
    let mut v = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                v.push(f([c(i), c(j), c(k)]));
            }
        }
    }
    v
}

pub(crate) fn extract(n: usize, values: &[f32], level: f32) -> Mesh {
    let grid = Grid {
        res: [n; 3],
        min: [-1.0; 3],
        max: [1.0; 3],
        values,
    };
    marching_cubes(&grid, level)
}

pub(crate) fn sphere(p: [f32; 3]) -> f32 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.7
}

pub(crate) fn torus(p: [f32; 3]) -> f32 {
    let q = (p[0] * p[0] + p[1] * p[1]).sqrt() - 0.5;
    (q * q + p[2] * p[2]).sqrt() - 0.2
}

/// Asserts every undirected edge is used by exactly two triangles, in opposite
/// directions. Returns the number of undirected edges.
fn assert_watertight_oriented(m: &Mesh) -> usize {
    let mut undirected: HashMap<(u32, u32), u32> = HashMap::new();
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &m.triangles {
        assert!(
            t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
            "degenerate ids {t:?}"
        );
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            *undirected.entry((a.min(b), a.max(b))).or_default() += 1;
            *directed.entry((a, b)).or_default() += 1;
        }
    }
    for (e, c) in &undirected {
        assert_eq!(*c, 2, "edge {e:?} shared by {c} triangles");
    }
    for (e, c) in &directed {
        assert_eq!(*c, 1, "directed edge {e:?} appears {c} times");
    }
    // No unused vertices either.
    let mut used = vec![false; m.vertices.len()];
    m.triangles
        .iter()
        .flatten()
        .for_each(|&i| used[i as usize] = true);
    assert!(used.iter().all(|u| *u), "unreferenced vertex");
    undirected.len()
}

fn euler(m: &Mesh, edges: usize) -> i64 {
    m.vertices.len() as i64 - edges as i64 + m.triangles.len() as i64
}

fn rel_err(got: f64, want: f64) -> f64 {
    (got - want).abs() / want.abs()
}

#[test]
fn tables_are_consistent() {
    for case in 0..256usize {
        // Edge table: an edge is crossed iff its corners are on different sides.
        let mut expect = 0u16;
        for (e, &(a, b, _)) in EDGE_CORNERS.iter().enumerate() {
            if ((case >> a) & 1) != ((case >> b) & 1) {
                expect |= 1 << e;
            }
        }
        assert_eq!(EDGE_TABLE[case], expect, "EDGE_TABLE[{case}]");

        // Triangle table: -1 terminated, multiple of 3, uses exactly the crossed
        // edges.
        let row = &TRI_TABLE[case];
        let len = row.iter().position(|&x| x < 0).unwrap_or(16);
        assert!(len % 3 == 0 && len <= 15, "TRI_TABLE[{case}] length {len}");
        assert!(
            row[len..].iter().all(|&x| x == -1),
            "TRI_TABLE[{case}] tail"
        );
        let mut used = 0u16;
        for &e in &row[..len] {
            assert!((0..12).contains(&e), "TRI_TABLE[{case}] bad edge {e}");
            used |= 1 << e;
        }
        assert_eq!(used, expect, "TRI_TABLE[{case}] edges");

        // Within the cube, the triangles form an oriented surface whose boundary
        // runs along cube faces, and each triangle faces away from the inside.
        let mid = |e: i8| {
            let (a, b, _) = EDGE_CORNERS[e as usize];
            let (pa, pb) = (CORNER_OFFSET[a], CORNER_OFFSET[b]);
            std::array::from_fn::<f64, 3, _>(|d| (pa[d] + pb[d]) as f64 * 0.5)
        };
        let mut directed: HashMap<(i8, i8), i32> = HashMap::new();
        for t in row[..len].chunks(3) {
            // Orientation as emitted by marching_cubes (reversed classic order).
            let tri = [t[0], t[2], t[1]];
            let n = cross64(
                sub64(mid(tri[1]), mid(tri[0])),
                sub64(mid(tri[2]), mid(tri[0])),
            );
            let mut s = 0.0;
            for &e in &tri {
                let (a, b, _) = EDGE_CORNERS[e as usize];
                let (inside, outside) = if (case >> a) & 1 == 1 { (a, b) } else { (b, a) };
                let d: [f64; 3] = std::array::from_fn(|x| {
                    CORNER_OFFSET[outside][x] as f64 - CORNER_OFFSET[inside][x] as f64
                });
                s += dot64(n, d);
            }
            assert!(s > 0.0, "TRI_TABLE[{case}] triangle {t:?} faces inward");
            for i in 0..3 {
                *directed.entry((tri[i], tri[(i + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &c) in &directed {
            assert_eq!(c, 1, "case {case}: directed edge {a}->{b} twice");
            if directed.contains_key(&(b, a)) {
                continue;
            }
            // Boundary edge: both points must lie on one cube face.
            let (pa, pb) = (mid(a), mid(b));
            let on_face = (0..3).any(|d| pa[d] == pb[d] && (pa[d] == 0.0 || pa[d] == 1.0));
            assert!(
                on_face,
                "case {case}: boundary edge {a}-{b} crosses the cube"
            );
        }
    }
}

#[test]
fn sphere_accuracy_and_topology() {
    let n = 96;
    let values = sample(n, -1.0, 1.0, sphere);
    let m = extract(n, &values, 0.0);
    let r = 0.7f64;
    assert!(!m.triangles.is_empty());
    assert_eq!(m.vertices.len(), m.normals.len());

    let area = m.area();
    let vol = m.volume();
    assert!(rel_err(area, 4.0 * PI * r * r) < 0.02, "area {area}");
    assert!(
        rel_err(vol, 4.0 / 3.0 * PI * r * r * r) < 0.02,
        "volume {vol}"
    );

    let cos5 = 5f64.to_radians().cos();
    for (p, nrm) in m.vertices.iter().zip(&m.normals) {
        let p = p.map(f64::from);
        let len = norm64(p);
        assert!((len - r).abs() < 0.01, "vertex {p:?} at radius {len}");
        let nrm = nrm.map(f64::from);
        assert!((norm64(nrm) - 1.0).abs() < 1e-5, "normal not unit: {nrm:?}");
        assert!(
            dot64(nrm, p) / len > cos5,
            "normal {nrm:?} not radial at {p:?}"
        );
    }
    let edges = assert_watertight_oriented(&m);
    assert_eq!(euler(&m, edges), 2, "sphere Euler characteristic");
}

#[test]
fn box_volume() {
    let (a, b, c) = (0.5f32, 0.3f32, 0.4f32);
    let n = 81;
    let values = sample(n, -1.0, 1.0, |p| {
        (p[0].abs() - a).max(p[1].abs() - b).max(p[2].abs() - c)
    });
    let m = extract(n, &values, 0.0);
    let want = 8.0 * (a * b * c) as f64;
    let vol = m.volume();
    assert!(rel_err(vol, want) < 0.02, "box volume {vol} vs {want}");
    let want_area = 8.0 * (a * b + b * c + a * c) as f64;
    assert!(rel_err(m.area(), want_area) < 0.02, "box area {}", m.area());
    assert_watertight_oriented(&m);
}

#[test]
fn torus_volume_and_topology() {
    let n = 96;
    let values = sample(n, -1.0, 1.0, torus);
    let m = extract(n, &values, 0.0);
    let want = 2.0 * PI * PI * 0.5 * 0.2 * 0.2;
    let vol = m.volume();
    assert!(rel_err(vol, want) < 0.02, "torus volume {vol} vs {want}");
    let edges = assert_watertight_oriented(&m);
    assert_eq!(euler(&m, edges), 0, "torus Euler characteristic");
}

#[test]
fn nonzero_level_and_anisotropic_grid() {
    // Sphere of radius 0.5 as the 0.2-level of |p| - 0.3, on a non-cubic grid
    // with different spacing per axis.
    let res = [40usize, 57, 33];
    let (min, max) = ([-0.9f32, -0.8, -0.7], [0.8f32, 0.9, 0.75]);
    let mut values = Vec::new();
    for k in 0..res[2] {
        for j in 0..res[1] {
            for i in 0..res[0] {
                let p: [f32; 3] = std::array::from_fn(|d| {
                    let idx = [i, j, k][d];
                    min[d] + (max[d] - min[d]) * idx as f32 / (res[d] - 1) as f32
                });
                values.push((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.3);
            }
        }
    }
    let m = marching_cubes(
        &Grid {
            res,
            min,
            max,
            values: &values,
        },
        0.2,
    );
    let want = 4.0 / 3.0 * PI * 0.125;
    assert!(rel_err(m.volume(), want) < 0.03, "volume {}", m.volume());
    for (p, nrm) in m.vertices.iter().zip(&m.normals) {
        let p = p.map(f64::from);
        assert!(dot64(nrm.map(f64::from), p) / norm64(p) > 0.98);
    }
    assert_watertight_oriented(&m);

    // Mirroring the x axis (max < min) must keep the outward orientation.
    let mut mirrored = values.clone();
    for k in 0..res[2] {
        for j in 0..res[1] {
            let row = &mut mirrored[(j + res[1] * k) * res[0]..][..res[0]];
            row.reverse();
        }
    }
    let m2 = marching_cubes(
        &Grid {
            res,
            min: [0.9, min[1], min[2]],
            max: [-0.8, max[1], max[2]],
            values: &mirrored,
        },
        0.2,
    );
    assert!(
        rel_err(m2.volume(), m.volume()) < 1e-4,
        "{} vs {}",
        m2.volume(),
        m.volume()
    );
    assert_watertight_oriented(&m2);
}

/// Small deterministic PRNG (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next_f32(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (x >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    }
}

#[test]
fn random_fields_are_watertight() {
    // Random values exercise every case, including all ambiguous faces; a
    // positive border makes every component closed.
    let n = 14;
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut seen = [false; 256];
    for round in 0..40 {
        let mut values = vec![1.0f32; n * n * n];
        for k in 1..n - 1 {
            for j in 1..n - 1 {
                for i in 1..n - 1 {
                    let mut v = rng.next_f32();
                    // Some samples exactly on the level.
                    if round % 4 == 3 && v.abs() < 0.1 {
                        v = 0.0;
                    }
                    values[i + n * (j + n * k)] = v;
                }
            }
        }
        for k in 0..n - 1 {
            for j in 0..n - 1 {
                for i in 0..n - 1 {
                    let mut case = 0;
                    for (c, o) in CORNER_OFFSET.iter().enumerate() {
                        let v = values[i + o[0] + n * (j + o[1] + n * (k + o[2]))];
                        case |= usize::from(v < 0.0) << c;
                    }
                    seen[case] = true;
                }
            }
        }
        let m = extract(n, &values, 0.0);
        assert_watertight_oriented(&m);
        assert!(m.volume() > 0.0);
        assert!(m.normals.iter().all(|v| v.iter().all(|x| x.is_finite())));
    }
    assert!(seen.iter().all(|s| *s), "not all 256 cases exercised");
}

#[test]
fn empty_and_degenerate_inputs() {
    let n = 8;
    let values = vec![1.0f32; n * n * n];
    let m = extract(n, &values, 0.0);
    assert!(m.vertices.is_empty() && m.normals.is_empty() && m.triangles.is_empty());
    assert_eq!(m.area(), 0.0);
    assert_eq!(m.volume(), 0.0);

    // All inside: also empty.
    let m = extract(n, &vec![-1.0f32; n * n * n], 0.0);
    assert!(m.triangles.is_empty());

    // Too few samples along an axis.
    let v = [0.0f32, -1.0, 1.0, 0.5];
    let g = Grid {
        res: [4, 1, 1],
        min: [0.0; 3],
        max: [1.0; 3],
        values: &v,
    };
    assert!(marching_cubes(&g, 0.0).triangles.is_empty());
    let g = Grid {
        res: [0, 0, 0],
        min: [0.0; 3],
        max: [1.0; 3],
        values: &[],
    };
    assert!(marching_cubes(&g, 0.0).triangles.is_empty());

    // NaN level.
    let values = sample(16, -1.0, 1.0, sphere);
    assert!(extract(16, &values, f32::NAN).triangles.is_empty());
}

#[test]
#[should_panic(expected = "values.len()")]
fn wrong_value_count_panics() {
    let v = vec![0.0f32; 7];
    marching_cubes(
        &Grid {
            res: [2, 2, 2],
            min: [0.0; 3],
            max: [1.0; 3],
            values: &v,
        },
        0.0,
    );
}

#[test]
fn nan_region_does_not_panic() {
    let n = 48;
    let mut values = sample(n, -1.0, 1.0, sphere);
    let c = |i: usize| -1.0 + 2.0 * i as f32 / (n - 1) as f32;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                if c(i) > 0.2 && c(k) < 0.1 {
                    values[i + n * (j + n * k)] = f32::NAN;
                }
            }
        }
    }
    // A corner block of NaN, an all-NaN grid, and isolated NaNs.
    let m = extract(n, &values, 0.0);
    assert!(!m.triangles.is_empty());
    for (p, nrm) in m.vertices.iter().zip(&m.normals) {
        assert!(p.iter().all(|x| x.is_finite()));
        assert!(nrm.iter().all(|x| x.is_finite()));
        let l = (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
        assert!((l - 1.0).abs() < 1e-4, "normal {nrm:?}");
    }
    assert!(
        extract(n, &vec![f32::NAN; n * n * n], 0.0)
            .triangles
            .is_empty()
    );
    let mut values = sample(n, -1.0, 1.0, sphere);
    for i in (0..values.len()).step_by(97) {
        values[i] = f32::NAN;
    }
    let m = extract(n, &values, 0.0);
    assert!(m.normals.iter().flatten().all(|x| x.is_finite()));
}

#[test]
fn single_cube_orientation_and_normal_fallback() {
    // One inside corner at the origin: one triangle facing away from it.
    let v = [-1.0f32, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    let g = Grid {
        res: [2, 2, 2],
        min: [0.0; 3],
        max: [1.0; 3],
        values: &v,
    };
    let m = marching_cubes(&g, 0.0);
    assert_eq!(m.triangles.len(), 1);
    let [a, b, c] = m.triangles[0].map(|i| m.vertices[i as usize].map(f64::from));
    let face = cross64(sub64(b, a), sub64(c, a));
    assert!(face.iter().all(|x| *x > 0.0), "face normal {face:?}");
    for n in &m.normals {
        assert!(n.iter().all(|x| *x > 0.0), "normal {n:?}");
    }

    // Bottom layer inside, top outside, but a flat box (min z == max z): the
    // gradient is not computable, so normals come from the faces (+z).
    let v = [-1.0f32, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0];
    let g = Grid {
        res: [2, 2, 2],
        min: [0.0; 3],
        max: [1.0, 1.0, 0.0],
        values: &v,
    };
    let m = marching_cubes(&g, 0.0);
    assert_eq!(m.triangles.len(), 2);
    for n in &m.normals {
        assert!(
            (n[2] - 1.0).abs() < 1e-6 && n[0] == 0.0 && n[1] == 0.0,
            "normal {n:?}"
        );
    }
}

#[test]
fn area_and_volume_of_a_tetrahedron() {
    let m = Mesh {
        vertices: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        normals: vec![[0.0; 3]; 4],
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    };
    assert!((m.volume() - 1.0 / 6.0).abs() < 1e-12);
    assert!((m.area() - (1.5 + 3f64.sqrt() / 2.0)).abs() < 1e-12);
}
