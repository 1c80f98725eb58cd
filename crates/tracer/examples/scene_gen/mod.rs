//! Procedural test geometry shared by `examples/make_scenes.rs` and `benches/tracer.rs` (included by
//! both with `#[path]`; not an example of its own).
//!
//! The displaced sphere: a geodesic sphere (an icosahedron whose faces are split into `n × n`
//! triangles each, so `20 n²` triangles) displaced radially by a smooth sum of sines, sitting on the
//! floor of the Cornell box. Vertices are shared between neighbouring faces (each is computed once,
//! from a canonical key), so the mesh is closed and watertight.
#![allow(dead_code)]

use glam::{DVec3, Vec3, Vec4};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::material::Material;
use pathfarm_tracer::scene::SceneParts;
use std::collections::HashMap;
use std::path::PathBuf;

/// Geodesic frequency giving 20·128² = 327,680 triangles (the "330k" scene).
pub const FREQ_330K: u32 = 128;
/// Geodesic frequency giving 20·224² = 1,003,520 triangles (the "million" scene).
pub const FREQ_1M: u32 = 224;

/// Undisplaced radius, in the Cornell box's units (the box spans about 0..5.56 × 0..5.49 × 0..5.59).
pub const SPHERE_RADIUS: f32 = 0.8;
/// Relative amplitude of the radial displacement (the radius varies within ±8 %).
pub const DISPLACEMENT: f32 = 0.08;
/// Centre of the sphere's footprint on the floor (x, z). The box's blocks occupy the middle
/// (short block x 0.82..2.90, z 0.65..2.72; tall block x 2.65..4.72, z 2.47..4.56), so the sphere
/// stands in the free front corner in front of the tall block, in full view of the camera
/// (which looks along +z from z = −8), clear of both blocks and the x = 5.5 wall.
pub const SPHERE_CENTER_XZ: [f32; 2] = [4.25, 1.2];

/// The Cornell box's white, as in `cornell.gltf` (Lambertian: metallic 0, roughness 1, specular 0).
pub const WHITE: [f32; 3] = [0.725, 0.71, 0.68];

/// `../shared/scenes/cornell.gltf` beside the repository.
pub fn cornell_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes/cornell.gltf")
}

/// An indexed triangle mesh (counter-clockwise seen from outside).
#[derive(Clone, Debug, Default)]
pub struct IndexedMesh {
    pub positions: Vec<Vec3>,
    pub indices: Vec<u32>,
}

impl IndexedMesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// One `[Vec3; 3]` per triangle, as [`pathfarm_tracer::geometry::Mesh`] stores them.
    pub fn triangles(&self) -> Vec<[Vec3; 3]> {
        self.indices
            .chunks_exact(3)
            .map(|t| {
                [
                    self.positions[t[0] as usize],
                    self.positions[t[1] as usize],
                    self.positions[t[2] as usize],
                ]
            })
            .collect()
    }

    /// Component-wise bounds of the positions.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }

    /// True if every edge is shared by exactly two triangles, once in each direction (closed,
    /// consistently oriented, no T-junctions).
    pub fn is_watertight(&self) -> bool {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.indices.len());
        for t in self.indices.chunks_exact(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *edges.entry((a, b)).or_default() += 1;
            }
        }
        edges
            .iter()
            .all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
    }
}

/// The smooth radial displacement, in [−1, 1], of the unit direction `d`.
pub fn displacement(d: DVec3) -> f64 {
    0.40 * (5.1 * d.x + 2.3 * d.y + 0.7).sin()
        + 0.25 * (7.3 * d.y - 4.1 * d.z + 1.9).sin()
        + 0.20 * (11.7 * d.z + 6.2 * d.x + 2.6).sin()
        + 0.15 * (23.0 * d.x + 17.0 * d.y - 19.0 * d.z).sin() * (13.0 * d.z - 9.0 * d.y).cos()
}

/// The 12 vertices and 20 counter-clockwise (seen from outside) faces of a unit icosahedron.
fn icosahedron() -> (Vec<DVec3>, [[u8; 3]; 20]) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let verts = [
        (-1., t, 0.),
        (1., t, 0.),
        (-1., -t, 0.),
        (1., -t, 0.),
        (0., -1., t),
        (0., 1., t),
        (0., -1., -t),
        (0., 1., -t),
        (t, 0., -1.),
        (t, 0., 1.),
        (-t, 0., -1.),
        (-t, 0., 1.),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    (verts, faces)
}

/// A geodesic sphere of frequency `n` (20 n² triangles), radius `radius`, displaced radially by
/// ±`amplitude`·radius·[`displacement`], with its footprint centred on `center_xz` and its lowest
/// vertex `lift` above y = 0.
pub fn displaced_sphere(
    n: u32,
    radius: f32,
    amplitude: f32,
    center_xz: [f32; 2],
    lift: f32,
) -> IndexedMesh {
    assert!(n >= 1 && n < u16::MAX as u32);
    let (corners, faces) = icosahedron();
    // A grid point is a combination of icosahedron corners with integer weights summing to n; the
    // key lists them sorted by corner, so points on shared edges and corners get one vertex, computed
    // by the same arithmetic whichever face asks.
    type Key = [(u8, u16); 3];
    let mut index_of: HashMap<Key, u32> =
        HashMap::with_capacity(10 * (n as usize) * (n as usize) + 2);
    let mut unit: Vec<DVec3> = Vec::with_capacity(10 * (n as usize) * (n as usize) + 2);
    let mut vertex = |w: [(u8, u16); 3]| -> u32 {
        let mut key: Key = w;
        for k in &mut key {
            if k.1 == 0 {
                *k = (u8::MAX, 0);
            }
        }
        key.sort_unstable();
        *index_of.entry(key).or_insert_with(|| {
            let mut p = DVec3::ZERO;
            for &(c, wt) in &key {
                if wt > 0 {
                    p += corners[c as usize] * (wt as f64);
                }
            }
            unit.push(p.normalize());
            (unit.len() - 1) as u32
        })
    };
    let mut indices = Vec::with_capacity(20 * 3 * (n as usize) * (n as usize));
    let n16 = n as u16;
    for [a, b, c] in faces {
        // p(i, j) = ((n−i−j)·a + i·b + j·c) / n.
        let p = |i: u16, j: u16| [(a, n16 - i - j), (b, i), (c, j)];
        let mut grid = vec![vec![0u32; 0]; n as usize + 1];
        for i in 0..=n16 {
            grid[i as usize] = (0..=n16 - i).map(|j| vertex(p(i, j))).collect();
        }
        for i in 0..n as usize {
            for j in 0..n as usize - i {
                indices.extend([grid[i][j], grid[i + 1][j], grid[i][j + 1]]);
                if i + j + 1 < n as usize {
                    indices.extend([grid[i + 1][j], grid[i + 1][j + 1], grid[i][j + 1]]);
                }
            }
        }
    }
    let r = radius as f64;
    let amp = amplitude as f64;
    let displaced: Vec<DVec3> = unit
        .iter()
        .map(|&d| d * (r * (1.0 + amp * displacement(d))))
        .collect();
    let min_y = displaced.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
    let offset = DVec3::new(
        center_xz[0] as f64,
        lift as f64 - min_y,
        center_xz[1] as f64,
    );
    let positions = displaced.iter().map(|&p| (p + offset).as_vec3()).collect();
    IndexedMesh { positions, indices }
}

/// The benchmark sphere of frequency `n` (radius, displacement and place as the written scenes).
pub fn bench_sphere(n: u32) -> IndexedMesh {
    displaced_sphere(n, SPHERE_RADIUS, DISPLACEMENT, SPHERE_CENTER_XZ, 1e-3)
}

/// The sphere's material as the loader makes it from the JSON `make_scenes` writes.
pub fn white_material() -> Material {
    Material {
        name: Some("sphere_white".to_string()),
        base_color: Vec4::new(WHITE[0], WHITE[1], WHITE[2], 1.0),
        metallic: 0.0,
        roughness: 1.0,
        specular: 0.0,
        double_sided: true,
        ..Material::default()
    }
}

/// The parts of the shared Cornell box, loaded from `cornell_path()`.
pub fn cornell_parts() -> SceneParts {
    let path = cornell_path();
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    gltf::load_parts(&bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("cannot load {}: {e}", path.display()))
}

/// The Cornell box plus `sphere` (with [`white_material`]), in memory: the scene `make_scenes` writes
/// as `cornell_sphere.glb` when `sphere` is `bench_sphere(FREQ_330K)`.
pub fn cornell_with(sphere: &IndexedMesh) -> SceneParts {
    let mut parts = cornell_parts();
    add_white_mesh(&mut parts, sphere).unwrap_or_else(|e| panic!("{e}"));
    parts
}

/// Appends `mesh` to `parts` with a new [`white_material`]. The mesh carries positions only, so the
/// scene must too: appended to a mesh with per-triangle normals, UVs or tangents it would leave
/// those arrays short.
pub fn add_white_mesh(parts: &mut SceneParts, mesh: &IndexedMesh) -> Result<(), &'static str> {
    let m = &parts.mesh;
    if m.normals.is_some() || m.uv0.is_some() || m.uv1.is_some() || m.tangents.is_some() {
        return Err("the scene to extend is expected to have positions only");
    }
    let material = parts.materials.len() as u32;
    parts.materials.push(white_material());
    let tris = mesh.triangles();
    parts
        .mesh
        .material
        .extend(std::iter::repeat_n(material, tris.len()));
    parts.mesh.positions.extend(tris);
    Ok(())
}
