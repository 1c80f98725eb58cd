//! EXT_mesh_gpu_instancing: a node whose extension lists per-instance TRANSLATION, ROTATION and
//! SCALE accessors places its mesh once per row, at the node's world transform times the row's
//! T·R·S (the node itself is not placed besides). Scatter tools and several exporters write
//! forests and crowds this way; each row becomes a placement like a node's, so a mesh placed by
//! rows is kept instanced (`instancing`) and never flattened unless it emits.
//!
//! Rotations may be floats or normalized signed bytes or shorts (as the extension allows); each is
//! normalised, and a zero quaternion is an error naming the node and the row.

use super::accessors::Accessors;
use super::error::GltfError;
use super::nodes::node_label;
use glam::{DMat4, DQuat, DVec3};
use gltf::json;

pub(crate) const EXTENSION: &str = "EXT_mesh_gpu_instancing";

/// The accessor indices of a node's instancing attributes.
#[derive(Clone, Copy, Debug, Default)]
struct Attributes {
    translation: Option<usize>,
    rotation: Option<usize>,
    scale: Option<usize>,
}

fn object_error(root: &json::Root, node: usize, reason: String) -> GltfError {
    GltfError::Object {
        object: format!("{} ({EXTENSION})", node_label(root, node)),
        reason,
    }
}

/// The node's instancing attributes, if it has the extension.
fn attributes(root: &json::Root, node: usize) -> Result<Option<Attributes>, GltfError> {
    let Some(ext) = root
        .nodes
        .get(node)
        .and_then(|n| n.extensions.as_ref())
        .and_then(|e| e.others.get(EXTENSION))
    else {
        return Ok(None);
    };
    let Some(attrs) = ext.get("attributes").and_then(|a| a.as_object()) else {
        return Err(object_error(
            root,
            node,
            "has no \"attributes\" object".into(),
        ));
    };
    let index = |name: &str| -> Result<Option<usize>, GltfError> {
        match attrs.get(name) {
            None => Ok(None),
            Some(v) => v
                .as_u64()
                .and_then(|i| usize::try_from(i).ok())
                .filter(|&i| i < root.accessors.len())
                .map(Some)
                .ok_or_else(|| {
                    object_error(
                        root,
                        node,
                        format!(
                            "{name} is {v}, not one of the file's {} accessors",
                            root.accessors.len()
                        ),
                    )
                }),
        }
    };
    let found = Attributes {
        translation: index("TRANSLATION")?,
        rotation: index("ROTATION")?,
        scale: index("SCALE")?,
    };
    if found.translation.is_none() && found.rotation.is_none() && found.scale.is_none() {
        return Err(object_error(
            root,
            node,
            "has none of TRANSLATION, ROTATION and SCALE".into(),
        ));
    }
    Ok(Some(found))
}

/// How many times node `node` places its mesh: its rows with the extension, else once. From the
/// JSON alone (the accessors' counts, which must agree).
pub(crate) fn placement_count(root: &json::Root, node: usize) -> Result<u64, GltfError> {
    let Some(attrs) = attributes(root, node)? else {
        return Ok(1);
    };
    let mut count = None;
    for (name, index) in [
        ("TRANSLATION", attrs.translation),
        ("ROTATION", attrs.rotation),
        ("SCALE", attrs.scale),
    ] {
        let Some(i) = index else { continue };
        let n = root.accessors[i].count.0;
        match count {
            None => count = Some((name, n)),
            Some((first, m)) if m != n => {
                return Err(object_error(
                    root,
                    node,
                    format!("{name} has {n} elements but {first} has {m}"),
                ))
            }
            Some(_) => {}
        }
    }
    Ok(count.map_or(1, |(_, n)| n))
}

/// The world transforms at which node `node` (world transform `world`) places its mesh: one per
/// row of its instancing attributes, or `world` itself without the extension.
pub(crate) fn placements(
    acc: &Accessors<'_, '_>,
    node: usize,
    world: &DMat4,
) -> Result<Vec<DMat4>, GltfError> {
    Ok(match rows(acc, node)? {
        None => vec![*world],
        Some(rows) => rows.iter().map(|row| *world * *row).collect(),
    })
}

/// The local transforms of node `node`'s instancing rows (each placement is the node's world
/// transform times one), or `None` without the extension.
pub(crate) fn rows(acc: &Accessors<'_, '_>, node: usize) -> Result<Option<Vec<DMat4>>, GltfError> {
    let root = acc.root();
    let Some(attrs) = attributes(root, node)? else {
        return Ok(None);
    };
    let rows = placement_count(root, node)? as usize;
    let label = |name: &str| format!("{name} of {} ({EXTENSION})", node_label(root, node));
    let translation = match attrs.translation {
        Some(i) => Some(acc.vec3(i, &label("TRANSLATION"))?),
        None => None,
    };
    let rotation = match attrs.rotation {
        Some(i) => Some(acc.vec4(i, &label("ROTATION"))?),
        None => None,
    };
    let scale = match attrs.scale {
        Some(i) => Some(acc.vec3(i, &label("SCALE"))?),
        None => None,
    };
    let mut out = Vec::with_capacity(rows);
    for row in 0..rows {
        let t = translation
            .as_ref()
            .map_or(DVec3::ZERO, |t| t[row].as_dvec3());
        let s = scale.as_ref().map_or(DVec3::ONE, |s| s[row].as_dvec3());
        let q = rotation.as_ref().map_or(DQuat::IDENTITY, |r| {
            let r = r[row].as_dvec4();
            DQuat::from_xyzw(r.x, r.y, r.z, r.w)
        });
        let len = q.length();
        if len <= 1e-12 {
            return Err(object_error(
                root,
                node,
                format!("row {row} has a zero-length ROTATION quaternion"),
            ));
        }
        out.push(DMat4::from_scale_rotation_translation(s, q / len, t));
    }
    Ok(Some(out))
}
