//! The renderable scene: world-space triangles with their BVH, materials, textures, lights and the
//! camera. Built once (from glTF by [`crate::gltf`], or by hand in tests) and then only read, from any
//! number of threads.

mod bundle;
mod intersect;
mod world;

pub(crate) use intersect::shading_normal;
pub use intersect::{Hit, SurfaceInteraction};
pub use world::World;

use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::geometry::{
    usable_placements, Bvh, InstanceError, Instances, Mesh, MeshError, Placement, Prototype,
    Unplaced,
};
use crate::integrator::DiffuseScene;
use crate::light::{Environment, Lights, PunctualLight};
use crate::material::{Material, Texture};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Arc;

/// What a loader hands to [`Scene::build`].
#[derive(Clone, Debug, Default)]
pub struct SceneParts {
    /// The triangles placed once, in world space.
    pub mesh: Mesh,
    /// Meshes kept once in their own space and placed by `placements` (a two-level BVH, see
    /// [`crate::geometry::Instances`]). None of their materials may emit: lights are sampled over
    /// world-space triangles, so emissive meshes are flattened into `mesh`.
    pub prototypes: Vec<Mesh>,
    pub placements: Vec<Placement>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub punctual_lights: Vec<PunctualLight>,
    /// `None`: frame the scene with a default camera.
    pub camera: Option<Camera>,
    /// Things the loader ignored or worked around, reported once each.
    pub warnings: Vec<String>,
    /// Degenerate triangles the loader already dropped (they are not in `mesh`).
    pub degenerate_dropped: usize,
}

impl SceneParts {
    /// These parts with every instanced mesh flattened into world-space triangles (see
    /// [`crate::geometry::flatten_into`]).
    pub fn flatten_instances(mut self) -> SceneParts {
        crate::geometry::flatten_into(&self.prototypes, &self.placements, &mut self.mesh);
        self.prototypes.clear();
        self.placements.clear();
        self
    }
}

/// Facts about a built scene, for logs and reports.
#[derive(Clone, Debug, Default)]
pub struct SceneInfo {
    /// Triangles stored: the world-space ones and each instanced mesh once.
    pub triangles: usize,
    /// Placements of instanced meshes, and the triangles they place (each mesh's count once per
    /// placement).
    pub instances: usize,
    pub instanced_triangles: u64,
    /// Zero-area (or non-finite) triangles dropped, by the loader or at build time.
    pub degenerate_dropped: usize,
    pub emissive_triangles: usize,
    pub punctual_lights: usize,
    pub bvh_nodes: usize,
    /// Wall seconds the world-space mesh's BVH took to build (the instanced meshes' trees not
    /// counted).
    pub bvh_seconds: f64,
    /// Approximate bytes held by geometry, BVH and textures.
    pub bytes: usize,
    pub warnings: Vec<String>,
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
}

/// Why a scene cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    Instance(#[from] InstanceError),
    #[error("instanced mesh {prototype}: {source}")]
    PrototypeMesh { prototype: usize, source: MeshError },
    #[error("instanced mesh {prototype}: triangle {triangle} refers to material {material}, but the scene has {count} materials")]
    PrototypeMaterial {
        prototype: usize,
        triangle: usize,
        material: u32,
        count: usize,
    },
    /// Lights are sampled over world-space triangles: an emissive mesh must be flattened.
    #[error("instanced mesh {prototype} uses emissive material {material}; emissive meshes must be placed as world-space triangles")]
    EmissivePrototype { prototype: usize, material: u32 },
    /// Every triangle of the scene was degenerate: a scene made only of unrenderable geometry is
    /// broken input, not an empty scene (which has no triangles at all).
    #[error("all {dropped} triangles of the scene are degenerate (zero area or non-finite corners); nothing can be rendered")]
    AllDegenerate { dropped: usize },
    #[error(
        "triangle {triangle} refers to material {material}, but the scene has {count} materials"
    )]
    MaterialIndex {
        triangle: usize,
        material: u32,
        count: usize,
    },
}

/// A scene ready to render. Its geometry and textures are shared (`Arc`): the scenes an animation's
/// frames make hold what does not move between frames once.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The world-space triangles (those placed once, and every emitter), in the loader's order.
    pub mesh: Arc<Mesh>,
    pub bvh: Arc<Bvh>,
    /// Instanced meshes and their placements (empty for most scenes, and then free).
    pub instances: Instances,
    pub materials: Vec<Material>,
    pub textures: Arc<[Texture]>,
    pub lights: Lights,
    pub camera: Camera,
    pub info: SceneInfo,
    /// Some material has alpha (MASK or BLEND): intersection must test coverage.
    any_alpha: bool,
    /// Some material has a volume: paths track whether they are inside one.
    pub(crate) any_volume: bool,
    /// Per material, its BSDF when no texture varies it (at a placeholder frame; see
    /// [`Scene::bsdf_at`]). Derived from `materials` at build time.
    bsdf_templates: Vec<Option<Bsdf>>,
    /// What the wavefront integrator needs, for a scene it can render. Derived at build time.
    pub(crate) diffuse: Option<DiffuseScene>,
}

impl Scene {
    /// Drops degenerate triangles, builds the BVH and the light distributions.
    pub fn build(parts: SceneParts) -> Result<Scene, SceneError> {
        let SceneParts {
            mesh,
            prototypes,
            placements,
            materials,
            textures,
            punctual_lights,
            camera,
            warnings,
            degenerate_dropped: dropped_by_loader,
        } = parts;
        let world = World::build(mesh, &materials, &textures)?;
        let (prototypes, prototype_dropped) = build_prototypes(prototypes, &materials)?;
        // Drop zero-area and non-finite triangles: they cannot be hit, sampled or shaded.
        let (instances, unplaced) = Instances::place(prototypes, &placements)?;
        let degenerate_dropped = degenerate(
            dropped_by_loader + world.dropped + prototype_dropped,
            unplaced,
            world.mesh.is_empty() && instances.is_empty(),
        )?;
        Ok(Scene::assemble(Assembly {
            world: &world,
            instances,
            materials,
            textures: textures.into(),
            punctual_lights,
            camera,
            warnings,
            degenerate_dropped,
        }))
    }

    /// Everything [`Scene::build`] checks, without building anything (no BVH, no light
    /// distributions): `Ok` exactly when `build` of the same parts succeeds, with the loader's
    /// warnings. What a server runs on a submitted scene that its workers will build.
    pub fn check(parts: SceneParts) -> Result<Vec<String>, SceneError> {
        let SceneParts {
            mesh,
            prototypes,
            placements,
            materials,
            warnings,
            degenerate_dropped: dropped_by_loader,
            ..
        } = parts;
        let (mesh, world_dropped) = World::checked(mesh, &materials)?;
        let (prototypes, prototype_dropped) = checked_prototypes(prototypes, &materials)?;
        let triangles: Vec<usize> = prototypes.iter().map(Mesh::len).collect();
        let (usable, unplaced) = usable_placements(&triangles, &placements)?;
        degenerate(
            dropped_by_loader + world_dropped + prototype_dropped,
            unplaced,
            mesh.is_empty() && usable.is_empty(),
        )?;
        Ok(warnings)
    }

    /// A scene of parts built already (and perhaps shared with other scenes): only the light
    /// choice, the default camera and what is derived from the materials are made here.
    pub fn assemble(a: Assembly<'_>) -> Scene {
        let Assembly {
            world,
            instances,
            materials,
            textures,
            punctual_lights,
            camera,
            warnings,
            degenerate_dropped,
        } = a;
        let (mut lo, mut hi) = world.bounds();
        if let Some((ilo, ihi)) = instances.bounds() {
            lo = lo.min(ilo);
            hi = hi.max(ihi);
        }
        if world.mesh.is_empty() && instances.is_empty() {
            lo = Vec3::ZERO;
            hi = Vec3::ZERO;
        }
        let radius = 0.5 * (hi - lo).length();
        let lights = Lights::new(world.area.clone(), punctual_lights, radius.max(1e-3));
        let camera = camera.unwrap_or_else(|| Camera::framing(0.5 * (lo + hi), radius.max(1e-3)));
        let mesh = world.mesh.clone();
        let bvh = world.bvh.clone();
        let info = SceneInfo {
            triangles: mesh.len() + instances.stored_triangles(),
            instances: instances.instances.len(),
            instanced_triangles: instances.placed_triangles(),
            degenerate_dropped,
            emissive_triangles: lights.area.triangles.len(),
            punctual_lights: lights.punctual.len(),
            bvh_nodes: bvh.node_count(),
            bvh_seconds: world.bvh_seconds,
            bytes: mesh.bytes()
                + bvh.bytes()
                + instances.bytes()
                + textures.iter().map(Texture::bytes).sum::<usize>(),
            warnings,
            bounds_min: lo,
            bounds_max: hi,
        };
        let any_alpha = materials.iter().any(Material::has_alpha);
        let any_volume = materials
            .iter()
            .any(|m| m.volume.is_some() && m.transmission > 0.0);
        let bsdf_templates = materials
            .iter()
            .map(|m| {
                m.constant_params()
                    .map(|p| Bsdf::new(p, Vec3::Z, Vec3::Z, None))
            })
            .collect::<Vec<_>>();
        let diffuse = DiffuseScene::new(
            &materials,
            &bsdf_templates,
            &textures,
            &mesh,
            &instances,
            &lights,
        );
        tracing::debug!(
            wavefront = diffuse.is_some(),
            "whether the scene's materials and lights let the wavefront lanes render it"
        );
        Scene {
            bsdf_templates,
            diffuse,
            mesh,
            bvh,
            instances,
            materials,
            textures,
            lights,
            camera,
            info,
            any_alpha,
            any_volume,
        }
    }

    /// True if some material has alpha (MASK or BLEND).
    #[inline]
    pub fn any_alpha(&self) -> bool {
        self.any_alpha
    }

    /// The shading normal and the BSDF of textured material `material` at `hit`, whose
    /// interpolated shading normal is `ns` and tangent `tangent`: what [`Scene::bsdf_at`] reads
    /// there, the BSDF in a frame of its own (`Bsdf::at` moves it to the normal), for a material
    /// without a clear coat (whose normal it leaves out).
    pub(crate) fn textured_bsdf(
        &self,
        material: u32,
        hit: &Hit,
        ns: Vec3,
        tangent: Option<glam::Vec4>,
    ) -> (Vec3, Bsdf) {
        let m = &self.materials[material as usize];
        let shading = m.shade(&self.textures, &self.hit_uv(hit), ns, tangent);
        let bsdf = Bsdf::new(shading.params, Vec3::Z, Vec3::Z, None);
        (shading.normal, bsdf)
    }

    /// The BSDF at a surface point: the material's textures evaluated there, or, for a material
    /// without them, its BSDF made once at build time and moved to the point (the same value).
    #[inline]
    pub fn bsdf_at(&self, si: &SurfaceInteraction) -> Bsdf {
        self.bsdf_of(si.material, si.ns, si.ng, si.tangent, || si.uv)
    }

    /// [`Scene::bsdf_at`] at a hit whose normals (`ns`, `ng`) and tangent are known, its texture
    /// coordinates read only if the material is textured (the wavefront's lanes, which make the
    /// surface's parts in their own steps).
    #[inline]
    pub(crate) fn hit_bsdf(
        &self,
        material: u32,
        hit: &Hit,
        ns: Vec3,
        ng: Vec3,
        tangent: Option<glam::Vec4>,
    ) -> Bsdf {
        self.bsdf_of(material, ns, ng, tangent, || self.hit_uv(hit))
    }

    #[inline(always)]
    fn bsdf_of(
        &self,
        material: u32,
        ns: Vec3,
        ng: Vec3,
        tangent4: Option<glam::Vec4>,
        uv: impl FnOnce() -> [glam::Vec2; 2],
    ) -> Bsdf {
        let tangent = tangent4.map(|t| t.truncate());
        if let Some(Some(template)) = self.bsdf_templates.get(material as usize) {
            return template.at(ns, ng, tangent);
        }
        let m = &self.materials[material as usize];
        let shading = m.shade(&self.textures, &uv(), ns, tangent4);
        Bsdf::with_coat_normal(
            shading.params,
            shading.normal,
            ng,
            tangent,
            shading.coat_normal,
        )
    }

    /// Lights the scene with an environment (`None` takes it away). The environment is part of the
    /// render rather than of the glTF file, which cannot carry one; it takes its share of the light
    /// samples by power against the emissive triangles (see [`crate::light`]).
    pub fn with_environment(mut self, environment: Option<Environment>) -> Self {
        let radius = 0.5 * (self.info.bounds_max - self.info.bounds_min).length();
        self.lights.set_environment(environment, radius.max(1e-3));
        self.diffuse = DiffuseScene::new(
            &self.materials,
            &self.bsdf_templates,
            &self.textures,
            &self.mesh,
            &self.instances,
            &self.lights,
        );
        self
    }

    /// Replaces the camera (e.g. one chosen by name).
    pub fn with_camera(mut self, camera: Camera) -> Self {
        self.camera = camera;
        self
    }
}

/// What [`Scene::assemble`] puts together.
pub struct Assembly<'w> {
    /// The world-space triangles (their `Arc`s are shared with the new scene).
    pub world: &'w World,
    pub instances: Instances,
    pub materials: Vec<Material>,
    pub textures: Arc<[Texture]>,
    pub punctual_lights: Vec<PunctualLight>,
    /// `None`: frame the scene with a default camera.
    pub camera: Option<Camera>,
    pub warnings: Vec<String>,
    /// Degenerate triangles dropped on the way, everywhere.
    pub degenerate_dropped: usize,
}

/// Checks the instanced meshes against the materials (none may emit), drops their degenerate
/// triangles and builds each one's BVH; returns them and how many triangles were dropped.
pub fn build_prototypes(
    prototypes: Vec<Mesh>,
    materials: &[Material],
) -> Result<(Vec<Arc<Prototype>>, usize), SceneError> {
    let (prototypes, dropped) = checked_prototypes(prototypes, materials)?;
    let built = prototypes
        .into_iter()
        .map(|m| Arc::new(Prototype::new(m)))
        .collect();
    Ok((built, dropped))
}

/// What [`build_prototypes`] does before it builds anything: each mesh checked against the
/// materials (none may emit), without its degenerate triangles, and how many were dropped.
fn checked_prototypes(
    prototypes: Vec<Mesh>,
    materials: &[Material],
) -> Result<(Vec<Mesh>, usize), SceneError> {
    let mut prototypes = prototypes;
    let mut dropped = 0;
    for (prototype, proto) in prototypes.iter_mut().enumerate() {
        proto
            .validate()
            .map_err(|source| SceneError::PrototypeMesh { prototype, source })?;
        for (triangle, &material) in proto.material.iter().enumerate() {
            match materials.get(material as usize) {
                None => {
                    return Err(SceneError::PrototypeMaterial {
                        prototype,
                        triangle,
                        material,
                        count: materials.len(),
                    })
                }
                Some(m) if m.is_emissive() => {
                    return Err(SceneError::EmissivePrototype {
                        prototype,
                        material,
                    })
                }
                Some(_) => {}
            }
        }
        dropped += drop_degenerate(proto);
    }
    Ok((prototypes, dropped))
}

/// The degenerate triangles of a scene: those `dropped` and those the `unplaced` placements (a
/// singular transform) would have placed, which are as degenerate as a flattened copy of them
/// would be. A scene left with `nothing` to render after dropping some is an error.
fn degenerate(dropped: usize, unplaced: Unplaced, nothing: bool) -> Result<usize, SceneError> {
    if unplaced.placements > 0 {
        tracing::info!(
            placements = unplaced.placements,
            "dropped instances with singular transforms"
        );
    }
    let dropped = dropped + unplaced.triangles;
    if dropped > 0 {
        if nothing {
            return Err(SceneError::AllDegenerate { dropped });
        }
        tracing::info!(degenerate_dropped = dropped, "dropped zero-area triangles");
    }
    Ok(dropped)
}

/// Drops the mesh's zero-area and non-finite triangles (they cannot be hit, sampled or shaded);
/// returns how many.
pub(crate) fn drop_degenerate(mesh: &mut Mesh) -> usize {
    // In parallel, in order (rayon's collect keeps it).
    let keep: Vec<u32> = (0..mesh.len())
        .into_par_iter()
        .filter(|&i| mesh.is_renderable(i))
        .map(|i| i as u32)
        .collect();
    let dropped = mesh.len() - keep.len();
    if dropped > 0 {
        mesh.reorder(&keep);
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::Bsdf;
    use crate::material::{TextureRef, TextureSampler};
    use glam::{Vec2, Vec4};

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
}
