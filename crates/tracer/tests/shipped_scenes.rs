//! The scenes committed under `scenes/` (the benchmark's and the reference scenes): every one loads
//! self-contained (no external resources) without warnings, has a camera and a light, and renders a
//! small image with no invalid samples and a positive, finite mean; and each benchmark scene has the
//! property it was made for (`examples/make_bench_scenes.rs`). The small ones render the same bits
//! whether their ray queries go to the flat 16-lane test or to the tree.

mod common;

use common::image_mean_and_stderr;
use pathfarm_tracer::gltf::{load_parts, LoadOptions, NoExternalResources};
use pathfarm_tracer::math::luminance;
use pathfarm_tracer::{render_image, DirectStrategy, RenderSettings, SamplerKind, Scene};
use std::path::PathBuf;

/// The repository's `scenes/` directory.
fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

/// Every `*.gltf` in `scenes/`, by name, sorted.
fn shipped() -> Vec<(String, Vec<u8>)> {
    let dir = scenes_dir();
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            e.expect("directory entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.ends_with(".gltf"))
        .collect();
    names.sort();
    names
        .into_iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).expect("readable scene");
            (n, bytes)
        })
        .collect()
}

/// Loads `bytes` with the server's resolver (embedded data only); asserts a camera and no warnings.
fn load(name: &str, bytes: &[u8]) -> Scene {
    let parts = load_parts(bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(parts.camera.is_some(), "{name}: no camera");
    assert!(
        parts.warnings.is_empty(),
        "{name}: warnings {:?}",
        parts.warnings
    );
    let scene = Scene::build(parts).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(
        scene.info.degenerate_dropped, 0,
        "{name}: degenerate triangles"
    );
    scene
}

/// Total area of the emissive triangles.
fn light_area(scene: &Scene) -> f32 {
    scene
        .lights
        .area
        .triangles
        .iter()
        .map(|&t| scene.mesh.area(t as usize))
        .sum()
}

/// Total emitted power (luminance) of the area lights.
fn light_power(scene: &Scene) -> f32 {
    scene
        .lights
        .area
        .triangles
        .iter()
        .map(|&t| {
            let m = &scene.materials[scene.mesh.material[t as usize] as usize];
            let sides = if m.double_sided { 2.0 } else { 1.0 };
            sides * luminance(m.emissive) * scene.mesh.area(t as usize) * std::f32::consts::PI
        })
        .sum()
}

fn scene(name: &str) -> Scene {
    let bytes = std::fs::read(scenes_dir().join(name)).expect("readable scene");
    load(name, &bytes)
}

#[test]
fn every_shipped_scene_loads_and_renders() {
    let scenes = shipped();
    let names: Vec<&str> = scenes.iter().map(|(n, _)| n.as_str()).collect();
    for expected in [
        "caustics.gltf",
        "cornell.gltf",
        "furnace.gltf",
        "furnacebox.gltf",
        "glossy.gltf",
        "smalllight.gltf",
        "textured.gltf",
    ] {
        assert!(
            names.contains(&expected),
            "{expected} missing from {names:?}"
        );
    }
    for (name, bytes) in &scenes {
        let scene = load(name, bytes);
        assert!(
            scene.info.emissive_triangles + scene.info.punctual_lights > 0,
            "{name}: no light"
        );
        let settings = RenderSettings::new(16, 16);
        let image = render_image(&scene, &settings, 16, 0..4, &|_| {});
        assert_eq!(image.invalid_count, 0, "{name}: invalid samples");
        assert!(image.pixels.iter().all(|p| p.count == 4), "{name}");
        let (mean, stderr) = image_mean_and_stderr(&image);
        assert!(
            mean.is_finite() && mean > 0.0 && stderr.is_finite(),
            "{name}: image mean {mean} ± {stderr}"
        );
    }
}

#[test]
fn smalllight_has_one_tiny_light_as_powerful_as_the_cornell_box_light() {
    let scene = scene("smalllight.gltf");
    let size = scene.info.bounds_max - scene.info.bounds_min;
    let largest_face = (size.x * size.y).max(size.y * size.z).max(size.z * size.x);
    let area = light_area(&scene);
    assert_eq!(scene.info.emissive_triangles, 2);
    assert_eq!(scene.info.punctual_lights, 0);
    assert!(
        area > 0.0 && area < 1e-3 * largest_face,
        "light area {area} against the largest face {largest_face}"
    );
    // Its power matches the Cornell box light's (so the images are about as bright).
    let cornell = light_power(&self::scene("cornell.gltf"));
    let power = light_power(&scene);
    assert!(
        (power / cornell - 1.0).abs() < 0.01,
        "power {power} against the Cornell box light's {cornell}"
    );
}

#[test]
fn caustics_has_a_glass_volume_and_a_mirror() {
    let scene = scene("caustics.gltf");
    assert!(
        scene.materials.iter().any(|m| m.transmission == 1.0
            && m.roughness == 0.0
            && m.metallic == 0.0
            && m.ior == 1.5
            && m.volume.is_some()),
        "no refracting glass volume: {:?}",
        scene.materials
    );
    assert!(
        scene
            .materials
            .iter()
            .any(|m| m.metallic == 1.0 && m.roughness == 0.0 && m.transmission == 0.0),
        "no mirror: {:?}",
        scene.materials
    );
    assert!(scene.mesh.normals.is_some(), "the spheres are smooth");
}

#[test]
fn glossy_has_a_glossy_metal() {
    let scene = scene("glossy.gltf");
    assert!(
        scene
            .materials
            .iter()
            .any(|m| m.metallic == 1.0 && (0.15..=0.25).contains(&m.roughness)),
        "no glossy metal: {:?}",
        scene.materials
    );
}

#[test]
fn textured_has_color_normal_and_metallic_roughness_textures() {
    let scene = scene("textured.gltf");
    assert!(!scene.textures.is_empty());
    assert!(
        scene
            .materials
            .iter()
            .any(|m| m.base_color_texture.is_some()
                && m.normal_texture.is_some()
                && m.metallic_roughness_texture.is_some()),
        "no material with color, normal and metallic-roughness textures"
    );
    assert!(scene.mesh.uv0.is_some() && scene.mesh.tangents.is_some());
}

/// A farm mixes processors: on one with AVX-512F a scene of at most 64 triangles is tested without
/// its BVH (`geometry/bvh/flat.rs`), on one with AVX2 a scene of at most 32, and elsewhere the tree
/// answers. Both must render the same
/// bits, for every direct-lighting strategy and sampler.
#[test]
fn small_scenes_render_the_same_bits_with_the_flat_test_and_with_the_tree() {
    let mut compared = Vec::new();
    for (name, bytes) in shipped() {
        let flat = load(&name, &bytes);
        if !flat.bvh.is_flat() {
            continue;
        }
        let mut tree = load(&name, &bytes);
        tree.bvh = (*tree.bvh).clone().tree_only().into();
        assert!(!tree.bvh.is_flat());
        for direct in DirectStrategy::ALL {
            for sampler in [SamplerKind::Sobol, SamplerKind::Independent] {
                let settings = RenderSettings {
                    direct,
                    sampler,
                    seed: 11,
                    ..RenderSettings::new(24, 20)
                };
                let a = render_image(&flat, &settings, 8, 0..4, &|_| {});
                let b = render_image(&tree, &settings, 8, 0..4, &|_| {});
                assert!(a.rays > 0);
                assert!(
                    a.pixels == b.pixels && a.rays == b.rays,
                    "{name}, {direct:?}, {sampler:?}: the flat test and the tree differ"
                );
            }
        }
        compared.push(name);
    }
    if compared.is_empty() {
        eprintln!(
            "SKIPPED: this processor has neither AVX-512F nor AVX2, so every scene uses its tree"
        );
    } else {
        // cornell.gltf (32 triangles) and furnacebox.gltf (12) everywhere, smalllight.gltf (34)
        // with AVX-512F only.
        let names: Vec<&str> = compared.iter().map(String::as_str).collect();
        assert!(
            names.contains(&"cornell.gltf") && names.contains(&"furnacebox.gltf"),
            "flat scenes: {compared:?}"
        );
        assert!(compared.len() <= 3, "flat scenes: {compared:?}");
    }
}
