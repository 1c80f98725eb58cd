//! Tracer micro-benchmarks: BVH build, ray throughput, BSDF sampling and accumulation merging.
//!
//! ```text
//! cargo bench -p pathfarm-tracer --bench tracer [-- FILTER]
//! ```
//!
//! - `bvh_build`: `Scene::build` of the Cornell box plus a displaced sphere of 327,680 triangles
//!   (the scene `examples/make_scenes.rs` writes as `cornell_sphere.glb`, generated in memory).
//! - `rays`: closest-hit (`Scene::intersect`) and shadow (`Scene::visible`) rays, single-threaded,
//!   on the Cornell box and on the 330k scene. One fixed batch of 65,536 rays from random points in
//!   the air inside the box: closest-hit rays in uniformly random directions, shadow rays towards
//!   random points of the ceiling light (t_max = distance · (1 − 10⁻⁴), as the integrator does).
//! - `flat_vs_tree`: the same rays against the Cornell box's 32 triangles, and against the box
//!   with a 20-triangle sphere, through `Bvh` directly, answered by the flat test of every triangle
//!   (`geometry/bvh/flat.rs`, on a processor with AVX-512F or AVX2) and by the 4-wide tree
//!   (`Bvh::tree_only`): a closest-hit and a shadow query per element.
//! - `bsdf`: `Bsdf::sample` followed by `Bsdf::eval` of the sampled direction, for a batch of 1,024
//!   random outgoing directions, for a diffuse, a rough-metal and a smooth-glass material.
//! - `accumulation`: `Accumulation::merge` of one 256×256 accumulation into another.
//!
//! Throughputs are in elements (rays, BSDF samples, pixels) per second.

#[path = "../examples/scene_gen/mod.rs"]
mod scene_gen;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use glam::{Vec2, Vec3};
use pathfarm_tracer::bsdf::{Bsdf, PbrParams};
use pathfarm_tracer::geometry::{Bvh, Ray, RayPrecomp};
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{Accumulation, Scene};
use std::hint::black_box;
use std::time::Duration;

const RAYS: usize = 65_536;
const BSDF_BATCH: usize = 1_024;
const SHADOW_EPSILON: f32 = 1e-4;

/// SplitMix64: a small deterministic generator, so every run traces the same rays.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    fn unit_vector(&mut self) -> Vec3 {
        let z = 1.0 - 2.0 * self.f32();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * self.f32();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// A point in the air inside the Cornell box: not inside the blocks' bounding boxes nor the sphere's
/// bounding ball (the same points for both scenes).
fn air_point(rng: &mut Rng) -> Vec3 {
    // Axis-aligned bounds of the (rotated) blocks, from cornell.gltf's accessors.
    const BLOCKS: [(Vec3, Vec3); 2] = [
        (Vec3::new(0.82, 0.0, 0.65), Vec3::new(2.90, 1.65, 2.72)),
        (Vec3::new(2.65, 0.0, 2.47), Vec3::new(4.72, 3.30, 4.56)),
    ];
    let r = scene_gen::SPHERE_RADIUS * (1.0 + scene_gen::DISPLACEMENT);
    let [cx, cz] = scene_gen::SPHERE_CENTER_XZ;
    let sphere_center = Vec3::new(cx, r, cz);
    loop {
        let p = Vec3::new(
            rng.range(0.05, 5.45),
            rng.range(0.05, 5.43),
            rng.range(0.05, 5.50),
        );
        let in_block = BLOCKS
            .iter()
            .any(|(lo, hi)| p.cmpge(*lo).all() && p.cmple(*hi).all());
        if !in_block && p.distance(sphere_center) > r + 0.02 {
            return p;
        }
    }
}

struct RayBatch {
    closest: Vec<Ray>,
    /// Shadow rays with their t_max.
    shadow: Vec<(Ray, f32)>,
}

fn ray_batch() -> RayBatch {
    let mut rng = Rng(0x005E_ED0F_7AC3);
    let mut closest = Vec::with_capacity(RAYS);
    let mut shadow = Vec::with_capacity(RAYS);
    for _ in 0..RAYS {
        let o = air_point(&mut rng);
        closest.push(Ray::new(o, rng.unit_vector()));
        // The ceiling light of cornell.gltf: x 2.13..3.43, z 2.27..3.32, at y = 5.483.
        let target = Vec3::new(rng.range(2.13, 3.43), 5.483, rng.range(2.27, 3.32));
        let d = target - o;
        let dist = d.length();
        shadow.push((Ray::new(o, d / dist), dist * (1.0 - SHADOW_EPSILON)));
    }
    RayBatch { closest, shadow }
}

fn sphere_scene_parts() -> SceneParts {
    scene_gen::cornell_with(&scene_gen::bench_sphere(scene_gen::FREQ_330K))
}

fn bvh_build(c: &mut Criterion) {
    let parts = sphere_scene_parts();
    let mut group = c.benchmark_group("bvh_build");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(8));
    group.throughput(Throughput::Elements(parts.mesh.len() as u64));
    group.bench_function("cornell_sphere_330k", |b| {
        b.iter_batched(
            || parts.clone(),
            |parts| Scene::build(parts).expect("scene builds"),
            BatchSize::PerIteration,
        )
    });
    group.finish();
}

fn rays(c: &mut Criterion) {
    let batch = ray_batch();
    let scenes = [
        (
            "cornell",
            Scene::build(scene_gen::cornell_parts()).expect("scene builds"),
        ),
        (
            "cornell_sphere_330k",
            Scene::build(sphere_scene_parts()).expect("scene builds"),
        ),
    ];
    let mut group = c.benchmark_group("rays");
    group.throughput(Throughput::Elements(RAYS as u64));
    for (name, scene) in &scenes {
        // Hit and occlusion rates, for the record.
        let hits = batch
            .closest
            .iter()
            .filter(|r| scene.intersect(r, f32::INFINITY, 0.5).is_some())
            .count();
        let visible = batch
            .shadow
            .iter()
            .filter(|(r, t)| scene.visible(r, *t, 0.5))
            .count();
        eprintln!(
            "rays/{name}: {} triangles, closest-hit rays hitting {:.1} %, shadow rays unoccluded {:.1} %",
            scene.info.triangles,
            100.0 * hits as f64 / RAYS as f64,
            100.0 * visible as f64 / RAYS as f64
        );
        group.bench_function(format!("{name}/closest"), |b| {
            b.iter(|| {
                let mut sum = 0.0f32;
                for ray in &batch.closest {
                    if let Some(hit) = scene.intersect(black_box(ray), f32::INFINITY, 0.5) {
                        sum += hit.t;
                    }
                }
                sum
            })
        });
        group.bench_function(format!("{name}/shadow"), |b| {
            b.iter(|| {
                let mut n = 0u32;
                for (ray, t_max) in &batch.shadow {
                    n += scene.visible(black_box(ray), *t_max, 0.5) as u32;
                }
                n
            })
        });
        // A closest-hit ray and a shadow ray per element, as the integrator traces them at a path
        // vertex: one after the other, and together (the two walks interleaved).
        group.bench_function(format!("{name}/closest_then_shadow"), |b| {
            b.iter(|| {
                let (mut sum, mut n) = (0.0f32, 0u32);
                for (ray, (shadow, t_max)) in batch.closest.iter().zip(&batch.shadow) {
                    if let Some(hit) = scene.intersect(black_box(ray), f32::INFINITY, 0.5) {
                        sum += hit.t;
                    }
                    n += scene.visible(black_box(shadow), *t_max, 0.5) as u32;
                }
                (sum, n)
            })
        });
        group.bench_function(format!("{name}/closest_and_shadow"), |b| {
            b.iter(|| {
                let (mut sum, mut n) = (0.0f32, 0u32);
                for (ray, (shadow, t_max)) in batch.closest.iter().zip(&batch.shadow) {
                    let (hit, visible) = scene.intersect_and_visible(
                        black_box(ray),
                        0.5,
                        black_box(shadow),
                        *t_max,
                        0.5,
                    );
                    if let Some(hit) = hit {
                        sum += hit.t;
                    }
                    n += visible as u32;
                }
                (sum, n)
            })
        });
    }
    group.finish();
}

fn flat_vs_tree(c: &mut Criterion) {
    let batch = ray_batch();
    let queries: Vec<(RayPrecomp, Vec3, RayPrecomp, Vec3, f32)> = batch
        .closest
        .iter()
        .zip(&batch.shadow)
        .map(|(ray, (shadow, t_max))| {
            let (a, b) = (RayPrecomp::new(ray), RayPrecomp::new(shadow));
            (a, ray.d, b, shadow.d, *t_max)
        })
        .collect();
    let mut group = c.benchmark_group("flat_vs_tree");
    group.throughput(Throughput::Elements(RAYS as u64));
    // The box alone (32 triangles), and with the coarsest sphere (20 more): where the flat test's
    // cost, linear in the triangles, meets the tree's.
    let meshes = [
        ("cornell", scene_gen::cornell_parts().mesh),
        (
            "cornell_ico",
            scene_gen::cornell_with(&scene_gen::bench_sphere(1)).mesh,
        ),
    ];
    for (scene, mesh) in meshes {
        let bvh = Bvh::build(&mesh);
        eprintln!(
            "flat_vs_tree: {scene}, {} triangles, flat test {}",
            mesh.len(),
            if bvh.is_flat() {
                "in use"
            } else {
                "not available (no AVX2 or too many triangles): both rows are the tree"
            }
        );
        for (name, bvh) in [("flat", bvh.clone()), ("tree", bvh.tree_only())] {
            group.bench_function(format!("{scene}/{name}"), |b| {
                b.iter(|| {
                    let (mut sum, mut n) = (0.0f32, 0u32);
                    for (a, da, s, ds, t_max) in &queries {
                        if let Some((_, hit)) =
                            bvh.closest(black_box(a), *da, f32::INFINITY, |_, _| true)
                        {
                            sum += hit.t;
                        }
                        n += bvh.any(black_box(s), *ds, *t_max, |_, _| true) as u32;
                    }
                    (sum, n)
                })
            });
        }
    }
    group.finish();
}

fn bsdf(c: &mut Criterion) {
    let white = Vec3::new(0.8, 0.8, 0.8);
    let configs = [
        ("diffuse", PbrParams::diffuse(Vec3::from(scene_gen::WHITE))),
        (
            "rough_metal",
            PbrParams {
                metallic: 1.0,
                roughness: 0.4,
                specular: 1.0,
                ..PbrParams::diffuse(Vec3::new(0.95, 0.64, 0.54))
            },
        ),
        (
            "glass",
            PbrParams {
                roughness: 0.0,
                specular: 1.0,
                ior: 1.5,
                transmission: 1.0,
                thin_walled: false,
                ..PbrParams::diffuse(white)
            },
        ),
    ];
    // A slightly tilted surface; outgoing directions uniform over its upper hemisphere.
    let n = Vec3::new(0.3, 0.2, 0.93).normalize();
    let mut rng = Rng(0xB5DF);
    let inputs: Vec<(Vec3, f32, Vec2)> = (0..BSDF_BATCH)
        .map(|_| {
            let mut wo = rng.unit_vector();
            if wo.dot(n) < 0.0 {
                wo = -wo;
            }
            (wo, rng.f32(), Vec2::new(rng.f32(), rng.f32()))
        })
        .collect();
    let mut group = c.benchmark_group("bsdf");
    group.throughput(Throughput::Elements(BSDF_BATCH as u64));
    for (name, params) in configs {
        let bsdf = Bsdf::new(params, n, n, None);
        group.bench_function(format!("{name}/sample_eval"), |b| {
            b.iter(|| {
                let bsdf = black_box(&bsdf);
                let mut sum = Vec3::ZERO;
                for &(wo, u_lobe, u) in &inputs {
                    if let Some(s) = bsdf.sample(wo, u_lobe, u) {
                        sum += s.weight + bsdf.eval(wo, s.wi);
                    }
                }
                sum
            })
        });
    }
    group.finish();
}

fn accumulation(c: &mut Criterion) {
    let (w, h) = (256u32, 256u32);
    let mut rng = Rng(0xACC);
    let mut filled = || {
        let mut acc = Accumulation::new(0, 0, w, h);
        for p in &mut acc.pixels {
            for _ in 0..4 {
                p.add_sample(Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 4.0);
            }
        }
        acc.rays = 123_456;
        acc
    };
    let mut into = filled();
    let other = filled();
    let mut group = c.benchmark_group("accumulation");
    group.throughput(Throughput::Elements((w * h) as u64));
    // Sums keep growing across iterations; u128 fixed point cannot overflow in any realistic run.
    group.bench_function("merge_256x256", |b| {
        b.iter(|| into.merge(black_box(&other)).expect("same size"))
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(3));
    targets = bvh_build, rays, flat_vs_tree, bsdf, accumulation
}
criterion_main!(benches);
