//! Scene builders and statistics shared by the integration tests.
#![allow(dead_code)]

pub mod bins;
pub mod bsdf_chi2;

use glam::{Affine3A, Vec3, Vec4};
use pathfarm_tracer::camera::{Camera, Perspective, Projection};
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::light::{PointLight, PunctualLight};
use pathfarm_tracer::material::Material;
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{Accumulation, Scene};
use std::path::PathBuf;

/// PCG32 (O'Neill): a small, fast, deterministic generator for the tests' uniform inputs.
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

impl Pcg32 {
    /// The generator with initial state `seed` on stream `seq`.
    pub fn new(seed: u64, seq: u64) -> Self {
        let mut r = Pcg32 {
            state: 0,
            inc: (seq << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }

    /// One generator per seed, each on its own stream.
    pub fn seeded(seed: u64) -> Self {
        Pcg32::new(0x853c_49e6_748f_ea9b ^ seed, seed)
    }

    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    /// Uniform in [0, 1) with 24 bits.
    pub fn f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    pub fn vec2(&mut self) -> glam::Vec2 {
        glam::Vec2::new(self.f32(), self.f32())
    }

    /// Uniform integer in [0, n) (n ≤ 2³²; the tiny modulo bias does not matter for the tests).
    pub fn below(&mut self, n: u64) -> u64 {
        ((self.next_u32() as u64) << 32 | self.next_u32() as u64) % n
    }
}

/// A Lambertian material of albedo `rho` emitting `le` from its front face.
pub fn lambert(rho: f32, le: f32) -> Material {
    Material {
        base_color: Vec4::new(rho, rho, rho, 1.0),
        metallic: 0.0,
        roughness: 1.0,
        specular: 0.0,
        emissive: Vec3::splat(le),
        ..Material::default()
    }
}

/// A camera at `eye` looking down −Z with a 90° vertical field of view.
pub fn camera_at(eye: Vec3) -> Camera {
    Camera::new(
        Projection::Perspective(Perspective::new(90f32.to_radians())),
        Affine3A::from_translation(eye),
    )
}

/// The closed box [-1,1]³ with its 12 triangles facing inwards (front = counter-clockwise seen from
/// inside), all of material 0.
pub fn inward_box() -> Mesh {
    let mut mesh = Mesh::default();
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    // Each face as a quad (a, b, c, d); triangles (a, b, c) and (a, c, d).
    let faces = [
        [
            c(-1., -1., -1.),
            c(-1., 1., -1.),
            c(1., 1., -1.),
            c(1., -1., -1.),
        ], // z = -1, seen from +z
        [
            c(-1., -1., 1.),
            c(1., -1., 1.),
            c(1., 1., 1.),
            c(-1., 1., 1.),
        ], // z = +1
        [
            c(-1., -1., -1.),
            c(1., -1., -1.),
            c(1., -1., 1.),
            c(-1., -1., 1.),
        ], // y = -1
        [
            c(-1., 1., -1.),
            c(-1., 1., 1.),
            c(1., 1., 1.),
            c(1., 1., -1.),
        ], // y = +1
        [
            c(-1., -1., -1.),
            c(-1., -1., 1.),
            c(-1., 1., 1.),
            c(-1., 1., -1.),
        ], // x = -1
        [
            c(1., -1., -1.),
            c(1., 1., -1.),
            c(1., 1., 1.),
            c(1., -1., 1.),
        ], // x = +1
    ];
    for [a, b, cc, d] in faces {
        for tri in [[a, b, cc], [a, cc, d]] {
            // Orient every triangle so its counter-clockwise front faces the inside.
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            let centroid = (tri[0] + tri[1] + tri[2]) / 3.0;
            mesh.positions.push(if n.dot(-centroid) > 0.0 {
                tri
            } else {
                [tri[0], tri[2], tri[1]]
            });
        }
    }
    mesh.material = vec![0; mesh.positions.len()];
    mesh
}

/// A geodesic sphere of radius `r` around the origin, `subdivisions` times subdivided icosahedron,
/// triangles facing inwards.
pub fn inward_sphere(r: f32, subdivisions: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut verts: Vec<Vec3> = [
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
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut faces: Vec<[usize; 3]> = vec![
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
    for _ in 0..subdivisions {
        let mut cache = std::collections::HashMap::new();
        let mut mid = |a: usize, b: usize, verts: &mut Vec<Vec3>| -> usize {
            *cache.entry((a.min(b), a.max(b))).or_insert_with(|| {
                verts.push(((verts[a] + verts[b]) * 0.5).normalize());
                verts.len() - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = mid(a, b, &mut verts);
            let bc = mid(b, c, &mut verts);
            let ca = mid(c, a, &mut verts);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    let mut mesh = Mesh::default();
    for [a, b, c] in faces {
        // Icosahedron faces are counter-clockwise from outside; swap to face inwards.
        mesh.positions
            .push([verts[a] * r, verts[c] * r, verts[b] * r]);
    }
    mesh.material = vec![0; mesh.positions.len()];
    mesh
}

/// The "furnace": a closed box whose walls emit `le` and reflect with albedo `rho`, camera inside.
/// Exact radiance everywhere: le / (1 − rho).
pub fn furnace_box(rho: f32, le: f32) -> Scene {
    Scene::build(SceneParts {
        mesh: inward_box(),
        materials: vec![lambert(rho, le)],
        camera: Some(camera_at(Vec3::new(0.1, -0.2, 0.3))),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

/// The furnace inside a sphere: walls of a geodesic sphere of radius 1 emit `le` and reflect with
/// albedo `rho`. Unlike the box it has no corners, so light-area sampling has bounded variance
/// (inside a sphere cos θ cos θ' / r² is constant).
pub fn furnace_sphere(rho: f32, le: f32) -> Scene {
    Scene::build(SceneParts {
        mesh: inward_sphere(1.0, 4),
        materials: vec![lambert(rho, le)],
        camera: Some(camera_at(Vec3::new(0.1, -0.2, 0.3))),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

/// A diffuse sphere of radius `r` and albedo `rho` lit by an isotropic point light of intensity `i` at
/// its centre. Exact radiance everywhere inside: ρ I / (π r² (1 − ρ)) (up to the tessellation).
pub fn sphere_with_point_light(r: f32, rho: f32, i: f32) -> Scene {
    Scene::build(SceneParts {
        mesh: inward_sphere(r, 5),
        materials: vec![lambert(rho, 0.0)],
        punctual_lights: vec![PunctualLight::Point(PointLight {
            position: Vec3::ZERO,
            intensity: Vec3::splat(i),
        })],
        camera: Some(camera_at(Vec3::new(0.05, 0.02, 0.1))),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

/// A geodesic sphere of radius 1 facing outwards, with vertex normals, spherical texture
/// coordinates and tangents along u, all of material `material`.
pub fn smooth_sphere(subdivisions: u32, material: u32) -> Mesh {
    let inward = inward_sphere(1.0, subdivisions);
    let uv = |v: Vec3| {
        glam::Vec2::new(
            0.5 + v.z.atan2(v.x) / std::f32::consts::TAU,
            v.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI,
        )
    };
    let tangent = |v: Vec3| {
        let t = Vec3::new(-v.z, 0.0, v.x).normalize_or_zero();
        let t = if t == Vec3::ZERO { Vec3::X } else { t };
        t.extend(1.0)
    };
    let mut mesh = Mesh {
        normals: Some(Vec::new()),
        uv0: Some(Vec::new()),
        tangents: Some(Vec::new()),
        ..Mesh::default()
    };
    for [a, b, c] in inward.positions {
        let tri = [a, c, b];
        mesh.positions.push(tri);
        mesh.normals
            .as_mut()
            .unwrap()
            .push(tri.map(|v| v.normalize()));
        mesh.uv0.as_mut().unwrap().push(tri.map(uv));
        mesh.tangents.as_mut().unwrap().push(tri.map(tangent));
        mesh.material.push(material);
    }
    mesh
}

/// A room (the inward box scaled by 4, grey) lit by an emissive panel under its ceiling, holding
/// twelve placements of a smooth rough-metal sphere (rotated, scaled unevenly, three mirrored) and
/// two of a cut-out quad (alpha below its cutoff: rays pass through it), kept instanced.
pub fn instanced_room() -> SceneParts {
    use glam::{DMat4, DQuat, DVec3};
    use pathfarm_tracer::geometry::Placement;
    use pathfarm_tracer::material::AlphaMode;
    let mut room = inward_box();
    for t in &mut room.positions {
        *t = t.map(|v| v * 4.0);
    }
    let panel = [
        Vec3::new(-1.0, 3.9, -1.0),
        Vec3::new(1.0, 3.9, -1.0),
        Vec3::new(1.0, 3.9, 1.0),
        Vec3::new(-1.0, 3.9, 1.0),
    ];
    // Facing down: counter-clockwise seen from below.
    room.positions.push([panel[0], panel[1], panel[2]]);
    room.positions.push([panel[0], panel[2], panel[3]]);
    room.material.extend([1, 1]);
    let metal = Material {
        base_color: Vec4::new(0.9, 0.6, 0.3, 1.0),
        metallic: 1.0,
        roughness: 0.35,
        ..Material::default()
    };
    let cut_out = Material {
        base_color: Vec4::new(0.2, 0.9, 0.2, 0.25),
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..lambert(0.5, 0.0)
    };
    let mut quad = Mesh::default();
    quad.positions.push([
        Vec3::new(-1., -1., 0.),
        Vec3::new(1., -1., 0.),
        Vec3::new(1., 1., 0.),
    ]);
    quad.positions.push([
        Vec3::new(-1., -1., 0.),
        Vec3::new(1., 1., 0.),
        Vec3::new(-1., 1., 0.),
    ]);
    quad.material.extend([3, 3]);
    let mut placements: Vec<Placement> = (0..12)
        .map(|i| {
            let f = i as f64;
            let mirror = if i % 4 == 1 { -1.0 } else { 1.0 };
            Placement {
                prototype: 0,
                to_world: DMat4::from_scale_rotation_translation(
                    DVec3::new(0.5 * mirror, 0.35 + 0.05 * (f % 3.0), 0.45),
                    DQuat::from_rotation_y(0.9 * f) * DQuat::from_rotation_z(0.4 * f),
                    DVec3::new(
                        -2.7 + 1.1 * (f % 6.0),
                        -3.0 + 1.6 * (f / 6.0).floor(),
                        -1.5 - 0.4 * (f % 4.0),
                    ),
                ),
            }
        })
        .collect();
    for x in [-1.5, 1.5] {
        placements.push(Placement {
            prototype: 1,
            to_world: DMat4::from_translation(DVec3::new(x, 0.0, 1.0)),
        });
    }
    let camera = camera_at(Vec3::new(0.0, 0.0, 3.5));
    SceneParts {
        mesh: room,
        prototypes: vec![smooth_sphere(3, 2), quad],
        placements,
        materials: vec![lambert(0.6, 0.0), lambert(0.0, 8.0), metal, cut_out],
        camera: Some(camera),
        ..SceneParts::default()
    }
}

/// Mean luminance of the image and its standard error, from the per-pixel variance estimates.
pub fn image_mean_and_stderr(acc: &Accumulation) -> (f64, f64) {
    let n = acc.pixels.len() as f64;
    let mut mean = 0.0;
    let mut var = 0.0;
    for p in &acc.pixels {
        let m = p.mean();
        mean += 0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2];
        var += p.variance_of_mean().expect("two samples per pixel");
    }
    (mean / n, (var / (n * n)).sqrt())
}

/// `../shared/` beside the repository, if present.
pub fn shared_dir() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared");
    if dir.join("README.md").exists() {
        Some(dir)
    } else {
        eprintln!("skipped: ../shared/ (beside the repository) not found");
        None
    }
}
