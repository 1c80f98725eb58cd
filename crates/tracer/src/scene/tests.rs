//! Tests of the scene: BSDF templates against BSDFs made at the hit, `check` against `build`.

use super::*;
use crate::bsdf::Bsdf;
use crate::geometry::{Mesh, Placement};
use crate::material::{Material, Texture, TextureRef, TextureSampler};
use glam::{Vec2, Vec3, Vec4};

/// A material's BSDF made once and moved to each hit is the BSDF made at the hit, for every kind
/// of material; textured ones are shaded at the hit.
#[test]
fn bsdf_templates_equal_the_bsdf_made_at_the_hit() {
    let tex = |texture: u32| {
        Some(TextureRef {
            texture,
            texcoord: 0,
            transform: None,
        })
    };
    let materials = vec![
        Material {
            metallic: 0.0,
            specular: 0.0,
            base_color: Vec4::new(0.7, 0.2, 0.1, 1.0),
            ..Material::default()
        },
        Material {
            roughness: 0.3,
            ..Material::default()
        },
        Material {
            metallic: 0.0,
            roughness: 0.0,
            transmission: 1.0,
            ior: 1.33,
            ..Material::default()
        },
        Material {
            metallic: 0.2,
            roughness: 1.7, // out of range: sanitised the same way on both paths
            specular_color: Vec3::new(0.5, 1.0, 2.0),
            ..Material::default()
        },
        Material {
            metallic: 0.0,
            base_color_texture: tex(0),
            ..Material::default()
        },
    ];
    let mut mesh = Mesh::default();
    for m in 0..materials.len() as u32 {
        let x = m as f32 * 2.0;
        mesh.positions.push([
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 1.0, 0.0, 0.0),
            Vec3::new(x, 1.0, 0.0),
        ]);
        mesh.material.push(m);
    }
    let texels = vec![[10, 200, 30, 255], [250, 0, 128, 255]];
    let texture = Texture::new(None, 2, 1, texels, TextureSampler::default()).unwrap();
    let scene = Scene::build(SceneParts {
        mesh,
        materials,
        textures: vec![texture],
        ..SceneParts::default()
    })
    .unwrap();
    assert!(scene.bsdf_templates[..4].iter().all(Option::is_some));
    assert!(scene.bsdf_templates[4].is_none(), "a textured material");

    let ns = Vec3::new(0.3, -0.2, 0.9).normalize();
    let ng = Vec3::new(0.1, 0.0, 1.0).normalize();
    for material in 0..5u32 {
        for tangent in [None, Some(Vec4::new(1.0, 0.2, 0.0, 1.0))] {
            for u in [0.1f32, 0.9] {
                let si = SurfaceInteraction {
                    p: Vec3::ZERO,
                    clearance: 0.0,
                    ng,
                    ns,
                    uv: [Vec2::new(u, 0.5), Vec2::ZERO],
                    tangent,
                    material,
                    triangle: material,
                    front: true,
                };
                let m = &scene.materials[material as usize];
                let shading = m.shade(&scene.textures, &si.uv, ns, tangent);
                let made_here = Bsdf::with_coat_normal(
                    shading.params,
                    shading.normal,
                    ng,
                    tangent.map(|t| t.truncate()),
                    shading.coat_normal,
                );
                // Debug prints every field, floats to the last bit.
                assert_eq!(
                    format!("{:?}", scene.bsdf_at(&si)),
                    format!("{made_here:?}"),
                    "material {material}, tangent {tangent:?}, u {u}"
                );
            }
        }
    }
    // The texture is really read: its two texels give two different BSDFs.
    let at = |u: f32| SurfaceInteraction {
        p: Vec3::ZERO,
        clearance: 0.0,
        ng,
        ns,
        uv: [Vec2::new(u, 0.5), Vec2::ZERO],
        tangent: None,
        material: 4,
        triangle: 4,
        front: true,
    };
    assert_ne!(
        scene.bsdf_at(&at(0.1)).params().base_color,
        scene.bsdf_at(&at(0.9)).params().base_color
    );
}

/// `Scene::check` passes exactly the parts `Scene::build` builds, with the same warnings, and
/// refuses the others with the same error: good scenes (world-space, instanced, some of each
/// degenerate or unplaced) and every kind of broken one.
#[test]
fn check_agrees_with_build() {
    use glam::DMat4;
    let tri = |x: f32| {
        [
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 1.0, 0.0, 0.0),
            Vec3::new(x, 1.0, 0.0),
        ]
    };
    let flat = |x: f32| {
        [
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 1.0, 0.0, 0.0),
            Vec3::new(x + 2.0, 0.0, 0.0),
        ]
    };
    let mesh = |positions: Vec<[Vec3; 3]>, material: u32| Mesh {
        material: vec![material; positions.len()],
        positions,
        ..Mesh::default()
    };
    let place = |prototype: u32, scale: f64| Placement {
        prototype,
        to_world: DMat4::from_scale(glam::DVec3::splat(scale)),
    };
    let base = SceneParts {
        materials: vec![
            Material::default(),
            Material {
                emissive: Vec3::ONE,
                ..Material::default()
            },
        ],
        warnings: vec!["a loader's warning".into()],
        ..SceneParts::default()
    };
    let with = |f: &dyn Fn(&mut SceneParts)| {
        let mut p = base.clone();
        f(&mut p);
        p
    };
    let cases: Vec<(&str, SceneParts)> = vec![
        ("empty", base.clone()),
        (
            "world",
            with(&|p| p.mesh = mesh(vec![tri(0.0), tri(2.0)], 1)),
        ),
        (
            "some degenerate",
            with(&|p| p.mesh = mesh(vec![tri(0.0), flat(2.0)], 0)),
        ),
        (
            "all degenerate",
            with(&|p| p.mesh = mesh(vec![flat(0.0), flat(2.0)], 0)),
        ),
        (
            "all dropped by the loader",
            with(&|p| p.degenerate_dropped = 3),
        ),
        (
            "material out of range",
            with(&|p| p.mesh = mesh(vec![tri(0.0)], 2)),
        ),
        (
            "attributes disagree",
            with(&|p| {
                p.mesh = mesh(vec![tri(0.0)], 0);
                p.mesh.normals = Some(vec![]);
            }),
        ),
        (
            "instanced",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 0)];
                p.placements = vec![place(0, 1.0), place(0, 2.0)];
            }),
        ),
        (
            "one placement singular",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 0)];
                p.placements = vec![place(0, 1.0), place(0, 0.0)];
            }),
        ),
        (
            "every placement singular",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 0)];
                p.placements = vec![place(0, 0.0)];
            }),
        ),
        (
            "singular placements beside world triangles",
            with(&|p| {
                p.mesh = mesh(vec![tri(5.0)], 0);
                p.prototypes = vec![mesh(vec![tri(0.0)], 0)];
                p.placements = vec![place(0, 0.0)];
            }),
        ),
        (
            "a degenerate prototype",
            with(&|p| {
                p.prototypes = vec![mesh(vec![flat(0.0)], 0)];
                p.placements = vec![place(0, 1.0)];
            }),
        ),
        (
            "an emissive prototype",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 1)];
                p.placements = vec![place(0, 1.0)];
            }),
        ),
        (
            "a prototype's material out of range",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 7)];
                p.placements = vec![place(0, 1.0)];
            }),
        ),
        (
            "a placement of no prototype",
            with(&|p| {
                p.prototypes = vec![mesh(vec![tri(0.0)], 0)];
                p.placements = vec![place(3, 1.0)];
            }),
        ),
    ];
    let mut refused = 0;
    for (name, parts) in cases {
        let checked = Scene::check(parts.clone()).map_err(|e| e.to_string());
        let built = Scene::build(parts)
            .map(|s| s.info.warnings)
            .map_err(|e| e.to_string());
        assert_eq!(checked, built, "{name}");
        refused += usize::from(built.is_err());
    }
    assert_eq!(refused, 9, "the broken cases are refused");
}
