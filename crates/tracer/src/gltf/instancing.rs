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
//!   so an emitter is flattened however often it is placed;
//! - in an animated scene, a mesh that a moving node places is kept instanced too (unless it may
//!   emit): its BVH is built once and each frame only moves its placement. A node whose mesh
//!   deforms (skinned, or with morph targets) places no prototype: its triangles are made anew.

use super::animated::Motion;
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

/// Whether a primitive of mesh `mesh` has a material that may emit.
pub(crate) fn mesh_may_emit(root: &json::Root, mesh: usize) -> bool {
    root.meshes.get(mesh).is_some_and(|m| {
        m.primitives
            .iter()
            .any(|p| may_emit(root, p.material.map(|i| i.value())))
    })
}

/// The meshes to keep instanced among those the scene's nodes place (`motion`: which nodes move
/// or deform, nothing for a still scene).
pub(crate) fn instanced_meshes(
    root: &json::Root,
    nodes: &[Instance],
    motion: &Motion,
) -> Result<BTreeSet<usize>, GltfError> {
    let mut uses: HashMap<usize, u64> = HashMap::new();
    for inst in nodes {
        if motion.deforms(inst.node) {
            continue;
        }
        if let Some(m) = root.nodes.get(inst.node).and_then(|n| n.mesh) {
            let count = uses.entry(m.value()).or_default();
            // A moving node's mesh is kept instanced as if placed twice.
            let placed = placement_count(root, inst.node)?;
            let placed = if motion.moves(inst.node) {
                placed.max(2)
            } else {
                placed
            };
            *count = count.saturating_add(placed);
        }
    }
    Ok(uses
        .into_iter()
        .filter(|&(_, count)| count >= 2)
        .map(|(mesh, _)| mesh)
        .filter(|&mesh| root.meshes.get(mesh).is_some() && !mesh_may_emit(root, mesh))
        .collect())
}
