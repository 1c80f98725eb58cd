//! The wavefront integrator against the scalar one, sample by sample: every radiance bit, ray
//! count and vertex count must be the same.

use super::Wavefront;
use crate::gltf::{load_parts, LoadOptions, NoExternalResources};
use crate::render::render_sample;
use crate::scene::{Scene, SceneParts};
use crate::settings::{DirectStrategy, RenderSettings, RussianRoulette, SamplerKind};
use glam::{Vec3, Vec4};

mod guided;
mod lights;
mod materials;
mod textures;

fn parts(name: &str) -> SceneParts {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(format!("{name}.gltf"));
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    load_parts(&bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// The scene built (with its caustic guide, where it has one).
fn scene(parts: SceneParts) -> Scene {
    Scene::build(parts).expect("scene builds")
}

/// Renders `samples` of a grid of pixels both ways and compares every result.
fn assert_same_bits(scene: &Scene, settings: &RenderSettings, samples: std::ops::Range<u32>) {
    let Some(wavefront) = Wavefront::new(scene, settings) else {
        // Only where the processor has no build of the lanes (without AVX2, or not x86-64).
        assert!(
            crate::isa::Isa::detect().is_none(),
            "the wavefront takes this scene"
        );
        eprintln!("SKIPPED: this processor runs no build of the wavefront's lanes");
        return;
    };
    let pixels: Vec<(u32, u32)> = (0..settings.height)
        .step_by(3)
        .flat_map(|y| (0..settings.width).step_by(5).map(move |x| (x, y)))
        .collect();
    let work: Vec<(u32, u32, u32)> = pixels
        .iter()
        .flat_map(|&(x, y)| samples.clone().map(move |i| (x, y, i)))
        .collect();
    for wavefront in crate::isa::Isa::detected().map(|isa| wavefront.with_isa(isa)) {
        let mut got = Vec::new();
        wavefront.render(work.iter().copied(), |x, y, i, r| got.push((x, y, i, r)));
        assert_eq!(got.len(), work.len(), "every sample is rendered once");
        got.sort_by_key(|&(x, y, i, _)| (y, x, i));
        let mut expected = work.clone();
        expected.sort_by_key(|&(x, y, i)| (y, x, i));
        let mut nonzero = 0;
        for ((x, y, i, r), (ex, ey, ei)) in got.into_iter().zip(expected) {
            assert_eq!((x, y, i), (ex, ey, ei));
            let s = render_sample(scene, settings, x, y, i);
            let bits = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
            assert_eq!(
                (bits(r.radiance), r.rays, r.vertices),
                (bits(s.radiance), s.rays, s.vertices),
                "pixel ({x}, {y}) sample {i}, {:?} ({:?})",
                settings.rr,
                wavefront.isa
            );
            nonzero += usize::from(s.radiance != Vec3::ZERO);
        }
        // Not a comparison of zeros (with depth 0, only pixels that see a light carry any).
        if settings.max_depth != Some(0) {
            assert!(
                nonzero > work.len() / 10,
                "only {nonzero} of {} samples carry light",
                work.len()
            );
        }
    }
}

/// The pixels whose first sample differs between two scenes: that a change to a scene shows.
fn pixels_that_differ(a: &Scene, b: &Scene, s: &RenderSettings) -> usize {
    (0..s.height)
        .flat_map(|y| (0..s.width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            render_sample(a, s, x, y, 0).radiance != render_sample(b, s, x, y, 0).radiance
        })
        .count()
}

/// Two lamps for a scene: a point inside its bounds and a sun (chosen at each point by what they
/// send there: `lamp_weights` in the lanes).
fn point_and_sun(p: &SceneParts) -> Vec<crate::light::PunctualLight> {
    use crate::light::{DirectionalLight, PointLight, PunctualLight};
    let (lo, hi) = p.mesh.bounds();
    vec![
        PunctualLight::Point(PointLight {
            position: (lo + hi) * 0.5 + Vec3::new(0.1, 0.3, 0.1) * (hi - lo),
            intensity: Vec3::splat((hi - lo).length_squared()),
        }),
        PunctualLight::Directional(DirectionalLight {
            direction: Vec3::new(0.3, -0.4, -1.0).normalize(),
            illuminance: Vec3::new(1.0, 0.9, 0.8),
        }),
    ]
}

/// A sky of one colour (the peer comparison's environment scene's).
fn sky() -> crate::light::Environment {
    crate::light::Environment::uniform(Vec3::new(0.6, 0.75, 1.0)).expect("a valid colour")
}

fn settings(seed: u64, rr: RussianRoulette, max_depth: Option<u32>) -> RenderSettings {
    RenderSettings {
        seed,
        rr,
        max_depth,
        ..RenderSettings::new(48, 36)
    }
}

#[test]
fn every_sample_is_the_scalar_integrators_bit_for_bit() {
    let rrs = [
        (RussianRoulette::Auto, None),
        (RussianRoulette::Off, Some(6)),
        (RussianRoulette::Fixed(0.7), None),
        (
            RussianRoulette::Threshold {
                terminate: 0.5,
                below: 0.3,
            },
            None,
        ),
        (RussianRoulette::Auto, Some(0)),
        (RussianRoulette::Auto, Some(2)),
    ];
    for name in ["cornell", "smalllight", "furnacebox"] {
        let scene = scene(parts(name));
        for (k, &(rr, max_depth)) in rrs.iter().enumerate() {
            let settings = settings(
                (k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
                rr,
                max_depth,
            );
            assert_same_bits(&scene, &settings, 0..6);
            assert_same_bits(&scene, &settings, 1_000_003..1_000_005);
        }
    }
}

/// Cases the shipped scenes do not have: a double-sided light, a light seen from behind, a black
/// material (no direct lighting, the path ends at the BSDF sample) and an emissive wall that
/// reflects too.
#[test]
fn double_sided_lights_black_and_emissive_walls_are_the_scalar_integrators() {
    let mut p = parts("cornell");
    let light = p
        .materials
        .iter()
        .position(|m| m.is_emissive())
        .expect("the box has a light");
    p.materials[light].double_sided = true;
    let walls: Vec<usize> = (0..p.materials.len()).filter(|&m| m != light).collect();
    p.materials[walls[0]].base_color = Vec4::new(0.0, 0.0, 0.0, 1.0);
    p.materials[walls[1]].emissive = Vec3::new(0.2, 0.1, 0.05);
    let scene = scene(p);
    for rr in [RussianRoulette::Auto, RussianRoulette::Fixed(0.5)] {
        assert_same_bits(&scene, &settings(7, rr, None), 0..8);
    }
}

/// A mesh with vertex normals: the lanes interpolate them as `Scene::surface` does. The box's
/// normals are tilted by a different amount at every corner, and some corners are made to
/// disagree with the winding, to cancel out (zero: the geometric normal is used) or to be NaN.
#[test]
fn vertex_normals_are_interpolated_as_the_scalar_integrator_does() {
    let mut p = parts("cornell");
    let mut normals = Vec::with_capacity(p.mesh.positions.len());
    for (t, &[a, b, c]) in p.mesh.positions.iter().enumerate() {
        let ng = (b - a).cross(c - a).normalize();
        let corner = |k: usize| {
            let h = crate::sampler::hash_u32((t * 3 + k) as u32);
            let tilt = |shift: u32| ((h >> shift) & 0xff) as f32 / 255.0 - 0.5;
            (ng + 0.6 * Vec3::new(tilt(0), tilt(8), tilt(16))).normalize()
        };
        let mut n = [corner(0), corner(1), corner(2)];
        match t % 7 {
            // Disagrees with the winding: the interpolated normal is flipped to ng's side.
            1 => n = n.map(|v| -v),
            // Cancels out everywhere on the triangle's centre line: the geometric normal.
            2 => n = [Vec3::ZERO; 3],
            3 => n[0] = Vec3::splat(f32::NAN),
            _ => {}
        }
        normals.push(n);
    }
    p.mesh.normals = Some(normals);
    let scene = scene(p);
    assert!(
        scene.diffuse.is_some(),
        "the lanes take a mesh with normals"
    );
    for (seed, rr) in [(3, RussianRoulette::Auto), (4, RussianRoulette::Off)] {
        let max_depth = (rr == RussianRoulette::Off).then_some(5);
        assert_same_bits(&scene, &settings(seed, rr, max_depth), 0..8);
    }
    // The normals change the image: this is not the flat box again.
    let flat = self::scene(parts("cornell"));
    let s = settings(3, RussianRoulette::Auto, None);
    let differ = pixels_that_differ(&scene, &flat, &s);
    assert!(differ > (s.width * s.height / 4) as usize, "{differ}");
}

/// Punctual lamps (a point, a spot and a sun) beside the box's area light, and lighting the box
/// alone once its light is switched off: each vertex's lamp sample is `direct_punctual`'s.
#[test]
fn punctual_lamps_light_the_lanes_as_they_light_the_scalar_integrator() {
    use crate::light::{DirectionalLight, PointLight, PunctualLight, SpotLight};
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    let mut p = parts("cornell");
    for corner in p.mesh.positions.iter().flatten() {
        (lo, hi) = (lo.min(*corner), hi.max(*corner));
    }
    let (centre, size) = ((lo + hi) * 0.5, hi - lo);
    p.punctual_lights = vec![
        PunctualLight::Point(PointLight {
            position: centre + Vec3::new(0.2, 0.3, 0.1) * size,
            intensity: Vec3::new(0.8, 0.6, 0.4) * size.length_squared(),
        }),
        PunctualLight::Spot(SpotLight {
            position: centre + Vec3::new(-0.2, 0.4, 0.0) * size,
            direction: Vec3::new(0.1, -1.0, 0.2).normalize(),
            intensity: Vec3::splat(2.0) * size.length_squared(),
            cos_inner: 0.9,
            cos_outer: 0.7,
        }),
        PunctualLight::Directional(DirectionalLight {
            direction: Vec3::new(0.3, -0.4, -1.0).normalize(),
            illuminance: Vec3::new(1.0, 1.0, 0.8),
        }),
    ];
    let lit = scene(p.clone());
    assert!(lit.diffuse.is_some(), "the lanes take punctual lamps");
    for (seed, rr) in [(5, RussianRoulette::Auto), (6, RussianRoulette::Fixed(0.6))] {
        assert_same_bits(&lit, &settings(seed, rr, None), 0..6);
    }
    // The lamps alone: no emissive triangle, so no area light sample at all.
    for m in &mut p.materials {
        m.emissive = Vec3::ZERO;
    }
    let lamps_only = scene(p);
    assert!(lamps_only.lights.area.is_empty());
    assert!(lamps_only.diffuse.is_some());
    assert_same_bits(&lamps_only, &settings(7, RussianRoulette::Auto, None), 0..6);
}

/// The camera rays the lanes make ahead (`lanes/refill.rs`) are `Camera::generate_ray`'s: an
/// orthographic camera and a perspective one, turned, scaled unevenly and moved; and a camera
/// that collapses every direction to zero, whose samples are handed on at once as NaN.
#[test]
fn every_camera_ray_is_the_scalar_integrators() {
    use crate::camera::{Camera, Orthographic, Perspective, Projection};
    use glam::{Affine3A, Quat};
    let place = |to_world: Affine3A, base: &Camera| base.to_world * to_world;
    let base = scene(parts("cornell")).camera;
    let turned = Affine3A::from_scale_rotation_translation(
        Vec3::new(1.0, 1.3, 0.8),
        Quat::from_euler(glam::EulerRot::YXZ, 0.11, -0.07, 0.05),
        Vec3::new(0.02, -0.03, 0.1),
    );
    let cameras = [
        Camera::new(
            Projection::Orthographic(Orthographic { ymag: 0.9 }),
            place(turned, &base),
        ),
        Camera::new(
            Projection::Perspective(Perspective::new(0.6)),
            place(turned, &base),
        ),
        Camera::new(base.projection, Affine3A::ZERO),
    ];
    for (k, camera) in cameras.into_iter().enumerate() {
        let mut p = parts("cornell");
        p.camera = Some(camera);
        let scene = scene(p);
        let settings = settings(k as u64 + 3, RussianRoulette::Auto, None);
        if k == 2 {
            let ray = scene.camera.generate_ray(glam::Vec2::new(1.5, 2.5), 48, 36);
            assert!(!ray.d.is_finite(), "the collapsed camera makes no rays");
            let s = render_sample(&scene, &settings, 1, 2, 0);
            assert!(s.radiance.is_nan() && s.rays == 0);
        }
        assert_same_bits(&scene, &settings, 0..5);
    }
}

#[test]
fn settings_it_does_not_model_go_to_the_scalar_integrator() {
    let cornell = scene(parts("cornell"));
    let base = settings(1, RussianRoulette::Auto, None);
    assert!(cornell.diffuse.is_some());
    assert_eq!(
        Wavefront::new(&cornell, &base).is_some(),
        crate::isa::Isa::detect().is_some()
    );
    for other in [
        RenderSettings {
            direct: DirectStrategy::Light,
            ..base
        },
        RenderSettings {
            sampler: SamplerKind::Independent,
            ..base
        },
    ] {
        assert!(Wavefront::new(&cornell, &other).is_none());
    }
}

/// Instanced meshes (a two-level BVH): the lanes read a hit on an instance through
/// `Scene::instance_triangle`, as `Scene::surface` does. Small copies of the box's walls placed
/// inside it — one prototype flat, one with vertex normals, placed turned, scaled unevenly and
/// mirrored (two corners swap, and the barycentrics with them) — beside the box itself; and the
/// same copies with the walls alone under a lamp, without any world-space triangle.
#[test]
fn instanced_meshes_are_shaded_as_the_scalar_integrator_shades_them() {
    use crate::geometry::{Mesh, Placement};
    use crate::light::{PointLight, PunctualLight};
    use glam::{DMat4, DQuat, DVec3};
    let mut p = parts("cornell");
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for corner in p.mesh.positions.iter().flatten() {
        (lo, hi) = (lo.min(*corner), hi.max(*corner));
    }
    let (centre, size) = ((lo + hi) * 0.5, hi - lo);
    // The box's walls moved to the unit cube around the origin (its light left out: emitters are
    // never instanced).
    let mut flat = Mesh::default();
    for (tri, &m) in p.mesh.positions.iter().zip(&p.mesh.material) {
        if !p.materials[m as usize].is_emissive() {
            flat.positions.push(tri.map(|v| (v - centre) / size));
            flat.material.push(m);
        }
    }
    let mut smooth = flat.clone();
    smooth.normals = Some(
        smooth
            .positions
            .iter()
            .enumerate()
            .map(|(t, &[a, b, c])| {
                let ng = (b - a).cross(c - a).normalize();
                let tilt = |k: u32| {
                    let h = crate::sampler::hash_u32(t as u32 * 3 + k);
                    Vec3::new(h as f32, (h >> 8) as f32, (h >> 16) as f32) / 16_777_216.0
                };
                [0, 1, 2].map(|k| (ng + 0.5 * (tilt(k) - Vec3::splat(0.5))).normalize())
            })
            .collect(),
    );
    let (c, s) = (centre.as_dvec3(), size.as_dvec3());
    let place = |prototype: u32, at: DVec3, scale: DVec3, turn: f64| Placement {
        prototype,
        to_world: DMat4::from_scale_rotation_translation(
            s * scale,
            DQuat::from_euler(glam::EulerRot::YXZ, turn, 0.3 * turn, -0.2 * turn),
            c + s * at,
        ),
    };
    p.prototypes = vec![flat, smooth];
    p.placements = vec![
        place(0, DVec3::new(-0.25, -0.3, 0.1), DVec3::splat(0.2), 0.4),
        place(
            1,
            DVec3::new(0.2, -0.25, -0.1),
            DVec3::new(0.25, 0.15, 0.2),
            -0.7,
        ),
        // Mirrored: a negative determinant.
        place(
            1,
            DVec3::new(0.0, 0.1, 0.0),
            DVec3::new(-0.2, 0.2, 0.2),
            1.1,
        ),
        place(
            0,
            DVec3::new(0.25, 0.2, 0.15),
            DVec3::new(0.15, -0.15, 0.15),
            2.0,
        ),
    ];
    let boxed = scene(p.clone());
    assert_eq!(boxed.info.instances, 4);
    assert!(boxed.diffuse.is_some(), "the lanes take instanced meshes");
    for (seed, rr) in [(8, RussianRoulette::Auto), (9, RussianRoulette::Off)] {
        let max_depth = (rr == RussianRoulette::Off).then_some(5);
        assert_same_bits(&boxed, &settings(seed, rr, max_depth), 0..8);
    }
    // The instances change the image: some samples see them.
    let plain = scene(parts("cornell"));
    let s = settings(8, RussianRoulette::Auto, None);
    let differ = pixels_that_differ(&boxed, &plain, &s);
    assert!(differ > (s.width * s.height / 10) as usize, "{differ}");
    // Instances alone, lit by a lamp (the walls themselves placed as an instance): misses load
    // the first instance's triangle.
    p.mesh = Mesh::default();
    p.placements.push(place(0, DVec3::ZERO, DVec3::ONE, 0.0));
    p.punctual_lights = vec![PunctualLight::Point(PointLight {
        position: centre + Vec3::new(0.1, 0.3, 0.2) * size,
        intensity: Vec3::splat(0.5) * size.length_squared(),
    })];
    let alone = scene(p);
    assert!(alone.mesh.is_empty() && alone.diffuse.is_some());
    assert_same_bits(&alone, &settings(10, RussianRoulette::Auto, None), 0..8);
}
