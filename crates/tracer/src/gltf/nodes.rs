//! The node hierarchy of the chosen scene: world transforms composed parent → child (in f64), visited
//! in depth-first pre-order (children in the order listed), without recursion so that a deep chain
//! cannot overflow the stack, and refusing cycles and nodes with two parents.

use super::error::{label, GltfError};
use glam::{DMat4, DQuat, DVec3};
use gltf::json;

/// A node of the scene with its world transform.
#[derive(Clone, Debug)]
pub(crate) struct Instance {
    pub node: usize,
    pub world: DMat4,
}

pub(crate) fn node_label(root: &json::Root, index: usize) -> String {
    label(
        "node",
        index,
        root.nodes.get(index).and_then(|n| n.name.as_deref()),
    )
}

fn finite(values: &[f32]) -> bool {
    values.iter().all(|v| v.is_finite())
}

/// A node's translation, rotation quaternion (x, y, z, w) and scale, as the file writes them (an
/// animation replaces some of them at each frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Trs {
    pub translation: [f32; 3],
    pub rotation: [f32; 4],
    pub scale: [f32; 3],
}

/// The node's TRS properties (their defaults where absent), or `None` for a node with a matrix.
pub(crate) fn node_trs(node: &json::Node) -> Option<Trs> {
    if node.matrix.is_some() {
        return None;
    }
    Some(Trs {
        translation: node.translation.unwrap_or([0.0; 3]),
        rotation: node.rotation.as_ref().map_or([0.0, 0.0, 0.0, 1.0], |q| q.0),
        scale: node.scale.unwrap_or([1.0; 3]),
    })
}

/// translation · rotation · scale, composed in f64 with the quaternion normalised; or why not.
pub(crate) fn trs_matrix(trs: &Trs) -> Result<DMat4, &'static str> {
    let (t, r, s) = (trs.translation, trs.rotation, trs.scale);
    if !finite(&t) || !finite(&r) || !finite(&s) {
        return Err("non-finite translation, rotation or scale");
    }
    let q = DQuat::from_xyzw(r[0] as f64, r[1] as f64, r[2] as f64, r[3] as f64);
    let len = q.length();
    // The components are finite, so the length is a number.
    if len <= 1e-12 {
        return Err("zero-length rotation quaternion");
    }
    Ok(DMat4::from_scale_rotation_translation(
        DVec3::new(s[0] as f64, s[1] as f64, s[2] as f64),
        q / len,
        DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64),
    ))
}

/// The node's local transform (matrix, or translation · rotation · scale).
pub(crate) fn local_transform(root: &json::Root, index: usize) -> Result<DMat4, GltfError> {
    let err = |reason: &str| GltfError::Object {
        object: node_label(root, index),
        reason: reason.to_string(),
    };
    let Some(node) = root.nodes.get(index) else {
        return Err(err("does not exist"));
    };
    match (&node.matrix, node_trs(node)) {
        (Some(m), _) => {
            if !finite(m) {
                return Err(err("non-finite matrix"));
            }
            Ok(DMat4::from_cols_array(&m.map(|v| v as f64)))
        }
        (None, Some(trs)) => trs_matrix(&trs).map_err(err),
        (None, None) => Err(err("has neither a matrix nor TRS")),
    }
}

/// The root nodes of the scene to render: `scene`, else the first scene, else (no scenes at all) every
/// node that is nobody's child. Returns the roots and a description of the choice.
pub(crate) fn scene_roots(root: &json::Root) -> (Vec<usize>, Option<String>) {
    let chosen = root
        .scene
        .map(|s| s.value())
        .filter(|&s| s < root.scenes.len())
        .or(if root.scenes.is_empty() {
            None
        } else {
            Some(0)
        });
    match chosen.and_then(|s| root.scenes.get(s)) {
        Some(scene) => (scene.nodes.iter().map(|n| n.value()).collect(), None),
        None => {
            let mut is_child = vec![false; root.nodes.len()];
            for node in &root.nodes {
                for c in node.children.iter().flatten() {
                    if let Some(flag) = is_child.get_mut(c.value()) {
                        *flag = true;
                    }
                }
            }
            let roots: Vec<usize> = (0..root.nodes.len()).filter(|&i| !is_child[i]).collect();
            let note = (!roots.is_empty())
                .then(|| "the file has no scenes; rendering every root node".to_string());
            (roots, note)
        }
    }
}

/// Every node reachable from `roots`, with its world transform, in depth-first pre-order.
pub(crate) fn traverse(root: &json::Root, roots: &[usize]) -> Result<Vec<Instance>, GltfError> {
    let mut visited = vec![false; root.nodes.len()];
    let mut out = Vec::new();
    // Stack of (node, parent world transform); roots pushed in reverse so the first is visited first.
    let mut stack: Vec<(usize, DMat4)> =
        roots.iter().rev().map(|&n| (n, DMat4::IDENTITY)).collect();
    while let Some((index, parent)) = stack.pop() {
        let Some(seen) = visited.get_mut(index) else {
            return Err(GltfError::Object {
                object: format!("node {index}"),
                reason: format!("does not exist (the file has {} nodes)", root.nodes.len()),
            });
        };
        if *seen {
            return Err(GltfError::Object {
                object: node_label(root, index),
                reason: "is reached twice in the scene's hierarchy (a cycle, or a node with two parents)".into(),
            });
        }
        *seen = true;
        let world = parent * local_transform(root, index)?;
        if !world.is_finite() {
            return Err(GltfError::Object {
                object: node_label(root, index),
                reason: "world transform overflows".into(),
            });
        }
        if let Some(children) = root.nodes.get(index).and_then(|n| n.children.as_ref()) {
            for c in children.iter().rev() {
                stack.push((c.value(), world));
            }
        }
        out.push(Instance { node: index, world });
    }
    Ok(out)
}
