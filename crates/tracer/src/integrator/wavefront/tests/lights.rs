//! Lights in the lanes against `trace_path`: the light table, the environment, the light tree,
//! emissive textures.

use super::*;

/// The lanes' choice of light and point is `AreaLights::sample`'s, bit for bit, on a grid of
/// samples and on each CDF value and its neighbours (where the choice changes), seen from points
/// far from the lights and close to them (where the point is sampled by solid angle).
#[test]
fn the_light_table_samples_what_area_lights_sample() {
    use crate::integrator::wavefront::lights::LightTable;
    use crate::integrator::wavefront::{LANES, V3};
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
