//! What a loader hands to [`Scene::build`](super::Scene::build), and what a built scene reports.

use crate::camera::Camera;
use crate::geometry::{Mesh, Placement};
use crate::light::PunctualLight;
use crate::material::{Material, Texture};
use glam::Vec3;

/// What a loader hands to [`Scene::build`](super::Scene::build).
#[derive(Clone, Debug, Default)]
pub struct SceneParts {
    /// The triangles placed once, in world space.
    pub mesh: Mesh,
    /// Meshes kept once in their own space and placed by `placements` (a two-level BVH, see
    /// [`crate::geometry::Instances`]). None of their materials may emit: lights are sampled over
    /// world-space triangles, so emissive meshes are flattened into `mesh`.
    pub prototypes: Vec<Mesh>,
    pub placements: Vec<Placement>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub punctual_lights: Vec<PunctualLight>,
    /// `None`: frame the scene with a default camera.
    pub camera: Option<Camera>,
    /// Things the loader ignored or worked around, reported once each.
    pub warnings: Vec<String>,
    /// Degenerate triangles the loader already dropped (they are not in `mesh`).
    pub degenerate_dropped: usize,
}

impl SceneParts {
    /// These parts with every instanced mesh flattened into world-space triangles (see
    /// [`crate::geometry::flatten_into`]).
    pub fn flatten_instances(mut self) -> SceneParts {
        crate::geometry::flatten_into(&self.prototypes, &self.placements, &mut self.mesh);
        self.prototypes.clear();
        self.placements.clear();
        self
    }
}

/// Facts about a built scene, for logs and reports.
#[derive(Clone, Debug, Default)]
pub struct SceneInfo {
    /// Triangles stored: the world-space ones and each instanced mesh once.
    pub triangles: usize,
    /// Placements of instanced meshes, and the triangles they place (each mesh's count once per
    /// placement).
    pub instances: usize,
    pub instanced_triangles: u64,
    /// Zero-area (or non-finite) triangles dropped, by the loader or at build time.
    pub degenerate_dropped: usize,
    pub emissive_triangles: usize,
    pub punctual_lights: usize,
    pub bvh_nodes: usize,
    /// Wall seconds the world-space mesh's BVH took to build (the instanced meshes' trees not
    /// counted).
    pub bvh_seconds: f64,
    /// Approximate bytes held by geometry, BVH and textures.
    pub bytes: usize,
    pub warnings: Vec<String>,
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
}
