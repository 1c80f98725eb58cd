//! Which meshes the loader keeps instanced (one object-space copy and a BVH of its own, placed by
//! each node: `geometry::Instances`) and which it flattens into world-space triangles. The one place
//! that decides, from facts of the file alone (so the triangle limit can be checked before any
//! geometry is read):
//!
//! - a mesh that one node places is flattened: instancing it would save nothing and cost every ray
//!   that reaches it a move into object space;
//! - a mesh that two or more nodes place (or one node, by two or more rows of
//!   EXT_mesh_gpu_instancing: `gpu_instancing`) is kept instanced, unless one of its primitives' materials
//!   may emit light (a non-zero `emissiveFactor`): lights are sampled over world-space triangles,
//!   so an emitter is flattened however often it is placed.

use super::error::GltfError;
use super::gpu_instancing::placement_count;
use super::nodes::Instance;
use gltf::json;
use std::collections::{BTreeSet, HashMap};

/// Whether glTF material `material` (or the default material, `None`) may emit.
fn may_emit(root: &json::Root, material: Option<usize>) -> bool {
    material
        .and_then(|m| root.materials.get(m))
        .is_some_and(|m| m.emissive_factor.0.iter().any(|&f| f > 0.0 || f.is_nan()))
}

/// The meshes to keep instanced among those the scene's nodes place.
pub(crate) fn instanced_meshes(
    root: &json::Root,
    nodes: &[Instance],
) -> Result<BTreeSet<usize>, GltfError> {
    let mut uses: HashMap<usize, u64> = HashMap::new();
    for inst in nodes {
        if let Some(m) = root.nodes.get(inst.node).and_then(|n| n.mesh) {
            let count = uses.entry(m.value()).or_default();
            *count = count.saturating_add(placement_count(root, inst.node)?);
        }
    }
    Ok(uses
        .into_iter()
        .filter(|&(_, count)| count >= 2)
        .map(|(mesh, _)| mesh)
        .filter(|&mesh| {
            root.meshes.get(mesh).is_some_and(|m| {
                !m.primitives
                    .iter()
                    .any(|p| may_emit(root, p.material.map(|i| i.value())))
            })
        })
        .collect())
}
