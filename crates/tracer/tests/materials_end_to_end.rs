//! Materials and lights through the whole integrator, against exact answers: glass in a uniform
//! radiance field, Beer–Lambert absorption, alpha cut-outs and stochastic blending, and a
//! directional light on a diffuse floor.

mod common;

use common::*;
use glam::{Affine3A, Vec3, Vec4};
use pathfarm_tracer::camera::{Camera, Orthographic, Projection};
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::light::{DirectionalLight, PunctualLight};
use pathfarm_tracer::material::{AlphaMode, Material, Volume};
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{render_image, DirectStrategy, RenderSettings, SamplerKind, Scene};

/// Appends `other` to `mesh` with every triangle using material `m`.
fn append(mesh: &mut Mesh, other: Mesh, m: u32) {
    mesh.material
        .extend(std::iter::repeat_n(m, other.positions.len()));
    mesh.positions.extend(other.positions);
}

/// The cube [-s, s]³ with its faces pointing outwards.
fn outward_box(s: f32) -> Mesh {
    let mut m = inward_box();
    for t in &mut m.positions {
        *t = [t[0] * s, t[2] * s, t[1] * s];
    }
    m
}

/// A quad in the plane z = `z` spanning [-h, h]², facing +z.
fn quad(h: f32, z: f32) -> Mesh {
    let (a, b, c, d) = (
        Vec3::new(-h, -h, z),
        Vec3::new(h, -h, z),
        Vec3::new(h, h, z),
        Vec3::new(-h, h, z),
    );
    Mesh {
        positions: vec![[a, b, c], [a, c, d]],
        material: vec![0, 0],
        ..Mesh::default()
    }
}

fn glass(thin: bool, sigma: f32, ior: f32) -> Material {
    Material {
        base_color: Vec4::ONE,
        metallic: 0.0,
        roughness: 0.0,
        transmission: 1.0,
        ior,
        volume: if thin {
            None
        } else {
            Some(Volume {
                sigma_a: Vec3::splat(sigma),
            })
        },
        ..Material::default()
    }
}

fn check_mean(scene: &Scene, exact: f64, settings: &RenderSettings, spp: u32, what: &str) {
    let acc = render_image(scene, settings, 16, 0..spp, &|_| {});
    assert_eq!(acc.invalid_count, 0, "{what}");
    let (mean, se) = image_mean_and_stderr(&acc);
    eprintln!(
        "{what:<40} {:>10}: {mean:.5} ± {se:.5} (exact {exact:.5})",
        settings.direct.name()
    );
    let tolerance = 3.0 * se + 1e-4 * exact;
    assert!(
        (mean - exact).abs() <= tolerance,
        "{what}, {}: {mean} ± {se}, exact {exact}",
        settings.direct
    );
}

#[test]
fn glass_in_a_uniform_radiance_field_changes_nothing() {
    // Black walls emitting Le = 1 enclose a glass cube: every ray, refracted or reflected any number
    // of times, ends on a wall, so every pixel is exactly 1 — if refraction, total internal reflection
    // and the 1/η² radiance scaling are right.
    for (label, material) in [
        ("solid glass, ior 1.5", glass(false, 0.0, 1.5)),
        ("thin-walled glass", glass(true, 0.0, 1.5)),
    ] {
        let mut mesh = inward_box();
        append(&mut mesh, outward_box(0.5), 1);
        let scene = Scene::build(SceneParts {
            mesh,
            materials: vec![lambert(0.0, 1.0), material],
            camera: Some(camera_at(Vec3::new(0.1, 0.05, 0.9))),
            ..SceneParts::default()
        })
        .expect("builds");
        for direct in [
            DirectStrategy::Mis,
            DirectStrategy::Bsdf,
            DirectStrategy::Hemisphere,
        ] {
            let settings = RenderSettings {
                direct,
                sampler: SamplerKind::Independent,
                ..RenderSettings::new(24, 24)
            };
            check_mean(&scene, 1.0, &settings, 8, label);
        }
    }
}

#[test]
fn beer_lambert_absorption_through_a_slab() {
    // An orthographic camera looks straight through a slab of thickness 0.5 (ior 1: no refraction,
    // no reflection) at an emitter of radiance 1: every ray crosses exactly 0.5 of the medium.
    let sigma = 1.3f32;
    let mut mesh = Mesh::default();
    append(&mut mesh, quad(10.0, -3.0), 0); // emitter facing the camera (+z)
    let mut slab = outward_box(1.0);
    for t in &mut slab.positions {
        for v in t.iter_mut() {
            *v = Vec3::new(v.x * 5.0, v.y * 5.0, v.z * 0.25 - 1.0);
        }
    }
    append(&mut mesh, slab, 1);
    let ortho = Camera::new(
        Projection::Orthographic(Orthographic { ymag: 1.0 }),
        Affine3A::IDENTITY,
    );
    let scene = Scene::build(SceneParts {
        mesh,
        materials: vec![lambert(0.0, 1.0), glass(false, sigma, 1.0)],
        camera: Some(ortho),
        ..SceneParts::default()
    })
    .expect("builds");
    let exact = (-sigma as f64 * 0.5).exp();
    let settings = RenderSettings::new(8, 8);
    let acc = render_image(&scene, &settings, 8, 0..4, &|_| {});
    for p in &acc.pixels {
        let m = p.mean();
        // Ray origins are offset off each surface by a few hundred ULPs (≈3·10⁻⁵ here), which
        // shortens the path through the medium by that much.
        assert!(
            (m[1] / exact - 1.0).abs() < 1e-4,
            "pixel {m:?}, exact {exact}"
        );
    }
}

#[test]
fn alpha_mask_cuts_out_and_blend_covers_stochastically() {
    // An emitter of radiance 1 behind a black quad. MASK with alpha below the cut-off: the quad is not
    // there (1). BLEND with alpha 0.3: covered 30% of the time (0.7).
    for (mode, alpha, exact) in [
        (AlphaMode::Mask { cutoff: 0.5 }, 0.2f32, 1.0f64),
        (AlphaMode::Blend, 0.3, 0.7),
    ] {
        let mut mesh = Mesh::default();
        append(&mut mesh, quad(10.0, -3.0), 0);
        append(&mut mesh, quad(10.0, -1.0), 1);
        let cover = Material {
            base_color: Vec4::new(0.0, 0.0, 0.0, alpha),
            alpha_mode: mode,
            ..lambert(0.0, 0.0)
        };
        let ortho = Camera::new(
            Projection::Orthographic(Orthographic { ymag: 1.0 }),
            Affine3A::IDENTITY,
        );
        let scene = Scene::build(SceneParts {
            mesh,
            materials: vec![lambert(0.0, 1.0), cover],
            camera: Some(ortho),
            ..SceneParts::default()
        })
        .expect("builds");
        let settings = RenderSettings {
            sampler: SamplerKind::Independent,
            ..RenderSettings::new(16, 16)
        };
        let acc = render_image(&scene, &settings, 16, 0..64, &|_| {});
        let (mean, se) = image_mean_and_stderr(&acc);
        eprintln!("{mode:?}: {mean:.4} ± {se:.4} (exact {exact})");
        assert!(
            (mean - exact).abs() <= 3.0 * se + 1e-6,
            "{mode:?}: {mean} ± {se}"
        );
    }
}

#[test]
fn directional_light_on_a_diffuse_floor() {
    // A sun of illuminance E at 60° from the zenith on an infinite-ish Lambertian floor of albedo ρ,
    // seen from straight above: L = ρ/π · E · cos 60°, for every strategy (the sun is a delta light,
    // always light-sampled).
    let (rho, e) = (0.6f32, 3.0f32);
    let sun_dir = Vec3::new(3f32.sqrt() / 2.0, 0.0, -0.5).normalize(); // travelling down at 60°
    let floor = quad(100.0, 0.0);
    let ortho = Camera::new(
        Projection::Orthographic(Orthographic { ymag: 1.0 }),
        Affine3A::from_translation(Vec3::new(0.0, 0.0, 5.0)),
    );
    let scene = Scene::build(SceneParts {
        mesh: floor,
        materials: vec![lambert(rho, 0.0)],
        punctual_lights: vec![PunctualLight::Directional(DirectionalLight {
            direction: sun_dir,
            illuminance: Vec3::splat(e),
        })],
        camera: Some(ortho),
        ..SceneParts::default()
    })
    .expect("builds");
    let exact = (rho / std::f32::consts::PI * e * 0.5) as f64;
    for direct in DirectStrategy::ALL {
        let settings = RenderSettings {
            direct,
            ..RenderSettings::new(8, 8)
        };
        let acc = render_image(&scene, &settings, 8, 0..4, &|_| {});
        for p in &acc.pixels {
            assert!(
                (p.mean()[0] - exact).abs() < 1e-5 * exact.max(1.0),
                "{direct}: {:?} vs {exact}",
                p.mean()
            );
        }
    }
}
