//! Materials beyond the Lambertian in the lanes against `trace_path`: alpha, general materials,
//! absorbing volumes, specular and glossy materials.

use super::*;

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
