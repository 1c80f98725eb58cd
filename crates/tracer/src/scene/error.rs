//! Why a scene cannot be built.

use crate::geometry::{InstanceError, MeshError};

/// Why a scene cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    Instance(#[from] InstanceError),
    #[error("instanced mesh {prototype}: {source}")]
    PrototypeMesh { prototype: usize, source: MeshError },
    #[error("instanced mesh {prototype}: triangle {triangle} refers to material {material}, but the scene has {count} materials")]
    PrototypeMaterial {
        prototype: usize,
        triangle: usize,
        material: u32,
        count: usize,
    },
    /// Lights are sampled over world-space triangles: an emissive mesh must be flattened.
    #[error("instanced mesh {prototype} uses emissive material {material}; emissive meshes must be placed as world-space triangles")]
    EmissivePrototype { prototype: usize, material: u32 },
    /// Every triangle of the scene was degenerate: a scene made only of unrenderable geometry is
    /// broken input, not an empty scene (which has no triangles at all).
    #[error("all {dropped} triangles of the scene are degenerate (zero area or non-finite corners); nothing can be rendered")]
    AllDegenerate { dropped: usize },
    #[error(
        "triangle {triangle} refers to material {material}, but the scene has {count} materials"
    )]
    MaterialIndex {
        triangle: usize,
        material: u32,
        count: usize,
    },
}
