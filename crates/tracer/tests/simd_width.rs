//! The BVH's leaf test runs 4 lanes wide (SSE2) or, where the processor has AVX2, 8 lanes wide
//! (`geometry::simd`). The choice must change speed only: every shipped scene, and a generated mesh
//! of many small triangles whose leaves hold two packets, renders the same bits either way.
//!
//! Its own test binary (its own process), because the width is a process-wide switch.

use pathfarm_tracer::geometry::{simd, Mesh};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::{render_image, Accumulation, DirectStrategy, RenderSettings, Scene};
use std::path::PathBuf;
use std::sync::Mutex;

/// Held by each test while it switches the width, so the tests of this binary (run on parallel
/// threads) do not switch it under each other.
static SWITCH: Mutex<()> = Mutex::new(());

fn shipped() -> Vec<(String, Scene)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".gltf"))
        .collect();
    names.sort();
    names
        .into_iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).expect("readable scene");
            let scene = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())
                .unwrap_or_else(|e| panic!("{n}: {e}"));
            (n, scene)
        })
        .collect()
}

fn render(scene: &Scene, direct: DirectStrategy) -> Accumulation {
    let settings = RenderSettings {
        seed: 3,
        direct,
        ..RenderSettings::new(40, 30)
    };
    render_image(scene, &settings, 16, 0..6, &|_| {})
}

#[test]
fn four_and_eight_lane_leaf_tests_render_the_same_bits() {
    if !simd::has_avx2() {
        eprintln!("SKIPPED: this processor has no AVX2, so only the 4-lane test exists here");
        return;
    }
    let _switch = SWITCH.lock().unwrap_or_else(|e| e.into_inner());
    let scenes = shipped();
    assert!(scenes.len() >= 5, "{} shipped scenes", scenes.len());
    let mut compared = 0;
    for (name, scene) in &scenes {
        for direct in [DirectStrategy::Mis, DirectStrategy::Bsdf] {
            simd::set_wide(false);
            let narrow = render(scene, direct);
            simd::set_wide(true);
            assert!(simd::wide());
            let wide = render(scene, direct);
            assert_eq!(
                narrow.rays, wide.rays,
                "{name}, {direct}: ray counts differ"
            );
            assert!(narrow.rays > 0, "{name}: nothing traced");
            assert!(
                narrow.pixels == wide.pixels,
                "{name}, {direct}: the 4- and 8-lane leaf tests give different images"
            );
            compared += 1;
        }
    }
    assert_eq!(compared, 2 * scenes.len());
}

/// A mesh of many small triangles: leaves of up to eight triangles (two packets), so the 8-lane
/// test runs on most leaves, against the 4-lane test on the same tree.
#[test]
fn a_dense_mesh_gives_the_same_closest_hits_with_either_width() {
    if !simd::has_avx2() {
        eprintln!("SKIPPED: this processor has no AVX2, so only the 4-lane test exists here");
        return;
    }
    let _switch = SWITCH.lock().unwrap_or_else(|e| e.into_inner());
    let mut mesh = Mesh::default();
    // A 64×64 height field of 8,192 triangles with shared edges (watertightness matters there).
    let n = 64;
    let h = |i: u32, j: u32| ((i * 7 + j * 13) % 17) as f32 * 0.01;
    let p = |i: u32, j: u32| glam::Vec3::new(i as f32 / n as f32, h(i, j), j as f32 / n as f32);
    for i in 0..n {
        for j in 0..n {
            mesh.positions.push([p(i, j), p(i, j + 1), p(i + 1, j)]);
            mesh.positions
                .push([p(i + 1, j), p(i, j + 1), p(i + 1, j + 1)]);
        }
    }
    mesh.material = vec![0; mesh.positions.len()];
    let (bvh, order) = pathfarm_tracer::geometry::Bvh::build(&mesh);
    mesh.reorder(&order);
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut hits = 0;
    for _ in 0..20_000 {
        let o = glam::Vec3::new(next() * 1.4 - 0.2, 0.5 + next(), next() * 1.4 - 0.2);
        let target = glam::Vec3::new(next(), 0.0, next());
        let d = (target - o).normalize();
        let pre =
            pathfarm_tracer::geometry::RayPrecomp::new(&pathfarm_tracer::geometry::Ray::new(o, d));
        simd::set_wide(false);
        let narrow = bvh.closest(&pre, d, f32::INFINITY, |_, _| true);
        let narrow_any = bvh.any(&pre, d, 1.0, |_, _| true);
        simd::set_wide(true);
        let wide = bvh.closest(&pre, d, f32::INFINITY, |_, _| true);
        let wide_any = bvh.any(&pre, d, 1.0, |_, _| true);
        assert_eq!(narrow, wide, "ray {o} {d}");
        assert_eq!(narrow_any, wide_any, "ray {o} {d}");
        hits += narrow.is_some() as u32;
    }
    assert!(hits > 15_000, "{hits} hits: the rays miss the mesh");
}
