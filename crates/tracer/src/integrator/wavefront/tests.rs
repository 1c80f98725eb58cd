//! The wavefront integrator against the scalar one, sample by sample: every radiance bit, ray
//! count and vertex count must be the same.

use super::Wavefront;
use crate::gltf::{load_parts, LoadOptions, NoExternalResources};
use crate::render::render_sample;
use crate::scene::{Scene, SceneParts};
use crate::settings::{DirectStrategy, RenderSettings, RussianRoulette, SamplerKind};
use glam::{Vec3, Vec4};

fn parts(name: &str) -> SceneParts {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(format!("{name}.gltf"));
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    load_parts(&bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

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

/// Alpha: every ray query takes its lane's coverage value (`Lanes::alpha_at`, `trace_path`'s
/// `alpha_at`), the camera rays' bundle, the closest rays (two a walk and alone), the shadow
/// rays traced with them and alone, and the lamps' (two a walk). The box with walls blended at
/// 45 % and cut out where a texture's alpha is low, lit by its light, lamps and a sky seen
/// through the walls; copies of its walls placed inside it as instances (whose coverage is
/// salted by the instance); and the textured scene with its texture's alpha cut out on the
/// floor and blended on the sphere.
#[test]
fn alpha_covers_the_lanes_as_it_covers_the_scalar_integrator() {
    use crate::geometry::{Mesh, Placement};
    use crate::material::AlphaMode;
    use glam::{DMat4, DQuat, DVec3};
    let mut p = parts("cornell");
    let mut blended = 0;
    for (k, m) in p.materials.iter_mut().enumerate() {
        if m.emissive == Vec3::ZERO && k % 2 == 0 {
            m.alpha_mode = AlphaMode::Blend;
            m.base_color.w = 0.45;
            blended += 1;
        }
    }
    assert!(blended >= 1);
    let (lo, hi) = p.mesh.bounds();
    p.punctual_lights = point_and_sun(&p);
    let walls = scene(p.clone()).with_environment(Some(sky()));
    assert!(walls.any_alpha() && walls.diffuse.is_some());
    let s = settings(1, RussianRoulette::Auto, None);
    let opaque = scene(parts("cornell"));
    assert!(pixels_that_differ(&opaque, &walls, &s) > 500);
    for (seed, rr) in [
        (81, RussianRoulette::Auto),
        (82, RussianRoulette::Fixed(0.7)),
    ] {
        assert_same_bits(&walls, &settings(seed, rr, None), 0..6);
    }
    // Copies of the walls, blended, as instances inside the box.
    let centre = (lo + hi) * 0.5;
    let size = hi - lo;
    let mut proto = Mesh::default();
    for (tri, &m) in p.mesh.positions.iter().zip(&p.mesh.material) {
        if !p.materials[m as usize].is_emissive() {
            proto.positions.push(tri.map(|v| (v - centre) / size));
            proto.material.push(m);
        }
    }
    let (c, sz) = (centre.as_dvec3(), size.as_dvec3());
    let place = |at: DVec3, scale: f64, turn: f64| Placement {
        prototype: 0,
        to_world: DMat4::from_scale_rotation_translation(
            sz * scale,
            DQuat::from_euler(glam::EulerRot::YXZ, turn, 0.3 * turn, 0.0),
            c + sz * at,
        ),
    };
    p.prototypes = vec![proto];
    p.placements = vec![
        place(DVec3::new(-0.2, -0.25, 0.1), 0.3, 0.4),
        place(DVec3::new(0.2, -0.2, -0.1), 0.25, -0.7),
    ];
    let placed = scene(p).with_environment(Some(sky()));
    assert_eq!(placed.info.instances, 2);
    assert!(pixels_that_differ(&walls, &placed, &s) > 100);
    assert_same_bits(&placed, &settings(83, RussianRoulette::Auto, None), 0..6);
    // Cut out and blended by a texture's alpha.
    let mut t = parts("textured");
    let textured: Vec<usize> = (0..t.materials.len())
        .filter(|&m| t.materials[m].base_color_texture.is_some())
        .collect();
    assert!(textured.len() >= 2);
    for (k, &m) in textured.iter().enumerate() {
        let texture = t.materials[m]
            .base_color_texture
            .as_ref()
            .expect("textured")
            .texture;
        for (j, texel) in t.textures[texture as usize].texels.iter_mut().enumerate() {
            texel[3] = ((j * 37) % 256) as u8;
        }
        t.materials[m].alpha_mode = match k % 2 {
            0 => AlphaMode::Mask { cutoff: 0.5 },
            _ => AlphaMode::Blend,
        };
    }
    let cut = scene(t).with_environment(Some(sky()));
    assert!(cut.any_alpha() && cut.diffuse.is_some());
    assert!(pixels_that_differ(&scene(parts("textured")), &cut, &s) > 300);
    for (seed, rr) in [(84, RussianRoulette::Auto), (85, RussianRoulette::Max)] {
        assert_same_bits(&cut, &settings(seed, rr, None), 0..6);
    }
}

/// General materials (`DiffuseMaterial::general`: the BSDF's lobes the vector steps do not
/// model) are made at each hit, evaluated and sampled lane by lane through the BSDF's own code
/// (`lanes/general.rs`): the box with walls of a rough and a smooth clear coat, a sheen, rough
/// glass (clear and absorbing, and thin-walled), a plastic half transmitting through smooth glass
/// (delta and non-delta lobes in one BSDF), beside its Lambertian and glossy walls, lit by its
/// light, by lamps (chosen per point and by power) and by a sky; and Blender's export of coats and
/// sheens (the suite's `clearcoat`).
#[test]
fn general_materials_are_shaded_lane_by_lane_as_the_scalar_integrator_shades_them() {
    use crate::material::{Material, Volume};
    let kinds: [fn(&mut Material); 7] = [
        |m| (m.clearcoat, m.clearcoat_roughness) = (1.0, 0.2),
        |m| (m.clearcoat, m.clearcoat_roughness, m.metallic) = (0.8, 0.0, 1.0),
        |m| (m.sheen_color, m.sheen_roughness) = (Vec3::new(0.9, 0.6, 0.3), 0.4),
        |m| (m.transmission, m.roughness) = (1.0, 0.3),
        |m| {
            (m.transmission, m.roughness) = (1.0, 0.45);
            m.volume = Some(Volume {
                sigma_a: Vec3::new(0.9, 0.35, 0.1),
            });
        },
        |m| (m.transmission, m.roughness, m.double_sided) = (0.9, 0.25, true),
        |m| (m.transmission, m.roughness, m.specular) = (0.5, 0.0, 1.0),
    ];
    let mut p = parts("cornell");
    let mut changed = 0;
    for (k, m) in p.materials.iter_mut().enumerate() {
        if m.emissive != Vec3::ZERO {
            continue;
        }
        kinds[k % kinds.len()](m);
        changed += 1;
    }
    assert!(changed >= 3);
    let general = scene(p.clone());
    let d = general
        .diffuse
        .as_ref()
        .expect("the lanes take every material");
    assert!(d.materials.iter().filter(|m| m.general).count() >= 3);
    let s = settings(1, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&scene(parts("cornell")), &general, &s) > 500);
    for (seed, rr) in [
        (61, RussianRoulette::Auto),
        (62, RussianRoulette::Fixed(0.7)),
        (63, RussianRoulette::Off),
    ] {
        assert_same_bits(&general, &settings(seed, rr, Some(8)), 0..6);
    }
    // Every kind on every wall in turn, so that each kind shades where the light falls.
    for shift in 1..kinds.len() {
        let mut q = parts("cornell");
        for (k, m) in q.materials.iter_mut().enumerate() {
            if m.emissive == Vec3::ZERO {
                kinds[(k + shift) % kinds.len()](m);
            }
        }
        assert_same_bits(
            &scene(q),
            &settings(64 + shift as u64, RussianRoulette::Auto, None),
            0..4,
        );
    }
    // Lamps (`light_punctual`'s evaluation, per point and lane by lane) and a sky
    // (`light_environment`'s).
    p.punctual_lights = point_and_sun(&p);
    let mut lit = scene(p).with_environment(Some(sky()));
    assert!(lit.diffuse.is_some() && lit.lights.punctual_per_point);
    assert_same_bits(&lit, &settings(71, RussianRoulette::Auto, Some(6)), 0..6);
    lit.lights.choose_punctual_by_power();
    assert_same_bits(&lit, &settings(72, RussianRoulette::Auto, Some(6)), 0..6);
    // Blender's export: coats and sheens, as a user's file has them.
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/suite/clearcoat.glb");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let exported = load_parts(&bytes, &NoExternalResources, &LoadOptions::default())
        .expect("the suite's clearcoat scene loads");
    let exported = scene(exported);
    let d = exported
        .diffuse
        .as_ref()
        .expect("the lanes take Blender's coats and sheens");
    assert!(d.materials.iter().any(|m| m.general));
    assert_same_bits(&exported, &settings(73, RussianRoulette::Auto, None), 0..4);
}

/// Glass that absorbs (a volume with an attenuation): each lane tracks the medium its path is
/// in as `trace_path` does (`lanes/volumes.rs`). The caustics scene's glass sphere, coloured;
/// and the box whose green wall is an open sheet of absorbing glass, so that paths entering it
/// go on to shade a copy of the wall behind it (Lambertian and glossy) from inside the medium, lit by the
/// box's light (through the glass), a small emitter and a lamp in the medium, a sun and a sky.
#[test]
fn absorbing_volumes_attenuate_the_lanes_as_they_attenuate_the_scalar_integrator() {
    use crate::light::{DirectionalLight, Environment, PointLight, PunctualLight};
    use crate::material::Volume;
    let sigma = Vec3::new(0.9, 0.35, 0.1);
    let mut coloured = parts("caustics");
    let mut glasses = 0;
    for m in &mut coloured.materials {
        if let Some(v) = &mut m.volume {
            v.sigma_a = sigma;
            glasses += 1;
        }
    }
    assert!(glasses > 0, "the caustics scene has a solid glass");
    let coloured = scene(coloured);
    assert!(coloured.diffuse.as_ref().is_some_and(|d| d.absorbing));
    let s = settings(51, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&coloured, &scene(parts("caustics")), &s) > 20);
    for (seed, rr) in [(51, RussianRoulette::Auto), (52, RussianRoulette::Max)] {
        assert_same_bits(&coloured, &settings(seed, rr, None), 0..8);
    }

    let mut p = parts("cornell");
    let wall = |p: &SceneParts, name: &str| {
        p.materials
            .iter()
            .position(|m| m.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("the box has a {name} wall"))
    };
    let (green, red, white) = (wall(&p, "green"), wall(&p, "red"), wall(&p, "white"));
    // Behind the glass wall, outside the box, a copy of it: what paths inside the medium shade
    // and light.
    let (lo, hi) = p.mesh.bounds();
    let glass_wall: Vec<[Vec3; 3]> = (0..p.mesh.len())
        .filter(|&t| p.mesh.material[t] as usize == green)
        .map(|t| p.mesh.positions[t])
        .collect();
    assert!(!glass_wall.is_empty());
    let mut lamp_outside = Vec3::ZERO;
    for (k, tri) in glass_wall.into_iter().enumerate() {
        let [a, b, c] = tri;
        let inward = (b - a).cross(c - a).normalize();
        let outward = if inward.dot((lo + hi) * 0.5 - a) > 0.0 {
            -inward
        } else {
            inward
        };
        let gap = 0.3 * (hi - lo).max_element();
        lamp_outside = (a + b + c) / 3.0 + outward * 0.5 * gap;
        p.mesh.positions.push(tri.map(|v| v + outward * gap));
        // Half white, half the glossy metal.
        p.mesh
            .material
            .push(if k % 2 == 0 { white } else { red } as u32);
    }
    // And in the gap a small double-sided emitter (the box's light's material): area light
    // samples from the copy, inside the medium, are attenuated too.
    let light = p
        .materials
        .iter()
        .position(|m| m.is_emissive())
        .expect("the box has a light");
    p.materials[light].double_sided = true;
    let r = 0.05 * (hi - lo).max_element();
    let e = Vec3::new(0.0, r, 0.0);
    let f = Vec3::new(0.0, 0.0, r);
    p.mesh
        .positions
        .push([lamp_outside - e, lamp_outside + e, lamp_outside + f]);
    p.mesh.material.push(light as u32);
    let glass = &mut p.materials[green];
    (glass.transmission, glass.roughness, glass.metallic) = (1.0, 0.0, 0.0);
    glass.volume = Some(Volume { sigma_a: sigma });
    // A glossy wall (in the box, and half the copy).
    let metal = &mut p.materials[red];
    (metal.metallic, metal.roughness) = (1.0, 0.4);
    let inside = scene(p.clone());
    assert!(inside.diffuse.as_ref().is_some_and(|d| d.absorbing));
    let mut clear = p.clone();
    clear.materials[green].volume = Some(Volume {
        sigma_a: Vec3::ZERO,
    });
    for (seed, rr) in [(53, RussianRoulette::Auto), (54, RussianRoulette::Off)] {
        let max_depth = (rr == RussianRoulette::Off).then_some(6);
        assert_same_bits(&inside, &settings(seed, rr, max_depth), 0..8);
    }
    // A lamp between the glass wall and its copy, inside the medium: the copy's lamp samples
    // are attenuated (the box's light reaches it only through the glass).
    let point = PunctualLight::Point(PointLight {
        position: lamp_outside,
        intensity: Vec3::splat((hi - lo).length_squared()),
    });
    let sun = PunctualLight::Directional(DirectionalLight {
        direction: Vec3::new(0.3, -0.4, -1.0).normalize(),
        illuminance: Vec3::new(1.0, 0.9, 0.8),
    });
    let sky = Environment::uniform(Vec3::new(0.6, 0.75, 1.0)).expect("a valid colour");
    let s = settings(55, RussianRoulette::Auto, Some(6));
    for lamps in [vec![point, sun], vec![point]] {
        let lit = |p: &SceneParts| {
            let mut p = p.clone();
            p.punctual_lights = lamps.clone();
            scene(p).with_environment(Some(sky.clone()))
        };
        let (absorbing, clear) = (lit(&p), lit(&clear));
        assert!(absorbing.diffuse.is_some());
        let differ = pixels_that_differ(&absorbing, &clear, &s);
        eprintln!("differ {differ}");
        assert!(differ > 100, "{differ}");
        assert_same_bits(&absorbing, &s, 0..6);
    }
    // Rough glass, and a coat on the white walls (general materials, `lanes/general.rs`): paths
    // enter the medium through a non-delta lobe, and shade the coated copy from inside it.
    let mut rough = p.clone();
    rough.materials[green].roughness = 0.3;
    let coat = &mut rough.materials[white];
    (coat.clearcoat, coat.clearcoat_roughness) = (1.0, 0.2);
    let mut tangled = rough.clone();
    let rough = scene(rough);
    let d = rough
        .diffuse
        .as_ref()
        .expect("the lanes take general materials");
    assert!(d.absorbing && d.materials[green].general && d.materials[white].general);
    for (seed, rr) in [(56, RussianRoulette::Auto), (57, RussianRoulette::Max)] {
        assert_same_bits(&rough, &settings(seed, rr, None), 0..8);
    }
    // With tangents (along each triangle's first edge): the frames of the lanes lit inside the
    // medium, glossy and general, are oriented by them.
    tangled.mesh.tangents = Some(
        tangled
            .mesh
            .positions
            .iter()
            .map(|&[a, b, _]| [(b - a).normalize().extend(1.0); 3])
            .collect(),
    );
    let tangled = scene(tangled);
    assert!(tangled.diffuse.as_ref().is_some_and(|d| d.tangents));
    let first = settings(1, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&rough, &tangled, &first) > 100);
    assert_same_bits(&tangled, &settings(58, RussianRoulette::Auto, None), 0..8);
}

/// Specular materials (delta lobes only: a perfect mirror, smooth glass with a clear volume)
/// continue their paths lane by lane through `Bsdf::sample` (`scatter_lane_by_lane`), as
/// `trace_path` does: the caustics scene's glass and mirror spheres, and the box with a mirror
/// wall and a glass wall, with and without an environment seen through the glass.
#[test]
fn specular_materials_scatter_as_the_scalar_integrator_scatters() {
    use crate::light::Environment;
    use crate::material::Volume;
    // Why a clear volume's medium needs no tracking: its transmittance is exactly 1.
    assert_eq!(crate::math::det::exp(-0.0 * 3.5), 1.0);
    let caustics = scene(parts("caustics"));
    assert!(
        caustics.diffuse.is_some(),
        "the lanes take mirrors and glass"
    );
    for (seed, rr) in [(31, RussianRoulette::Auto), (32, RussianRoulette::Max)] {
        assert_same_bits(&caustics, &settings(seed, rr, None), 0..8);
    }
    let mut p = parts("cornell");
    let wall = |name: &str| {
        p.materials
            .iter()
            .position(|m| m.name.as_deref() == Some(name))
    };
    let (red, green) = (wall("red").expect("red"), wall("green").expect("green"));
    let mirror = &mut p.materials[red];
    (mirror.metallic, mirror.roughness, mirror.base_color) = (1.0, 0.0, Vec4::ONE);
    let glass = &mut p.materials[green];
    (glass.transmission, glass.roughness, glass.metallic) = (1.0, 0.0, 0.0);
    glass.volume = Some(Volume {
        sigma_a: Vec3::ZERO,
    });
    let specular = scene(p.clone());
    assert!(specular.diffuse.is_some());
    assert!(
        pixels_that_differ(
            &scene(parts("cornell")),
            &specular,
            &settings(1, RussianRoulette::Auto, None)
        ) > 100
    );
    assert_same_bits(&specular, &settings(33, RussianRoulette::Auto, None), 0..8);
    let sky = Environment::uniform(Vec3::new(0.6, 0.75, 1.0)).expect("a valid colour");
    let under_sky = scene(p).with_environment(Some(sky));
    assert_same_bits(
        &under_sky,
        &settings(34, RussianRoulette::Auto, Some(6)),
        0..8,
    );
}

/// Glossy materials (a rough metal, a Lambertian base under a rough specular layer, mixes of
/// the two) are evaluated and sampled in the lanes by the BSDF's own code (`lanes/glossy.rs`):
/// the bench's glossy scene, and the box with Principled walls of every kind, lit by its light,
/// by lamps and by a sky.
#[test]
fn glossy_materials_are_shaded_as_the_scalar_integrator_shades_them() {
    let glossy = scene(parts("glossy"));
    assert!(glossy.diffuse.is_some(), "the lanes take rough metal");
    for (seed, rr) in [(41, RussianRoulette::Auto), (42, RussianRoulette::Max)] {
        assert_same_bits(&glossy, &settings(seed, rr, None), 0..6);
    }
    let mut p = parts("cornell");
    let kinds = [
        // Plastic: a base under the specular layer (Blender's Principled default).
        (0.0, 0.5, 1.0, Vec3::ONE, 1.5),
        // Metal, rough and nearly smooth.
        (1.0, 0.3, 1.0, Vec3::ONE, 1.5),
        (1.0, 0.05, 1.0, Vec3::ONE, 1.5),
        // Half metal; a tinted, weaker layer of another index.
        (0.5, 0.7, 1.0, Vec3::ONE, 1.5),
        (0.0, 0.4, 0.6, Vec3::new(1.0, 0.5, 0.2), 1.8),
    ];
    let mut changed = 0;
    for (k, m) in p.materials.iter_mut().enumerate() {
        if m.emissive != Vec3::ZERO {
            continue;
        }
        let (metallic, roughness, specular, tint, ior) = kinds[k % kinds.len()];
        (m.metallic, m.roughness, m.ior) = (metallic, roughness, ior);
        (m.specular, m.specular_color) = (specular, tint);
        changed += 1;
    }
    assert!(changed >= 3);
    let principled = scene(p.clone());
    assert!(principled.diffuse.is_some());
    let diffuse_box = scene(parts("cornell"));
    let s = settings(1, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&diffuse_box, &principled, &s) > 500);
    for (seed, rr) in [
        (43, RussianRoulette::Auto),
        (44, RussianRoulette::Fixed(0.7)),
    ] {
        assert_same_bits(&principled, &settings(seed, rr, None), 0..6);
    }
    // A lamp (`light_punctual`'s evaluation) and a sky (`light_environment`'s).
    p.punctual_lights = point_and_sun(&p);
    let lit = scene(p).with_environment(Some(sky()));
    assert!(lit.diffuse.is_some() && lit.lights.punctual_per_point);
    assert_same_bits(&lit, &settings(45, RussianRoulette::Auto, Some(6)), 0..6);
}

/// The lanes' choice of light and point is `AreaLights::sample`'s, bit for bit, on a grid of
/// samples and on each CDF value and its neighbours (where the choice changes), seen from points
/// far from the lights and close to them (where the point is sampled by solid angle).
#[test]
fn the_light_table_samples_what_area_lights_sample() {
    use super::lights::LightTable;
    use super::{LANES, V3};
    let mut by_solid_angle = 0;
    for name in ["cornell", "furnacebox", "smalllight"] {
        let scene = scene(parts(name));
        let diffuse = scene.diffuse.as_ref().expect("a diffuse scene");
        let table: &LightTable = diffuse.lights.as_deref().expect("chosen by power");
        let area = &scene.lights.area;
        // The vertices: the origin, and points just in front of and behind each light's centre.
        let mut points = vec![Vec3::ZERO];
        for (light, _) in area.sampled() {
            let centre = (light.corners[0] + light.corners[1] + light.corners[2]) / 3.0;
            points.extend([centre + 0.02 * light.normal, centre - 0.05 * light.normal]);
        }
        let mut selects: Vec<f32> = (0..4096).map(|k| k as f32 / 4096.0).collect();
        for &c in area.distribution().cdf() {
            selects.extend(
                [c.next_down(), c, c.next_up()]
                    .into_iter()
                    .filter(|u| (0.0..1.0).contains(u)),
            );
        }
        let mut checked = 0;
        for (c, chunk) in selects.chunks(LANES).enumerate() {
            let mut u_select = [0.5; LANES];
            u_select[..chunk.len()].copy_from_slice(chunk);
            let mut u = [[0.0; LANES]; 2];
            let mut p = V3::ZERO;
            for i in 0..LANES {
                u[0][i] = (i as f32 * 0.37 + u_select[i]).fract();
                u[1][i] = (i as f32 * 0.61 + 0.5 * u_select[i]).fract();
                p.set(i, points[(i + c) % points.len()]);
            }
            let isas = crate::isa::Isa::detected().map(Some).chain([None]);
            let wants = [true; LANES];
            for got in isas.map(|isa| table.sample(&u_select, &u, &p, &wants, isa)) {
                for i in 0..chunk.len() {
                    let Some(ls) = area.sample(
                        p.get(i),
                        Vec3::Z,
                        u_select[i],
                        glam::Vec2::new(u[0][i], u[1][i]),
                    ) else {
                        // No valid point: the lane's density says so.
                        assert_eq!(got.pdf_area[i], 0.0, "{name}: u_select {}", u_select[i]);
                        continue;
                    };
                    let (light, _) = area
                        .sampled()
                        .find(|&(_, tri)| tri == ls.triangle)
                        .expect("a light");
                    by_solid_angle += usize::from(
                        crate::light::by_solid_angle(
                            light.corners,
                            light.normal,
                            light.longest_edge2,
                            p.get(i),
                        )
                        .is_some(),
                    );
                    let m = &diffuse.materials[scene.mesh.material[ls.triangle as usize] as usize];
                    let bits = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
                    assert_eq!(
                        (
                            bits(got.point.get(i)),
                            bits(got.normal.get(i)),
                            got.pdf_area[i].to_bits(),
                            bits(got.front.get(i)),
                            bits(got.back.get(i))
                        ),
                        (
                            bits(ls.point),
                            bits(ls.normal),
                            ls.pdf_area.to_bits(),
                            bits(m.emission_front),
                            bits(m.emission_back)
                        ),
                        "{name}: u_select {}",
                        u_select[i]
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 4096);
    }
    assert!(
        by_solid_angle > 1000,
        "{by_solid_angle} samples by solid angle"
    );
}

/// An environment, one colour and an image, lights the lanes as it lights `trace_path`: each
/// vertex's light sample chooses between the image and the area lights as `light_query` chooses
/// (with the box's light, chosen from the table, and with the furnace's facets, chosen by the
/// tree), or always takes it (lamps and no emissive triangle; nothing but the environment), never
/// the one colour (`Lights::set_environment`), and a ray that
/// leaves the box through its open side takes its light, in full from the camera and weighted by
/// the power heuristic after a bounce.
#[test]
fn the_environment_lights_the_lanes_as_it_lights_the_scalar_integrator() {
    use crate::light::{map_for_tests, Environment, PointLight, PunctualLight};
    let sky = || Environment::uniform(Vec3::new(0.6, 0.75, 1.0)).expect("a valid colour");
    let image = || {
        let texels = (0..16 * 8)
            .map(|i| Vec3::new(0.2 + (i % 16) as f32 * 0.1, 1.0 + (i / 16) as f32, 0.5))
            .collect();
        map_for_tests(16, 8, texels, 30.0)
    };
    let box_alone = scene(parts("cornell"));
    for (k, env) in [sky(), image()].into_iter().enumerate() {
        let lit = scene(parts("cornell")).with_environment(Some(env.clone()));
        let p_env = lit.lights.environment_choice;
        if env.is_uniform() {
            assert_eq!(p_env, 0.0, "one colour is left to the BSDF's samples");
        } else {
            assert!(p_env > 0.0 && p_env < 1.0, "both families are sampled");
        }
        assert!(lit.diffuse.is_some(), "the lanes take an environment");
        assert!(
            pixels_that_differ(&box_alone, &lit, &settings(1, RussianRoulette::Auto, None)) > 100,
            "the environment is seen"
        );
        for (seed, rr) in [(21, RussianRoulette::Auto), (22, RussianRoulette::Off)] {
            assert_same_bits(&lit, &settings(seed + k as u64, rr, None), 0..6);
        }
        // No emissive triangle: every light sample is the environment's, beside a lamp's.
        let mut p = parts("cornell");
        for m in &mut p.materials {
            m.emissive = Vec3::ZERO;
        }
        let environment_only = scene(p.clone()).with_environment(Some(env.clone()));
        let only_choice = environment_only.lights.environment_choice;
        assert_eq!(only_choice, if env.is_uniform() { 0.0 } else { 1.0 });
        assert_same_bits(
            &environment_only,
            &settings(23, RussianRoulette::Auto, None),
            0..6,
        );
        let corners = p.mesh.positions.iter().flatten();
        let (lo, hi) = corners.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(*c), hi.max(*c))
        });
        p.punctual_lights = vec![PunctualLight::Point(PointLight {
            position: lo + (hi - lo) * Vec3::new(0.4, 0.7, 0.5),
            intensity: Vec3::splat(0.3) * (hi - lo).length_squared(),
        })];
        let with_lamp = scene(p).with_environment(Some(env.clone()));
        assert_same_bits(
            &with_lamp,
            &settings(24, RussianRoulette::Auto, Some(3)),
            0..6,
        );
        // Many lights, chosen by the tree, and the environment's share of the samples.
        let furnace = scene(parts("furnace")).with_environment(Some(env));
        assert!(furnace.lights.area.has_tree() && furnace.diffuse.is_some());
        assert_same_bits(&furnace, &settings(25, RussianRoulette::Auto, None), 0..4);
    }
}

/// A scene of more lights than the table holds chooses by the light tree, lane by lane: the
/// choice, the point and the density of a BSDF ray's hit at each lane's own vertex, as
/// `trace_path` makes them (1,280 emitting facets around the camera).
#[test]
fn a_scene_of_many_lights_chooses_by_the_tree_as_the_scalar_integrator_does() {
    let furnace = scene(parts("furnace"));
    assert!(
        furnace.lights.area.has_tree(),
        "the furnace has many lights"
    );
    let diffuse = furnace
        .diffuse
        .as_ref()
        .expect("the lanes model the furnace");
    assert!(diffuse.lights.is_none(), "no table: chosen by the tree");
    for (k, (rr, max_depth)) in [
        (RussianRoulette::Auto, None),
        (RussianRoulette::Off, Some(4)),
    ]
    .into_iter()
    .enumerate()
    {
        assert_same_bits(&furnace, &settings(k as u64 + 11, rr, max_depth), 0..4);
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

/// Textures: the shipped textured scene (a Lambertian floor with a base colour texture; a
/// sphere with base colour, metallic-roughness and normal textures, and tangents), then with its
/// roughness texture reaching zero somewhere and with texels of every kind (a general
/// material), without tangents, and with base
/// colours alone on a metal and a plastic sphere; each hit's texels read and its frame oriented
/// as `Scene::bsdf_at` does, in the world-space mesh and in instances (one mirrored: its
/// barycentrics swap, its texture coordinates must not, its tangents' handedness flips).
#[test]
fn textures_are_read_as_the_scalar_integrator_reads_them() {
    use crate::geometry::{Mesh, Placement};
    use glam::{DMat4, DQuat, DVec3};
    let shipped = scene(parts("textured"));
    assert!(shipped.diffuse.as_ref().is_some_and(|d| d.tangents));
    for (seed, rr) in [
        (54, RussianRoulette::Auto),
        (55, RussianRoulette::Fixed(0.7)),
    ] {
        assert_same_bits(&shipped, &settings(seed, rr, None), 0..6);
    }
    let mut p = parts("textured");
    let sphere = p
        .materials
        .iter()
        .position(|m| m.normal_texture.is_some())
        .expect("the sphere's material");
    // The sphere a normal-mapped Lambertian: the cosine lobe's frame oriented by the tangent.
    let mut matte = p.clone();
    (
        matte.materials[sphere].metallic,
        matte.materials[sphere].specular,
    ) = (0.0, 0.0);
    let matte = scene(matte);
    assert!(matte.diffuse.as_ref().is_some_and(|d| d.tangents));
    assert_same_bits(&matte, &settings(57, RussianRoulette::Auto, None), 0..6);
    // Lit by a lamp as well (`light_punctual`'s glossy evaluation), and the sphere an
    // untextured mirror on its tangents (`scatter_lane_by_lane`'s frame).
    let mut lamp = p.clone();
    let (lo, hi) = lamp.mesh.bounds();
    lamp.punctual_lights = vec![crate::light::PunctualLight::Point(
        crate::light::PointLight {
            position: (lo + hi) * 0.5 + Vec3::new(0.2, 0.3, 0.1) * (hi - lo),
            intensity: Vec3::splat((hi - lo).length_squared()),
        },
    )];
    let mut mirror = lamp.clone();
    let mut lamp = scene(lamp);
    assert!(lamp.diffuse.as_ref().is_some_and(|d| d.tangents));
    assert_same_bits(&lamp, &settings(58, RussianRoulette::Auto, None), 0..6);
    // The lamp chosen lane by lane (`light_punctual`'s other path).
    lamp.lights.choose_punctual_by_power();
    assert_same_bits(&lamp, &settings(60, RussianRoulette::Auto, None), 0..6);
    let m = &mut mirror.materials[sphere];
    (
        m.base_color_texture,
        m.metallic_roughness_texture,
        m.normal_texture,
    ) = (None, None, None);
    (m.metallic, m.roughness) = (1.0, 0.0);
    let mirror = scene(mirror);
    assert!(mirror.diffuse.as_ref().is_some_and(|d| d.tangents));
    assert_same_bits(&mirror, &settings(59, RussianRoulette::Auto, None), 0..6);
    let rough = p.materials[sphere]
        .metallic_roughness_texture
        .as_ref()
        .expect("a metallic-roughness texture")
        .texture as usize;
    // A roughness texture that reaches zero: a kind that changes from texel to texel, general
    // (`lanes/general.rs`), its texels made into its BSDF lane by lane.
    let mut smooth_somewhere = p.clone();
    smooth_somewhere.textures[rough].texels[0][1] = 0;
    let smooth_somewhere = scene(smooth_somewhere);
    let d = smooth_somewhere
        .diffuse
        .as_ref()
        .expect("a general material");
    assert!(d.materials[sphere].general && !d.materials[sphere].textured);
    assert_same_bits(
        &smooth_somewhere,
        &settings(61, RussianRoulette::Auto, None),
        0..6,
    );
    // Texels of every kind on one general material: a band of pure Lambertian texels (no
    // specular layer, metallic zero: no lobe value drawn), a band of mirror texels (metallic one,
    // roughness zero: delta lobes only, no light sample), glossy metal between.
    let mut kinds = p.clone();
    let m = &mut kinds.materials[sphere];
    (m.specular, m.metallic, m.roughness) = (0.0, 1.0, 1.0);
    let texels = &mut kinds.textures[rough].texels;
    let n = texels.len();
    for (k, t) in texels.iter_mut().enumerate() {
        match 3 * k / n {
            0 => t[2] = 0,
            1 => (t[1], t[2]) = (0, 255),
            _ => (t[1], t[2]) = (t[1].max(40), 255),
        }
    }
    let kinds = scene(kinds);
    assert!(kinds
        .diffuse
        .as_ref()
        .is_some_and(|d| d.materials[sphere].general));
    let first = settings(1, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&kinds, &smooth_somewhere, &first) > 100);
    for (seed, rr) in [(63, RussianRoulette::Auto), (64, RussianRoulette::Max)] {
        assert_same_bits(&kinds, &settings(seed, rr, None), 0..6);
    }
    // Without tangents, the normal map changes nothing (as in `Material::shade`).
    p.mesh.tangents = None;
    let untangled = scene(p.clone());
    assert!(untangled.diffuse.as_ref().is_some_and(|d| !d.tangents));
    assert!(
        pixels_that_differ(
            &shipped,
            &untangled,
            &settings(1, RussianRoulette::Auto, None)
        ) > 100
    );
    assert_same_bits(&untangled, &settings(56, RussianRoulette::Auto, None), 0..6);
    p.materials[sphere].normal_texture = None;
    p.materials[sphere].metallic_roughness_texture = None;
    p.materials[sphere].roughness = 0.35;
    // Textured and transmitting: general too, on its base colour's texels.
    let mut other = p.clone();
    other.materials[sphere].transmission = 1.0;
    let other = scene(other);
    assert!(other
        .diffuse
        .as_ref()
        .is_some_and(|d| d.materials[sphere].general));
    assert_same_bits(&other, &settings(62, RussianRoulette::Auto, None), 0..6);
    let untextured = {
        let mut q = p.clone();
        for m in &mut q.materials {
            m.base_color_texture = None;
        }
        scene(q)
    };
    let s = settings(1, RussianRoulette::Auto, None);
    for metallic in [1.0, 0.0] {
        p.materials[sphere].metallic = metallic;
        let textured = scene(p.clone());
        let d = textured
            .diffuse
            .as_ref()
            .expect("the lanes take base colours");
        assert_eq!(d.materials.iter().filter(|m| m.textured).count(), 2);
        assert!(pixels_that_differ(&textured, &untextured, &s) > 300);
        for (seed, rr) in [
            (51, RussianRoulette::Auto),
            (52, RussianRoulette::Fixed(0.7)),
        ] {
            assert_same_bits(&textured, &settings(seed, rr, None), 0..6);
        }
    }
    // The shipped scene's textured triangles, with their tangents and the materials as shipped,
    // as a prototype placed three times inside the box (whose world-space mesh has no tangents
    // now: its hits' frames are oriented as without).
    let shipped = parts("textured");
    p.materials = shipped.materials.clone();
    let textured_material = |m: u32| p.materials[m as usize].base_color_texture.is_some();
    let pick = |t: usize| textured_material(shipped.mesh.material[t]);
    let keep: Vec<usize> = (0..shipped.mesh.len()).filter(|&t| pick(t)).collect();
    fn attribute<T: Copy>(a: &Option<Vec<T>>, keep: &[usize]) -> Option<Vec<T>> {
        a.as_ref().map(|a| keep.iter().map(|&t| a[t]).collect())
    }
    let proto = Mesh {
        positions: keep.iter().map(|&t| shipped.mesh.positions[t]).collect(),
        material: keep.iter().map(|&t| shipped.mesh.material[t]).collect(),
        uv0: attribute(&shipped.mesh.uv0, &keep),
        normals: attribute(&shipped.mesh.normals, &keep),
        tangents: attribute(&shipped.mesh.tangents, &keep),
        ..Mesh::default()
    };
    assert!(proto.uv0.is_some() && proto.tangents.is_some());
    let (lo, hi) = proto.bounds();
    let (c, size) = (((lo + hi) * 0.5).as_dvec3(), (hi - lo).as_dvec3());
    let place = |at: DVec3, scale: DVec3, turn: f64| Placement {
        prototype: 0,
        to_world: DMat4::from_scale_rotation_translation(
            scale,
            DQuat::from_euler(glam::EulerRot::YXZ, turn, 0.2 * turn, 0.0),
            c + size * at,
        ) * DMat4::from_translation(-c),
    };
    p.prototypes = vec![proto];
    p.placements = vec![
        place(DVec3::new(-0.2, 0.3, 0.1), DVec3::splat(0.3), 0.5),
        place(
            DVec3::new(0.25, 0.2, -0.1),
            DVec3::new(-0.25, 0.25, 0.25),
            -0.8,
        ),
        place(DVec3::new(0.0, 0.4, 0.2), DVec3::splat(0.2), 2.0),
    ];
    let placed = scene(p);
    assert_eq!(placed.info.instances, 3);
    assert!(placed.diffuse.as_ref().is_some_and(|d| d.tangents));
    let plain = scene(parts("textured"));
    assert!(pixels_that_differ(&placed, &plain, &s) > 300);
    assert_same_bits(&placed, &settings(53, RussianRoulette::Auto, None), 0..6);
}

/// Emissive textures: the textured scene's tiled floor made to glow through its base colour
/// texture, the texel read where a ray meets it (`trace_closest`) and where a light sample lands
/// on it (`take_light`, the lanes sampling lights lane by lane), by the light tree and by power.
#[test]
fn emissive_textures_light_the_lanes_as_they_light_the_scalar_integrator() {
    let mut p = parts("textured");
    let floor = p
        .materials
        .iter()
        .position(|m| m.name.as_deref() == Some("floor_tiles"))
        .expect("the textured scene's floor");
    let m = &mut p.materials[floor];
    m.emissive = Vec3::new(0.5, 0.4, 0.3);
    m.emissive_texture = m.base_color_texture.clone();
    assert!(m.emissive_texture.is_some());
    let mut plain = p.clone();
    plain.materials[floor].emissive_texture = None;
    let mut glowing = scene(p);
    let lanes = glowing
        .diffuse
        .as_ref()
        .expect("the lanes take emissive textures");
    assert!(lanes.materials[floor].emissive_textured && lanes.lights.is_none());
    let s = settings(61, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&glowing, &scene(plain), &s) > 300);
    assert_same_bits(&glowing, &s, 0..6);
    assert_same_bits(&glowing, &settings(62, RussianRoulette::Max, None), 0..6);
    // The lights chosen by power, whatever the scene's own choice.
    glowing.lights.area.choose_by_power();
    assert!(!glowing.lights.area.has_tree());
    assert_same_bits(&glowing, &settings(63, RussianRoulette::Auto, None), 0..6);
}
