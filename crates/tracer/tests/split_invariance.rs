//! The accumulation of a pixel's samples is the same bits however the work is split: by sample
//! range, by tile, by thread count, and whenever it is rendered.

mod common;

use common::*;
use pathfarm_tracer::{
    render_image, render_tile, Accumulation, RenderSettings, SamplerKind, Scene, Tile,
};

fn scenes() -> Vec<(&'static str, Scene)> {
    vec![
        ("furnace box", furnace_box(0.7, 0.5)),
        ("point-lit sphere", sphere_with_point_light(1.0, 0.6, 5.0)),
        (
            "instanced room",
            Scene::build(instanced_room()).expect("scene builds"),
        ),
    ]
}

fn pixels_equal(a: &Accumulation, b: &Accumulation) -> bool {
    a.pixels == b.pixels && a.rays == b.rays && a.invalid_count == b.invalid_count
}

#[test]
fn random_partitions_of_the_sample_range_and_tiles_give_identical_bits() {
    // Deterministic random partitions: the test itself must be reproducible.
    let mut rng = Pcg32::seeded(42);
    for (name, scene) in scenes() {
        for sampler in [SamplerKind::Sobol, SamplerKind::Independent] {
            let settings = RenderSettings {
                sampler,
                seed: 99,
                ..RenderSettings::new(24, 20)
            };
            let spp = 13;
            let reference = render_image(&scene, &settings, 8, 0..spp, &|_| {});
            assert_eq!(reference.total_samples(), 24 * 20 * spp as u64);
            for trial in 0..4 {
                // Random cut points of [0, spp) and a random tile size for each piece.
                let mut cuts: Vec<u32> = (0..rng.below(5) + 1)
                    .map(|_| rng.below(spp as u64) as u32)
                    .collect();
                cuts.extend([0, spp]);
                cuts.sort_unstable();
                cuts.dedup();
                let mut pieces: Vec<Accumulation> = Vec::new();
                for w in cuts.windows(2) {
                    let tile = 1 + rng.below(13) as u32;
                    for t in Tile::grid(24, 20, tile) {
                        pieces.push(render_tile(&scene, &settings, t, w[0]..w[1]));
                    }
                }
                // Merge in a random order and grouping: pairwise merges of random pieces.
                while pieces.len() > 1 {
                    let i = rng.below(pieces.len() as u64) as usize;
                    let a = pieces.swap_remove(i);
                    let j = rng.below(pieces.len() as u64) as usize;
                    let mut b = pieces.swap_remove(j);
                    let mut merged = Accumulation::new(0, 0, 24, 20);
                    merged.merge(&a).expect("fits");
                    merged.merge(&b).expect("fits");
                    b = merged;
                    pieces.push(b);
                }
                let combined = pieces.pop().expect("one left");
                assert!(
                    pixels_equal(&combined, &reference),
                    "{name}, {sampler}, trial {trial}: cuts {cuts:?} differ"
                );
            }
        }
    }
}

#[test]
fn one_and_two_threads_give_identical_images() {
    for (name, scene) in scenes() {
        let settings = RenderSettings {
            seed: 5,
            ..RenderSettings::new(32, 24)
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| render_image(&scene, &settings, 7, 0..8, &|_| {}))
        };
        let one = run(1);
        let two = run(2);
        assert!(pixels_equal(&one, &two), "{name}: 1 and 2 threads differ");
        assert_eq!(one.mean_image(), two.mean_image());
    }
}

#[test]
fn the_same_seed_gives_the_same_bits_and_another_seed_does_not() {
    let scene = furnace_box(0.7, 0.5);
    let a = RenderSettings {
        seed: 1,
        ..RenderSettings::new(16, 16)
    };
    let b = RenderSettings {
        seed: 2,
        ..a.clone()
    };
    let r1 = render_image(&scene, &a, 16, 0..4, &|_| {});
    let r2 = render_image(&scene, &a, 5, 0..4, &|_| {});
    let r3 = render_image(&scene, &b, 16, 0..4, &|_| {});
    assert!(pixels_equal(&r1, &r2));
    assert!(
        !pixels_equal(&r1, &r3),
        "different seeds must give different samples"
    );
}

#[test]
fn the_scene_build_is_the_same_on_any_thread_count() {
    // Workers build their own BVH from the scene bytes; ties between equally distant triangles are
    // broken by triangle index, and which triangles a ray meets at all depends on the tree's
    // padded boxes, so the build must be deterministic: the same mesh, the same tree size and the
    // same hit (triangle and distance, bit for bit) for rays in every direction.
    let build = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| sphere_with_point_light(1.0, 0.5, 1.0))
    };
    let hits = |scene: &Scene| -> Vec<Option<(u32, u32)>> {
        (0..4096u32)
            .map(|k| {
                // Directions spread over the sphere (a Fibonacci lattice), from off the centre.
                let z = 1.0 - (2 * k + 1) as f32 / 4096.0;
                let phi = k as f32 * 2.399_963;
                let r = (1.0 - z * z).sqrt();
                let d = glam::Vec3::new(r * phi.cos(), r * phi.sin(), z);
                let ray = pathfarm_tracer::geometry::Ray::new(glam::Vec3::splat(0.1), d);
                scene
                    .intersect(&ray, f32::INFINITY, 0.5)
                    .map(|h| (h.triangle, h.t.to_bits()))
            })
            .collect()
    };
    let a = build(1);
    let a_hits = hits(&a);
    assert!(
        a_hits.iter().all(Option::is_some),
        "rays from inside the sphere must hit it"
    );
    for threads in [2, 3] {
        let b = build(threads);
        assert_eq!(
            a.mesh.positions, b.mesh.positions,
            "{threads} threads order the mesh differently"
        );
        assert_eq!(a.info.bvh_nodes, b.info.bvh_nodes);
        assert_eq!(a_hits, hits(&b), "{threads} threads: different hits");
    }
}
