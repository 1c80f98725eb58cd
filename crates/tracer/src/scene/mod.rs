//! The renderable scene: world-space triangles with their BVH, materials, textures, lights and the
//! camera. Built once (from glTF by [`crate::gltf`], or by hand in tests) and then only read, from any
//! number of threads.

mod build;
mod bundle;
mod caustics;
mod error;
mod intersect;
mod parts;
mod shading;
#[cfg(test)]
mod tests;
mod world;

pub(crate) use build::drop_degenerate;
pub use build::{build_prototypes, Assembly};
pub use error::SceneError;
pub(crate) use intersect::shading_normal;
pub use intersect::{Hit, SurfaceInteraction};
pub use parts::{SceneInfo, SceneParts};
pub use world::World;

use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::geometry::{Bvh, Instances, Mesh};
use crate::integrator::DiffuseScene;
use crate::light::{Environment, Lights};
use crate::material::{Material, Texture};
use std::sync::Arc;

/// A scene ready to render. Its geometry and textures are shared (`Arc`): the scenes an animation's
/// frames make hold what does not move between frames once.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The world-space triangles (those placed once, and every emitter), in the loader's order.
    pub mesh: Arc<Mesh>,
    pub bvh: Arc<Bvh>,
    /// Instanced meshes and their placements (empty for most scenes, and then free).
    pub instances: Instances,
    pub materials: Vec<Material>,
    pub textures: Arc<[Texture]>,
    pub lights: Lights,
    pub camera: Camera,
    pub info: SceneInfo,
    /// Some material has alpha (MASK or BLEND): intersection must test coverage.
    any_alpha: bool,
    /// Some material has a volume: paths track whether they are inside one.
    pub(crate) any_volume: bool,
    /// Per material, its BSDF when no texture varies it (at a placeholder frame; see
    /// [`Scene::bsdf_at`]). Derived from `materials` at build time.
    bsdf_templates: Vec<Option<Bsdf>>,
    /// What the wavefront integrator needs, for a scene it can render. Derived at build time.
    pub(crate) diffuse: Option<DiffuseScene>,
    /// The caustic guide, built on first use (`caustics.rs`).
    caustics: std::sync::OnceLock<Option<Arc<crate::guide::CausticGuide>>>,
}

impl Scene {
    /// True if some material has alpha (MASK or BLEND).
    #[inline]
    pub fn any_alpha(&self) -> bool {
        self.any_alpha
    }

    /// Lights the scene with an environment (`None` takes it away). The environment is part of the
    /// render rather than of the glTF file, which cannot carry one; it takes its share of the light
    /// samples by power against the emissive triangles (see [`crate::light`]).
    pub fn with_environment(mut self, environment: Option<Environment>) -> Self {
        let radius = 0.5 * (self.info.bounds_max - self.info.bounds_min).length();
        self.lights.set_environment(environment, radius.max(1e-3));
        self.diffuse = DiffuseScene::new(
            &self.materials,
            &self.bsdf_templates,
            &self.textures,
            &self.mesh,
            &self.instances,
            &self.lights,
        );
        self
    }

    /// Replaces the camera (e.g. one chosen by name).
    pub fn with_camera(mut self, camera: Camera) -> Self {
        self.camera = camera;
        self
    }
}
