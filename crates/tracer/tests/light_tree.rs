//! Many emitters choose by the light tree (`light::tree`): the image is the same, within its noise,
//! as the one BSDF sampling alone renders (which never chooses a light), for light sampling alone
//! and for MIS, with one-sided and two-sided emitters of different powers, some facing away from
//! everything they could light. Many punctual lamps (a lit street: points, spots, some pointing
//! away, and a sun) likewise: the same image as choosing them by power, with less noise, also on
//! the street Blender exports (`scenes/suite/lit_street.glb`, `make_street.py`). A few lamps, chosen
//! at each point by what each sends there: the same image as by power, with less noise.

mod common;

use common::*;
use glam::Vec3;
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::light::{DirectionalLight, PointLight, PunctualLight, SpotLight};
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{render_image, DirectStrategy, RenderSettings, Scene};

/// A 6 m floor under 100 small square emitters 0.6 to 1.4 m above it: most face down
/// (one-sided, material 1), every seventh emits from both faces and ten times brighter (material
/// 2), every fifth faces up, lighting nothing. The camera, below the lights, sees the floor alone:
/// the image is the light the floor gets, whose noise is the light choice's.
fn many_lights() -> Scene {
    let mut mesh = Mesh::default();
    let mut quad = |c: Vec3, half: f32, up: bool, material: u32| {
        let [a, b, cc, d] = [
            c + Vec3::new(-half, -half, 0.0),
            c + Vec3::new(half, -half, 0.0),
            c + Vec3::new(half, half, 0.0),
            c + Vec3::new(-half, half, 0.0),
        ];
        // Counter-clockwise seen from the side it faces.
        let tris = if up {
            [[a, b, cc], [a, cc, d]]
        } else {
            [[a, cc, b], [a, d, cc]]
        };
        for t in tris {
            mesh.positions.push(t);
            mesh.material.push(material);
        }
    };
    quad(Vec3::ZERO, 3.0, true, 0);
    let mut rng = Pcg32::seeded(5);
    for k in 0..100 {
        let c = Vec3::new(
            rng.f32() * 5.0 - 2.5,
            rng.f32() * 5.0 - 2.5,
            0.6 + 0.8 * rng.f32(),
        );
        let material = if k % 7 == 0 { 2 } else { 1 };
        quad(c, 0.12, k % 5 == 0, material);
    }
    let mut two_sided = lambert(0.0, 20.0);
    two_sided.double_sided = true;
    Scene::build(SceneParts {
        mesh,
        materials: vec![lambert(0.6, 0.0), lambert(0.0, 2.0), two_sided],
        camera: Some(camera_at(Vec3::new(0.3, -0.2, 0.5))),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

/// Image mean and standard error of `scene` rendered at 32 × 32 with `spp` samples.
fn render(scene: &Scene, direct: DirectStrategy, spp: u32) -> (f64, f64) {
    let settings = RenderSettings {
        direct,
        seed: 11,
        ..RenderSettings::new(32, 32)
    };
    let acc = render_image(scene, &settings, 16, 0..spp, &|_| {});
    assert_eq!(acc.invalid_count, 0);
    image_mean_and_stderr(&acc)
}

#[test]
fn light_sampling_by_the_tree_converges_to_what_bsdf_sampling_sees() {
    let scene = many_lights();
    assert!(scene.lights.area.has_tree(), "200 light triangles: a tree");
    let (reference, se_ref) = render(&scene, DirectStrategy::Bsdf, 256);
    assert!(se_ref < 0.02 * reference, "reference too noisy: {se_ref}");
    for direct in [DirectStrategy::Mis, DirectStrategy::Light] {
        let (mean, se) = render(&scene, direct, 64);
        let z = (mean - reference) / (se * se + se_ref * se_ref).sqrt();
        eprintln!(
            "{}: {mean:.5} ± {se:.5} against {reference:.5} ± {se_ref:.5}: z = {z:+.2}",
            direct.name()
        );
        assert!(z.abs() < 3.5, "{}: z = {z:.2}", direct.name());
        // The tree puts light samples where they count: less noise than BSDF sampling at a
        // quarter of the samples.
        assert!(
            se < se_ref,
            "{}: {se} against BSDF sampling's {se_ref}",
            direct.name()
        );
    }
}

/// The same lights chosen by power alone: the same image, with more noise (most power-chosen
/// samples go to lights far off or facing away).
#[test]
fn the_tree_has_less_noise_than_choosing_by_power() {
    let tree = many_lights();
    let mut power = many_lights();
    power.lights.area.choose_by_power();
    for direct in [DirectStrategy::Mis, DirectStrategy::Light] {
        let (m_tree, se_tree) = render(&tree, direct, 64);
        let (m_power, se_power) = render(&power, direct, 64);
        let z = (m_tree - m_power) / (se_tree * se_tree + se_power * se_power).sqrt();
        eprintln!(
            "{}: tree {m_tree:.5} ± {se_tree:.5}, power {m_power:.5} ± {se_power:.5}: z = {z:+.2}",
            direct.name()
        );
        assert!(z.abs() < 3.5, "{}: z = {z:.2}", direct.name());
        assert!(
            se_tree < 0.8 * se_power,
            "{}: tree {se_tree} against power {se_power}",
            direct.name()
        );
    }
}

/// A 40 m street (a floor) under 96 lamps 4 m up in two rows: points of different intensities,
/// every third a spot pointing down (every ninth pointing up, lighting nothing), and a dim sun.
/// The camera looks down at a stretch of it: most lamps are far from what it sees.
fn lit_street() -> Scene {
    let mut mesh = Mesh::default();
    let (a, b, c, d) = (
        Vec3::new(-20.0, -4.0, 0.0),
        Vec3::new(20.0, -4.0, 0.0),
        Vec3::new(20.0, 4.0, 0.0),
        Vec3::new(-20.0, 4.0, 0.0),
    );
    for t in [[a, b, c], [a, c, d]] {
        mesh.positions.push(t);
        mesh.material.push(0);
    }
    let mut lamps = Vec::new();
    for k in 0..96 {
        let position = Vec3::new(
            -19.5 + (k / 2) as f32 * 0.8,
            if k % 2 == 0 { -3.0 } else { 3.0 },
            4.0,
        );
        let intensity = Vec3::splat(20.0 + (k % 5) as f32 * 10.0);
        lamps.push(if k % 3 == 0 {
            PunctualLight::Spot(SpotLight {
                position,
                direction: if k % 9 == 0 { Vec3::Z } else { -Vec3::Z },
                intensity: intensity * 3.0,
                cos_inner: 0.85,
                cos_outer: 0.6,
            })
        } else {
            PunctualLight::Point(PointLight {
                position,
                intensity,
            })
        });
    }
    lamps.push(PunctualLight::Directional(DirectionalLight {
        direction: Vec3::new(0.2, 0.3, -1.0).normalize(),
        illuminance: Vec3::splat(0.5),
    }));
    // Looking straight down (a camera looks along −z) at a 6 m stretch of the street.
    let camera = camera_at(Vec3::new(1.0, 0.0, 3.0));
    Scene::build(SceneParts {
        mesh,
        materials: vec![lambert(0.6, 0.0)],
        punctual_lights: lamps,
        camera: Some(camera),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

#[test]
fn many_lamps_choose_by_the_tree_with_the_image_of_choosing_by_power_and_less_noise() {
    let tree = lit_street();
    assert!(tree.lights.punctual_tree.is_some(), "96 lamps: a tree");
    let mut power = lit_street();
    power.lights.choose_punctual_by_power();
    // Lamps are reached by their own sample whatever the strategy: one is enough.
    let (m_tree, se_tree) = render(&tree, DirectStrategy::Mis, 64);
    let (m_power, se_power) = render(&power, DirectStrategy::Mis, 64);
    let z = (m_tree - m_power) / (se_tree * se_tree + se_power * se_power).sqrt();
    eprintln!("tree {m_tree:.5} ± {se_tree:.5}, power {m_power:.5} ± {se_power:.5}: z = {z:+.2}");
    assert!(m_tree > 0.0);
    assert!(z.abs() < 3.5, "z = {z:.2}");
    assert!(
        se_tree < 0.8 * se_power,
        "tree {se_tree} against power {se_power}"
    );
}

/// The street Blender exports (97 lamps: points on posts, spots over the road and up the walls, a
/// moon; lit windows): its lamps are chosen by the tree, with the image of choosing them by power
/// and less noise.
#[test]
fn the_blender_street_chooses_its_lamps_by_the_tree() {
    use pathfarm_tracer::gltf::{load, LoadOptions, NoExternalResources};
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/suite/lit_street.glb");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let tree =
        load(&bytes, &NoExternalResources, &LoadOptions::default()).expect("the street loads");
    assert_eq!(tree.lights.punctual.len(), 97);
    assert!(
        tree.lights.punctual_tree.is_some(),
        "96 point and spot lamps: a tree"
    );
    let mut power = tree.clone();
    power.lights.choose_punctual_by_power();
    let (m_tree, se_tree) = render(&tree, DirectStrategy::Mis, 64);
    let (m_power, se_power) = render(&power, DirectStrategy::Mis, 64);
    let z = (m_tree - m_power) / (se_tree * se_tree + se_power * se_power).sqrt();
    eprintln!(
        "street: tree {m_tree:.5} ± {se_tree:.5}, power {m_power:.5} ± {se_power:.5}: z = {z:+.2}"
    );
    assert!(z.abs() < 3.5, "z = {z:.2}");
    assert!(
        se_tree < 0.8 * se_power,
        "tree {se_tree} against power {se_power}"
    );
}

/// A floor lit by a few lamps of every kind (`light::chooses_per_point`): a point lamp, a spot
/// on part of the floor, a spot pointing away, a bright lamp below the floor, and a sun. Chosen
/// at each point by what each lamp sends there, the image is the one of choosing them by power,
/// with much less noise (spot, lamp below and the far side of the cone take no samples).
fn few_lamps() -> Scene {
    let mut mesh = Mesh::default();
    let (a, b, c, d) = (
        Vec3::new(-3.0, -3.0, 0.0),
        Vec3::new(3.0, -3.0, 0.0),
        Vec3::new(3.0, 3.0, 0.0),
        Vec3::new(-3.0, 3.0, 0.0),
    );
    for t in [[a, b, c], [a, c, d]] {
        mesh.positions.push(t);
        mesh.material.push(0);
    }
    let lamps = vec![
        PunctualLight::Point(PointLight {
            position: Vec3::new(-1.0, 0.5, 1.5),
            intensity: Vec3::new(3.0, 2.5, 2.0),
        }),
        PunctualLight::Spot(SpotLight {
            position: Vec3::new(1.0, -0.5, 2.0),
            direction: Vec3::new(0.1, 0.2, -1.0).normalize(),
            intensity: Vec3::new(30.0, 20.0, 10.0),
            cos_inner: 0.97,
            cos_outer: 0.9,
        }),
        PunctualLight::Spot(SpotLight {
            position: Vec3::new(0.0, 0.0, 2.0),
            direction: Vec3::Z,
            intensity: Vec3::splat(50.0),
            cos_inner: 0.9,
            cos_outer: 0.7,
        }),
        PunctualLight::Point(PointLight {
            position: Vec3::new(0.0, 0.0, -1.0),
            intensity: Vec3::splat(200.0),
        }),
        PunctualLight::Directional(DirectionalLight {
            direction: Vec3::new(0.3, 0.2, -1.0).normalize(),
            illuminance: Vec3::new(0.3, 0.35, 0.4),
        }),
    ];
    Scene::build(SceneParts {
        mesh,
        materials: vec![lambert(0.6, 0.0)],
        punctual_lights: lamps,
        camera: Some(camera_at(Vec3::new(0.0, 0.0, 3.0))),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

/// Per-point choice (`per point`, 64 spp) against power (`power_spp`) on `scene`: the same mean
/// within the noise, and a standard error below `ratio` × power's at the same samples.
fn per_point_against_power(name: &str, per_point: &Scene, power_spp: u32, ratio: f64) {
    assert!(per_point.lights.punctual_per_point, "{name}: a few lamps");
    let mut power = per_point.clone();
    power.lights.choose_punctual_by_power();
    let (m_pp, se_pp) = render(per_point, DirectStrategy::Mis, 64);
    let (m_power, se_power) = render(&power, DirectStrategy::Mis, power_spp);
    let z = (m_pp - m_power) / (se_pp * se_pp + se_power * se_power).sqrt();
    // Power's error at 64 spp, as it falls with the square root of the samples.
    let se_power_64 = se_power * (f64::from(power_spp) / 64.0).sqrt();
    eprintln!(
        "{name}: per point {m_pp:.5} ± {se_pp:.5}, power at {power_spp} spp {m_power:.5} ± \
         {se_power:.5}: z = {z:+.2}; at 64 spp power's error is {se_power_64:.5}"
    );
    assert!(m_pp > 0.0);
    assert!(z.abs() < 3.5, "{name}: z = {z:.2}");
    assert!(
        se_pp < ratio * se_power_64,
        "{name}: per point {se_pp} against power {se_power_64}"
    );
}

#[test]
fn a_few_lamps_are_chosen_per_point_with_the_image_of_choosing_by_power_and_less_noise() {
    // Power's noise at 64 spp is 1 % of the mean here: 4096 spp for a tight reference.
    per_point_against_power("few lamps", &few_lamps(), 4096, 0.5);
}

/// Blender's instancing scene (a sun and a point lamp over 200 instanced monkeys and spheres).
#[test]
fn the_blender_instances_choose_their_two_lamps_per_point() {
    use pathfarm_tracer::gltf::{load, LoadOptions, NoExternalResources};
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/suite/instanced.glb");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let scene =
        load(&bytes, &NoExternalResources, &LoadOptions::default()).expect("the scene loads");
    assert_eq!(scene.lights.punctual.len(), 2);
    per_point_against_power("instanced", &scene, 256, 0.9);
}
