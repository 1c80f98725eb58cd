//! Skins: a skin's joints (nodes) and inverse bind matrices, read once; at a time, its joint
//! matrices, world(joint) · inverseBind(joint). A skinned vertex is the sum over its influences
//! of weight · jointMatrix · vertex (glTF ignores the transform of the node carrying the mesh): it
//! lands in world space.

use super::error::AnimationError;
use crate::gltf::accessors::Accessors;
use crate::gltf::error::{label, GltfError};
use crate::gltf::nodes::node_label;
use glam::DMat4;
use gltf::json;

/// A skin, as read.
#[derive(Clone, Debug)]
pub(crate) struct Skin {
    /// The joint nodes.
    pub joints: Vec<usize>,
    /// One per joint (the identity where the file has none).
    pub inverse_bind: Vec<DMat4>,
}

pub(crate) fn skin_label(root: &json::Root, index: usize) -> String {
    label(
        "skin",
        index,
        root.skins.get(index).and_then(|s| s.name.as_deref()),
    )
}

impl Skin {
    /// Skin `index`; every joint must be in the scene (`in_scene`).
    pub fn read(
        acc: &Accessors<'_, '_>,
        index: usize,
        in_scene: &[bool],
    ) -> Result<Skin, GltfError> {
        let root = acc.root();
        let name = || skin_label(root, index);
        let Some(skin) = root.skins.get(index) else {
            return Err(GltfError::Object {
                object: name(),
                reason: format!("does not exist (the file has {} skins)", root.skins.len()),
            });
        };
        let joints: Vec<usize> = skin.joints.iter().map(|j| j.value()).collect();
        for (joint, &node) in joints.iter().enumerate() {
            if !in_scene.get(node).copied().unwrap_or(false) {
                return Err(AnimationError::JointOutsideScene {
                    skin: name(),
                    joint,
                    node: node_label(root, node),
                }
                .into());
            }
        }
        let inverse_bind = match skin.inverse_bind_matrices {
            None => vec![DMat4::IDENTITY; joints.len()],
            Some(a) => {
                let m =
                    acc.read_vec::<16>(a.value(), &format!("inverseBindMatrices of {}", name()))?;
                if m.len() != joints.len() {
                    return Err(AnimationError::BindMatrices {
                        skin: name(),
                        matrices: m.len(),
                        joints: joints.len(),
                    }
                    .into());
                }
                m.iter()
                    .map(|c| DMat4::from_cols_array(&c.map(f64::from)))
                    .collect()
            }
        };
        Ok(Skin {
            joints,
            inverse_bind,
        })
    }

    /// Whether some joint moves (`moving[node]`).
    pub fn moves(&self, moving: &[bool]) -> bool {
        self.joints
            .iter()
            .any(|&j| moving.get(j).copied().unwrap_or(false))
    }

    /// The joint matrices for the nodes' world transforms `world`.
    pub fn joint_matrices(&self, world: &[DMat4]) -> Vec<DMat4> {
        self.joints
            .iter()
            .zip(&self.inverse_bind)
            .map(|(&j, ibm)| world[j] * *ibm)
            .collect()
    }
}
