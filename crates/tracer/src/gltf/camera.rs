//! The scene camera: the first node (in traversal order) carrying a camera, or the one chosen by name.
//! Its transform is the node's world transform with the scale stripped (rotation orthonormalized,
//! keeping the viewing direction −Z exact). glTF's aspect ratio, xmag and clip planes are ignored: the
//! image size comes from the render settings and nothing is clipped.

use super::error::{label, GltfError};
use super::nodes::{node_label, Instance};
use crate::camera::{Camera, Orthographic, Perspective, Projection};
use glam::{Affine3A, DMat4, DVec3, Mat3};
use gltf::json;
use json::camera::Type;
use json::validation::Checked;

fn camera_label(root: &json::Root, index: usize) -> String {
    label(
        "camera",
        index,
        root.cameras.get(index).and_then(|c| c.name.as_deref()),
    )
}

/// Picks and converts the scene's camera. `wanted` matches a camera's name first, then the name of a
/// node carrying a camera. `None` when the scene has no camera and none was asked for.
pub(crate) fn choose(
    root: &json::Root,
    instances: &[Instance],
    wanted: Option<&str>,
) -> Result<Option<Camera>, GltfError> {
    match pick(root, instances, wanted)? {
        Some((instance, index)) => convert(root, index, instance).map(Some),
        None => Ok(None),
    }
}

/// The scene's camera as [`choose`] picks it: the node instance carrying it and the camera's index.
pub(crate) fn pick<'i>(
    root: &json::Root,
    instances: &'i [Instance],
    wanted: Option<&str>,
) -> Result<Option<(&'i Instance, usize)>, GltfError> {
    let with_camera: Vec<(&Instance, usize)> = instances
        .iter()
        .filter_map(|i| {
            root.nodes
                .get(i.node)
                .and_then(|n| n.camera)
                .map(|c| (i, c.value()))
        })
        .collect();
    let chosen = match wanted {
        None => with_camera.first(),
        Some(name) => {
            let by_camera = with_camera
                .iter()
                .find(|(_, c)| root.cameras.get(*c).and_then(|c| c.name.as_deref()) == Some(name));
            let by_node = || {
                with_camera.iter().find(|(i, _)| {
                    root.nodes.get(i.node).and_then(|n| n.name.as_deref()) == Some(name)
                })
            };
            match by_camera.or_else(by_node) {
                Some(found) => Some(found),
                None => {
                    let available = with_camera
                        .iter()
                        .map(|(i, c)| {
                            format!("{} on {}", camera_label(root, *c), node_label(root, i.node))
                        })
                        .collect();
                    return Err(GltfError::CameraNotFound {
                        name: name.to_string(),
                        available,
                    });
                }
            }
        }
    };
    Ok(chosen.copied())
}

/// Camera `index` placed by `instance` (its node and world transform).
pub(crate) fn convert(
    root: &json::Root,
    index: usize,
    instance: &Instance,
) -> Result<Camera, GltfError> {
    let object = format!(
        "{} (on {})",
        camera_label(root, index),
        node_label(root, instance.node)
    );
    let err = |reason: &str| GltfError::Object {
        object: object.clone(),
        reason: reason.to_string(),
    };
    let Some(cam) = root.cameras.get(index) else {
        return Err(err("does not exist"));
    };
    let projection = match (cam.type_, &cam.perspective, &cam.orthographic) {
        (Checked::Valid(Type::Perspective), Some(p), _) => {
            if !(p.yfov.is_finite() && p.yfov > 0.0 && p.yfov < std::f32::consts::PI) {
                return Err(err(&format!("yfov {} is not in (0, π)", p.yfov)));
            }
            Projection::Perspective(Perspective::new(p.yfov))
        }
        (Checked::Valid(Type::Orthographic), _, Some(o)) => {
            let ymag = o.ymag.abs();
            if !(ymag.is_finite() && ymag > 0.0) {
                return Err(err(&format!("ymag {} is not a positive number", o.ymag)));
            }
            Projection::Orthographic(Orthographic { ymag })
        }
        _ => {
            return Err(err(
                "type does not match its perspective/orthographic properties",
            ))
        }
    };
    let to_world =
        rigid(&instance.world).ok_or_else(|| err("node transform is degenerate (zero scale)"))?;
    Ok(Camera::new(projection, to_world))
}

/// The rotation and translation of `m`, with the rotation orthonormalized (−Z kept, then +Y).
fn rigid(m: &DMat4) -> Option<Affine3A> {
    let z = m.z_axis.truncate().normalize_or_zero();
    if z == DVec3::ZERO {
        return None;
    }
    let y_in = m.y_axis.truncate();
    let mut y = (y_in - z * z.dot(y_in)).normalize_or_zero();
    let x;
    if y == DVec3::ZERO {
        let x_in = m.x_axis.truncate();
        let xo = (x_in - z * z.dot(x_in)).normalize_or_zero();
        x = if xo == DVec3::ZERO {
            z.any_orthonormal_vector()
        } else {
            xo
        };
        y = z.cross(x);
    } else {
        x = y.cross(z);
    }
    let t = m.w_axis.truncate().as_vec3();
    if !t.is_finite() {
        return None;
    }
    Some(Affine3A::from_mat3_translation(
        Mat3::from_cols(x.as_vec3(), y.as_vec3(), z.as_vec3()),
        t,
    ))
}
