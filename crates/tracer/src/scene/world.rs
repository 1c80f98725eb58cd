//! The world-space triangles of a scene (those placed once, and every emitter), their BVH and the
//! area lights over them: built once per scene, and shared (`Arc`) by the scenes an animation's
//! frames make when nothing in them moves.

use super::{drop_degenerate, SceneError};
use crate::geometry::{Bvh, Mesh};
use crate::light::AreaLights;
use crate::material::{Material, Texture};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Arc;

/// World-space triangles with their BVH and area lights.
#[derive(Clone, Debug)]
pub struct World {
    /// The triangles, renderable ones only, in the order they were given.
    pub mesh: Arc<Mesh>,
    pub bvh: Arc<Bvh>,
    pub area: AreaLights,
    /// Degenerate triangles dropped by the build.
    pub dropped: usize,
    /// Wall seconds the BVH's build took (for reports).
    pub bvh_seconds: f64,
    /// The box of every corner; inverted (+∞, −∞) without triangles.
    lo: Vec3,
    hi: Vec3,
}

impl World {
    /// Checks the mesh against the materials, drops its degenerate triangles, builds the BVH and
    /// collects the emissive triangles.
    pub fn build(
        mesh: Mesh,
        materials: &[Material],
        textures: &[Texture],
    ) -> Result<World, SceneError> {
        let (mesh, dropped) = World::checked(mesh, materials)?;
        let started = std::time::Instant::now();
        let bvh = Bvh::build(&mesh);
        let bvh_seconds = started.elapsed().as_secs_f64();
        tracing::debug!(triangles = mesh.len(), bvh_seconds, "built the BVH");
        let started = std::time::Instant::now();
        let area = AreaLights::new(&mesh, materials, textures);
        tracing::debug!(
            lights = area.triangles.len(),
            seconds = started.elapsed().as_secs_f64(),
            "collected the area lights"
        );
        let (lo, hi) = mesh.bounds();
        Ok(World {
            mesh: Arc::new(mesh),
            bvh: Arc::new(bvh),
            area,
            dropped,
            bvh_seconds,
            lo,
            hi,
        })
    }

    /// What [`World::build`] does before it builds anything: the mesh checked against the
    /// materials, without its degenerate triangles, and how many were dropped.
    pub(super) fn checked(
        mut mesh: Mesh,
        materials: &[Material],
    ) -> Result<(Mesh, usize), SceneError> {
        mesh.validate()?;
        // The first bad triangle, found in parallel.
        if let Some((triangle, &material)) = mesh
            .material
            .par_iter()
            .enumerate()
            .find_first(|(_, &m)| m as usize >= materials.len())
        {
            return Err(SceneError::MaterialIndex {
                triangle,
                material,
                count: materials.len(),
            });
        }
        let dropped = drop_degenerate(&mut mesh);
        Ok((mesh, dropped))
    }

    /// The box of every corner; inverted (+∞, −∞) without triangles.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.lo, self.hi)
    }
}
