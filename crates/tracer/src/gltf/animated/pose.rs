//! The scene's nodes at a time: each animated node's translation, rotation and scale sampled from
//! its channels (over the values the file gives it at rest), every node's world transform composed
//! parent → child, and each morphed node's weights.
//!
//! A node's local matrix is made by the still loader's own function (`nodes::trs_matrix`) and
//! composed in the same order, so a node at a time sits exactly where the still loader puts a node
//! whose TRS are the sampled values: a frame renders the bits of the still file it stands for.

use super::channels::{target_count, Channel, Target};
use super::error::AnimationError;
use crate::gltf::nodes::{self, node_label, Instance, Trs};
use crate::gltf::prepare::mesh_of;
use crate::gltf::GltfError;
use glam::DMat4;
use gltf::json;

/// The scene's node hierarchy and what its nodes are at rest.
#[derive(Clone, Debug)]
pub(crate) struct Hierarchy {
    /// The scene's nodes in depth-first pre-order (parents first), with their parents.
    order: Vec<(usize, Option<usize>)>,
    /// Per node of the file: its local transform at rest (the identity for nodes outside the
    /// scene).
    rest: Vec<DMat4>,
    /// Per node: its TRS at rest, for the nodes a channel animates.
    animated: Vec<Option<Trs>>,
    /// Per node: its morph weights at rest (the node's, else its mesh's, else zeros), for the
    /// nodes whose mesh has morph targets.
    weights: Vec<Option<Vec<f32>>>,
    /// Per node: it is in the scene.
    in_scene: Vec<bool>,
}

/// The scene at a time.
#[derive(Clone, Debug)]
pub(crate) struct Pose {
    /// Per node of the file: its world transform (the identity outside the scene).
    pub world: Vec<DMat4>,
    /// Per node: its morph weights, for nodes whose mesh has morph targets.
    pub weights: Vec<Option<Vec<f32>>>,
}

impl Hierarchy {
    /// The hierarchy of the scene's nodes (`instances`, in the still loader's traversal order).
    pub fn new(
        root: &json::Root,
        instances: &[Instance],
        channels: &[Channel],
    ) -> Result<Hierarchy, GltfError> {
        let n = root.nodes.len();
        let mut parent = vec![None; n];
        let mut in_scene = vec![false; n];
        let mut rest = vec![DMat4::IDENTITY; n];
        for inst in instances {
            in_scene[inst.node] = true;
            rest[inst.node] = nodes::local_transform(root, inst.node)?;
            for c in root.nodes[inst.node].children.iter().flatten() {
                if let Some(p) = parent.get_mut(c.value()) {
                    *p = Some(inst.node);
                }
            }
        }
        let order = instances.iter().map(|i| (i.node, parent[i.node])).collect();
        let mut animated = vec![None; n];
        for ch in channels {
            if ch.target != Target::Weights {
                animated[ch.node] = root.nodes.get(ch.node).and_then(nodes::node_trs);
            }
        }
        let mut weights = vec![None; n];
        for inst in instances {
            let node = &root.nodes[inst.node];
            let Some(mesh) = mesh_of(root, inst.node) else {
                continue;
            };
            let count = target_count(root, mesh);
            if count == 0 {
                continue;
            }
            let given = node
                .weights
                .as_ref()
                .or(root.meshes.get(mesh).and_then(|m| m.weights.as_ref()));
            let mut w = vec![0.0; count];
            if let Some(given) = given {
                for (w, g) in w.iter_mut().zip(given) {
                    *w = if g.is_finite() { *g } else { 0.0 };
                }
            }
            weights[inst.node] = Some(w);
        }
        Ok(Hierarchy {
            order,
            rest,
            animated,
            weights,
            in_scene,
        })
    }

    /// Per node of the file: whether the rendered scene reaches it.
    pub fn in_scene(&self) -> &[bool] {
        &self.in_scene
    }

    /// Per node: whether its world transform changes with time (a channel moves it or an
    /// ancestor).
    pub fn moving(&self) -> Vec<bool> {
        let mut moving = vec![false; self.rest.len()];
        for &(node, parent) in &self.order {
            moving[node] = self.animated[node].is_some() || parent.is_some_and(|p| moving[p]);
        }
        moving
    }

    /// Node `node`'s TRS at `time`, for a node a channel animates.
    pub fn trs_at(&self, channels: &[Channel], node: usize, time: f32) -> Option<Trs> {
        let mut trs = (*self.animated.get(node)?)?;
        for ch in channels.iter().filter(|c| c.node == node) {
            apply(ch, &mut trs, time);
        }
        Some(trs)
    }

    /// The scene at `time` (seconds).
    pub fn pose(
        &self,
        root: &json::Root,
        channels: &[Channel],
        time: f32,
    ) -> Result<Pose, GltfError> {
        let mut trs = self.animated.clone();
        let mut weights = self.weights.clone();
        for ch in channels {
            let node = ch.node;
            match (ch.target, &mut trs[node], &mut weights[node]) {
                (Target::Weights, _, Some(w)) if w.len() == ch.keys.width => {
                    ch.keys.sample(time, w)
                }
                (_, Some(t), _) => apply(ch, t, time),
                _ => {}
            }
        }
        let mut world = vec![DMat4::IDENTITY; self.rest.len()];
        for &(node, parent) in &self.order {
            let local = match &trs[node] {
                Some(t) => nodes::trs_matrix(t).map_err(|reason| AnimationError::AtTime {
                    time,
                    reason: format!("{}: {reason}", node_label(root, node)),
                })?,
                None => self.rest[node],
            };
            // As `nodes::traverse` composes it (the identity above a root).
            let above = parent.map_or(DMat4::IDENTITY, |p| world[p]);
            let w = above * local;
            if !w.is_finite() {
                return Err(AnimationError::AtTime {
                    time,
                    reason: format!("{}: world transform overflows", node_label(root, node)),
                }
                .into());
            }
            world[node] = w;
        }
        Ok(Pose { world, weights })
    }
}

/// Sets the property channel `ch` animates (translation, rotation or scale) to its value at
/// `time`.
fn apply(ch: &Channel, trs: &mut Trs, time: f32) {
    match ch.target {
        Target::Translation => ch.keys.sample(time, &mut trs.translation),
        Target::Scale => ch.keys.sample(time, &mut trs.scale),
        Target::Rotation => trs.rotation = ch.keys.sample_rotation(time),
        Target::Weights => {}
    }
}
