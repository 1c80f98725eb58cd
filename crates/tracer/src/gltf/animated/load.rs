//! Loading an animated file once: the still loader's steps (`prepare`, the mesh builder), with the
//! animation read first so that the nodes it moves and the meshes it deforms are set apart:
//!
//! - what never moves is built now, once: the world-space triangles (meshes placed once by still
//!   nodes, still emitters, deformations that nothing animates) with their BVH and area lights,
//!   unless some emitter moves (then they are kept and rebuilt with it at every frame), and every
//!   mesh kept instanced, with its BVH;
//! - a mesh that a moving node places is kept instanced (`instancing`): a frame only moves its
//!   placement;
//! - a moving emitter (lights are sampled over world-space triangles) and a deformation that the
//!   animation drives (a skin whose joints move, a node whose morph weights are animated) keep
//!   their primitives, which each frame emits again.

use super::channels::{self, Target};
use super::deform::Deformable;
use super::pose::Hierarchy;
use super::skin::{skin_label, Skin};
use super::{
    placed, AnimatedScene, DeformedNode, Motion, MovingEmitter, PlacementSource, WorldSource,
};
use crate::gltf::accessors::Accessors;
use crate::gltf::document::Parsed;
use crate::gltf::error::{GltfError, Warnings};
use crate::gltf::instancing::mesh_may_emit;
use crate::gltf::mesh::MeshBuilder;
use crate::gltf::nodes::Instance;
use crate::gltf::prepare::{self, mesh_of};
use crate::gltf::resources::Resources;
use crate::gltf::{bounds, camera, gpu_instancing, LoadOptions, ResourceResolver};
use crate::scene::{build_prototypes, World};
use std::collections::hash_map::{Entry, HashMap};

pub(crate) fn load(
    parsed: Parsed<'_>,
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<AnimatedScene, GltfError> {
    let root = &parsed.root;
    let mut warnings = Warnings::default();
    for w in &parsed.warnings {
        warnings.once(w.clone());
    }
    let instances = prepare::scene_nodes(root, &mut warnings)?;
    let res = Resources::new(root, parsed.bin, resolver);
    let acc = Accessors::new(root, &res);

    // The animation first: which nodes move and which meshes deform decide how the scene is kept.
    let mut in_scene = vec![false; root.nodes.len()];
    for inst in &instances {
        in_scene[inst.node] = true;
    }
    let channels = channels::read(&acc, &in_scene, &mut warnings)?;
    let hierarchy = Hierarchy::new(root, &instances, &channels)?;
    let moving = hierarchy.moving();
    let mut weights_animated = vec![false; root.nodes.len()];
    for ch in &channels {
        if ch.target == Target::Weights {
            weights_animated[ch.node] = true;
        }
    }
    let mut skins: Vec<Skin> = Vec::new();
    let mut skin_slot: HashMap<usize, usize> = HashMap::new();
    let mut deforming = vec![false; root.nodes.len()];
    for inst in &instances {
        let Some(mesh) = mesh_of(root, inst.node) else {
            continue;
        };
        let skin = root.nodes[inst.node].skin.map(|s| s.value());
        if let Some(s) = skin {
            if let Entry::Vacant(e) = skin_slot.entry(s) {
                e.insert(skins.len());
                skins.push(Skin::read(&acc, s, hierarchy.in_scene())?);
            }
        }
        deforming[inst.node] = skin.is_some() || channels::target_count(root, mesh) > 0;
    }
    let motion = Motion {
        moving: moving.clone(),
        deforming,
        animated: true,
    };

    let scan = prepare::scan(root, instances, options, &motion, &mut warnings)?;
    let instances: &[Instance] = &scan.instances;
    let mats = prepare::Materials::convert(root, &res, &scan, &mut warnings)?;
    let mut builder = MeshBuilder::new(&acc, mats.needs);
    let material_of = |m: Option<usize>| mats.of(m);
    let mut placements = Vec::new();
    let mut deformed = Vec::new();
    let mut emitters = Vec::new();
    let mut lights = Vec::new();
    let mut pose = None;
    for inst in instances {
        let node = inst.node;
        if root.nodes[node]
            .extensions
            .as_ref()
            .is_some_and(|e| e.khr_lights_punctual.is_some())
        {
            lights.push(node);
        }
        let Some(m) = mesh_of(root, node) else {
            continue;
        };
        let rows = gpu_instancing::rows(&acc, node)?;
        if motion.deforms(node) {
            let skin = root.nodes[node]
                .skin
                .and_then(|s| skin_slot.get(&s.value()).map(|&k| (s.value(), k)));
            let label = skin.map(|(s, _)| skin_label(root, s));
            let joints = skin.map(|(_, k)| skins[k].joints.len());
            let mut prims = Vec::new();
            for read in builder.local_primitives(m, &material_of, &mut warnings)? {
                let with = label.as_deref().zip(joints);
                prims.push(Deformable::read(&acc, m, read, with, &mut warnings)?);
            }
            let dynamic = weights_animated[node]
                || skin.is_some_and(|(_, k)| skins[k].moves(&moving))
                // Morphed but not skinned: the node's transform places the morphed mesh.
                || (skin.is_none() && moving[node]);
            let d = DeformedNode {
                node,
                mesh: m,
                skin: skin.map(|(_, k)| k),
                emits: mesh_may_emit(root, m),
                rows,
                primitives: prims,
            };
            if dynamic {
                deformed.push(d);
            } else {
                // Nothing animates it: deformed once, now, into the world-space triangles.
                let pose = match &pose {
                    Some(p) => p,
                    None => pose.insert(hierarchy.pose(root, &channels, 0.0)?),
                };
                let worlds = d.worlds(pose);
                for (p, posed) in d.pose(&skins, pose) {
                    for world in &worlds {
                        let v = posed.vertices(&p.base);
                        builder.add_vertices(node, m, &v, world, p.base.material);
                    }
                }
            }
            continue;
        }
        if !scan.instanced.contains(&m) && moving[node] {
            emitters.push(MovingEmitter {
                node,
                mesh: m,
                rows,
                primitives: builder
                    .local_primitives(m, &material_of, &mut warnings)?
                    .into_iter()
                    .map(|r| r.local)
                    .collect(),
            });
            continue;
        }
        for (k, world) in placed(inst.world, &rows).iter().enumerate() {
            if scan.instanced.contains(&m) {
                if builder.add_placement(node, m, world, &material_of, &mut warnings)? {
                    let prototype = builder.prototype_of(m).unwrap_or(u32::MAX);
                    placements.push(PlacementSource {
                        prototype,
                        node,
                        row: rows.as_ref().map(|r| r[k]),
                    });
                }
            } else {
                builder.add_instance(node, m, world, &material_of, &mut warnings)?;
            }
        }
    }
    let built = builder.finish();
    bounds::check(root, built.far)?;
    let chosen_camera =
        camera::pick(root, instances, options.camera.as_deref())?.map(|(i, c)| (i.node, c));
    let materials = mats.materials;
    let textures: std::sync::Arc<[_]> = mats.textures.finish().into();
    let (prototypes, prototype_dropped) = build_prototypes(built.prototypes, &materials)?;
    let dynamic_world = !emitters.is_empty() || deformed.iter().any(|d| d.emits);
    let world = if dynamic_world {
        WorldSource::PerFrame(built.mesh)
    } else {
        WorldSource::Shared(World::build(built.mesh, &materials, &textures)?)
    };
    Ok(AnimatedScene {
        root: parsed.root.clone(),
        channels,
        hierarchy,
        skins,
        materials,
        textures,
        world,
        prototypes,
        placements,
        deformed,
        emitters,
        lights,
        camera: chosen_camera,
        needs: mats.needs,
        warnings: warnings.into_vec(),
        dropped: built.dropped + prototype_dropped,
    })
}
