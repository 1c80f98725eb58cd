//! Many emitters choose by the light tree (`light::tree`): the image is the same, within its noise,
//! as the one BSDF sampling alone renders (which never chooses a light), for light sampling alone
//! and for MIS, with one-sided and two-sided emitters of different powers, some facing away from
//! everything they could light.

mod common;

use common::*;
use glam::Vec3;
use pathfarm_tracer::geometry::Mesh;
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
