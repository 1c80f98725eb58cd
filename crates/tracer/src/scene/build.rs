//! Building a scene: the checks, the instanced meshes' BVHs, the assembly of parts built already.

use super::{Scene, SceneError, SceneInfo, SceneParts, World};
use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::geometry::{usable_placements, Instances, Mesh, Prototype, Unplaced};
use crate::integrator::DiffuseScene;
use crate::light::{Lights, PunctualLight};
use crate::material::{Material, Texture};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Arc;

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
            caustics: std::sync::OnceLock::new(),
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
