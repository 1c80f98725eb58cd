//! The world-space extent the loader accepts.
//!
//! Every coordinate is finite by the time it gets here, but finite is not enough: the BVH builder
//! (obvhs) computes surface areas and summed SAH costs in `f32`, and a single vertex near 10²⁰ (a
//! mutated float, a node scale of 10¹⁹) makes those areas infinite and the costs NaN or infinite. The
//! builder's CWBVH conversion then finds no valid split for a node and indexes its decision table with
//! an "invalid" marker: a debug assertion in a debug build, and in a release build a read of an
//! unrelated entry, i.e. a corrupt tree or an out-of-bounds panic (found by the `gltf_load` fuzz
//! target, see docs/fuzzing.md). Bounding coordinates keeps every area and cost finite.

use super::accessors::Accessors;
use super::error::GltfError;
use super::mesh::primitive_label;
use super::nodes::{node_label, Instance};
use crate::geometry::Mesh;
use glam::Vec3;
use gltf::json;
use json::mesh::{Mode, Semantic};
use json::validation::Checked;

/// Largest absolute world-space vertex coordinate (in scene units, metres in glTF): a million
/// kilometres. The scene's half surface area is then at most 3·(2·10¹²)² ≈ 1.2·10²⁵, and a BVH over
/// [`super::MAX_TRIANGLES`] triangles sums at most a few hundred million such areas, far below
/// `f32::MAX` (3.4·10³⁸). `f32` has no precision left for ray tracing at this scale long before.
pub const MAX_COORDINATE: f32 = 1e12;

fn outside(v: Vec3) -> bool {
    v.abs().max_element() > MAX_COORDINATE
}

/// Refuses a scene whose triangles reach beyond ±[`MAX_COORDINATE`], naming the node and primitive.
pub(crate) fn check(
    root: &json::Root,
    acc: &Accessors,
    instances: &[Instance],
    mesh: &Mesh,
) -> Result<(), GltfError> {
    let Some(corner) = mesh.positions.iter().flatten().find(|v| outside(**v)) else {
        return Ok(());
    };
    let limit = |object: String, v: Vec3| {
        GltfError::Limit(format!(
            "{object}: a vertex lies at ({:e}, {:e}, {:e}) in world space, beyond ±{MAX_COORDINATE:e} \
             (scale the scene down)",
            v.x, v.y, v.z
        ))
    };
    // Only on failure: find the instance and primitive that put this corner there. The mesh keeps no
    // record of where its triangles came from, so re-read the positions as the mesh builder does.
    for inst in instances {
        let Some(m) = root.nodes.get(inst.node).and_then(|n| n.mesh) else {
            continue;
        };
        let Some(prims) = root.meshes.get(m.value()).map(|m| &m.primitives) else {
            continue;
        };
        for (p, prim) in prims.iter().enumerate() {
            let triangles = matches!(
                prim.mode,
                Checked::Valid(Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)
            );
            let Some(pos) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) else {
                continue;
            };
            if !triangles {
                continue;
            }
            let Ok(points) = acc.read_vec::<3>(pos.value(), "POSITION") else {
                continue;
            };
            let far = points.iter().map(|v| {
                inst.world
                    .transform_point3(Vec3::from(*v).as_dvec3())
                    .as_vec3()
            });
            if let Some(v) = far.into_iter().find(|v| outside(*v)) {
                let object = format!(
                    "{}, {}",
                    node_label(root, inst.node),
                    primitive_label(root, m.value(), p)
                );
                return Err(limit(object, v));
            }
        }
    }
    Err(limit("the scene".to_string(), *corner))
}

#[cfg(test)]
mod tests {
    use super::super::{load_parts, GltfError, LoadOptions, NoExternalResources};
    use base64::Engine as _;

    /// One triangle with corners (x, 0, 0), (0, 1, 0) and the origin, under a node scaling X by
    /// `scale`. (A long thin triangle: its area stays finite, so the mesh builder keeps it.)
    fn triangle(x: f32, scale: f32) -> Vec<u8> {
        let mut buf = Vec::new();
        for v in [x, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0] {
            buf.extend(v.to_le_bytes());
        }
        let uri = base64::engine::general_purpose::STANDARD.encode(&buf);
        format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
                "min":[0,0,0],"max":[{x},1,0]}}],
            "meshes":[{{"name":"tri","primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "nodes":[{{"name":"far","mesh":0,"scale":[{scale},1,1]}}],
            "scenes":[{{"nodes":[0]}}]}}"#
        )
        .into_bytes()
    }

    fn load(bytes: &[u8]) -> Result<(), GltfError> {
        load_parts(bytes, &NoExternalResources, &LoadOptions::default()).map(|_| ())
    }

    #[test]
    fn coordinates_beyond_the_limit_are_refused_with_the_node_named() {
        load(&triangle(0.5e12, 1.0)).expect("within the limit");
        for (x, scale) in [(1e15, 1.0), (1.0, 1e13)] {
            let e = load(&triangle(x, scale)).unwrap_err();
            assert!(matches!(e, GltfError::Limit(_)), "{e:?}");
            let e = e.to_string();
            assert!(e.contains("node 0 \"far\""), "{e}");
            assert!(e.contains("primitive 0"), "{e}");
            assert!(e.contains("beyond ±1e12"), "{e}");
        }
    }
}
