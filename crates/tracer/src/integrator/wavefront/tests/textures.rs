//! Textures, normal maps and tangents in the lanes against `trace_path`.

use super::*;

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
    // The mirror under the area light has a caustic guide: the textured, normal-mapped floor's
    // guided lanes sample its mixture with their texels' BSDF (`Lanes::guided_bsdf`).
    assert!(mirror.caustic_guide().is_some());
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
