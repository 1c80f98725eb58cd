//! The world-space extent the loader accepts.
//!
//! Every coordinate is finite by the time it gets here, but finite is not enough: the BVH builder of
//! the time (obvhs) computed surface areas and summed SAH costs in `f32`, and a single vertex near
//! 10²⁰ (a mutated float, a node scale of 10¹⁹) made those areas infinite and the costs NaN or
//! infinite; its CWBVH conversion then found no valid split for a node and indexed its decision
//! table with an "invalid" marker (found by the `gltf_load` fuzz target, see docs/fuzzing.md). Our
//! own builder (`geometry/bvh/binned.rs`) computes its costs in `f64` and falls back to median splits
//! where they are not finite, but `f32` has no precision left for ray tracing at such scales, and
//! bounding coordinates keeps every area and cost finite all the same.

use super::error::GltfError;
use super::mesh::primitive_label;
use super::nodes::node_label;
use glam::Vec3;
use gltf::json;

/// Largest absolute world-space vertex coordinate (in scene units, metres in glTF): a million
/// kilometres. The scene's half surface area is then at most 3·(2·10¹²)² ≈ 1.2·10²⁵, and a BVH over
/// [`super::MAX_TRIANGLES`] triangles sums at most a few hundred million such areas, far below
/// `f32::MAX` (3.4·10³⁸). `f32` has no precision left for ray tracing at this scale long before.
pub const MAX_COORDINATE: f32 = 1e12;

pub(crate) fn outside(v: Vec3) -> bool {
    v.abs().max_element() > MAX_COORDINATE
}

/// A triangle corner beyond ±[`MAX_COORDINATE`], and the node and primitive that put it there (the
/// mesh builder records the first one it keeps).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Far {
    pub node: usize,
    pub mesh: usize,
    pub primitive: usize,
    pub corner: Vec3,
}

/// Refuses a scene with a triangle reaching beyond ±[`MAX_COORDINATE`], naming the node and
/// primitive.
pub(crate) fn check(root: &json::Root, far: Option<Far>) -> Result<(), GltfError> {
    let Some(far) = far else {
        return Ok(());
    };
    let v = far.corner;
    Err(GltfError::Limit(format!(
        "{}, {}: a vertex lies at ({:e}, {:e}, {:e}) in world space, beyond ±{MAX_COORDINATE:e} \
         (scale the scene down)",
        node_label(root, far.node),
        primitive_label(root, far.mesh, far.primitive),
        v.x,
        v.y,
        v.z
    )))
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
