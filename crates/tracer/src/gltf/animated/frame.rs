//! A scene at a time, from a loaded [`AnimatedScene`] and nothing else (no bytes, no parsing): the
//! nodes posed, the placements moved, the moving emitters and the animated deformations emitted
//! again, and the scene put together from the parts built at load (shared) and these.
//!
//! What a frame builds: the tree over the placements, one BVH over the frame's deformed triangles
//! (all deforming meshes together, in world space, placed once by the identity), and — only when
//! some emitter moves or deforms — the world-space triangles' BVH and area lights. The rest is
//! shared with the loaded scene and with every other frame: the world-space triangles and their
//! BVH when no emitter moves, every instanced mesh with its BVH, the materials' textures.

use super::deform::Posed;
use super::error::AnimationError;
use super::pose::Pose;
use super::{placed, AnimatedScene, DeformedNode, WorldSource};
use crate::geometry::{Instances, Placement, Prototype};
use crate::gltf::bounds::{self, outside, MAX_COORDINATE};
use crate::gltf::emit::{emit, Origin};
use crate::gltf::error::{GltfError, Warnings};
use crate::gltf::mesh::empty_mesh;
use crate::gltf::nodes::Instance;
use crate::gltf::{camera, lights};
use crate::scene::{drop_degenerate, Assembly, Scene, SceneError, World};
use glam::DMat4;
use std::sync::Arc;

impl DeformedNode {
    /// The transforms its posed vertices are emitted under: the identity for a skinned mesh
    /// (skinning lands in world space), else its node's (by each instancing row).
    pub(crate) fn worlds(&self, pose: &Pose) -> Vec<DMat4> {
        match self.skin {
            Some(_) => vec![DMat4::IDENTITY],
            None => placed(pose.world[self.node], &self.rows),
        }
    }

    /// Its primitives posed: morphed by the node's weights, skinned by its skin's joints.
    pub(crate) fn pose<'a>(
        &'a self,
        skins: &[super::skin::Skin],
        pose: &Pose,
    ) -> impl Iterator<Item = (&'a super::deform::Deformable, Posed)> {
        let joints = self.skin.map(|k| skins[k].joint_matrices(&pose.world));
        let weights = pose.weights[self.node].clone().unwrap_or_default();
        let node_world = pose.world[self.node];
        self.primitives.iter().map(move |p| {
            let posed = p.pose(&weights, joints.as_deref(), &node_world);
            (p, posed)
        })
    }
}

impl AnimatedScene {
    pub(super) fn build_at(&self, time: f32) -> Result<Scene, GltfError> {
        let root = &self.root;
        let pose = self.hierarchy.pose(root, &self.channels, time)?;
        let at = |reason: String| GltfError::from(AnimationError::AtTime { time, reason });
        let mut dropped = self.dropped;
        let mut far = None;

        // The placements of instanced meshes, where the nodes are now.
        let mut placements: Vec<Placement> = self
            .placements
            .iter()
            .map(|p| {
                let world = pose.world[p.node];
                Placement {
                    prototype: p.prototype,
                    to_world: p.row.map_or(world, |row| world * row),
                }
            })
            .collect();
        let mut prototypes = self.prototypes.clone();

        // Deforming meshes: the emitters' into the world-space triangles, the others into one
        // world-space prototype of this frame.
        let mut moved_world = empty_mesh(&self.needs);
        let mut deformed = empty_mesh(&self.needs);
        for d in &self.deformed {
            let worlds = d.worlds(&pose);
            let out = if d.emits {
                &mut moved_world
            } else {
                &mut deformed
            };
            let origin = Origin {
                node: d.node,
                mesh: d.mesh,
            };
            for (p, posed) in d.pose(&self.skins, &pose) {
                let v = posed.vertices(&p.base);
                for world in &worlds {
                    let done = emit(out, &v, world, p.base.material, origin, far.is_none());
                    dropped += done.dropped;
                    far = far.or(done.far);
                }
            }
        }
        for e in &self.emitters {
            let origin = Origin {
                node: e.node,
                mesh: e.mesh,
            };
            for world in placed(pose.world[e.node], &e.rows) {
                for p in &e.primitives {
                    let v = p.vertices();
                    let done = emit(
                        &mut moved_world,
                        &v,
                        &world,
                        p.material,
                        origin,
                        far.is_none(),
                    );
                    dropped += done.dropped;
                    far = far.or(done.far);
                }
            }
        }
        bounds::check(root, far)?;
        if !deformed.is_empty() {
            dropped += drop_degenerate(&mut deformed);
            if !deformed.is_empty() {
                placements.push(Placement {
                    prototype: prototypes.len() as u32,
                    to_world: DMat4::IDENTITY,
                });
                prototypes.push(Arc::new(Prototype::new(deformed)));
            }
        }
        let (instances, unplaced) =
            Instances::place(prototypes, &placements).map_err(SceneError::from)?;
        dropped += unplaced.triangles;
        if let Some((lo, hi)) = instances.bounds() {
            if outside(lo) || outside(hi) {
                return Err(at(format!(
                    "the moving meshes reach from {lo} to {hi}, beyond ±{MAX_COORDINATE:e} \
                     (scale the scene down)"
                )));
            }
        }
        let built;
        let world = match &self.world {
            WorldSource::Shared(w) => w,
            WorldSource::PerFrame(still) => {
                let mut mesh = still.clone();
                append(&mut mesh, moved_world);
                built = World::build(mesh, &self.materials, &self.textures)?;
                &built
            }
        };

        // Lights and the camera where their nodes are now.
        let mut scratch = Warnings::default();
        let mut punctual_lights = Vec::new();
        for &node in &self.lights {
            if let Some(l) = lights::node_light(root, node, &pose.world[node], &mut scratch)? {
                punctual_lights.push(l);
            }
        }
        let camera = match self.camera {
            Some((node, index)) => {
                let placed = Instance {
                    node,
                    world: pose.world[node],
                };
                Some(camera::convert(root, index, &placed)?)
            }
            None => None,
        };
        Ok(Scene::assemble(Assembly {
            world,
            instances,
            materials: self.materials.clone(),
            textures: self.textures.clone(),
            punctual_lights,
            camera,
            warnings: self.warnings.clone(),
            degenerate_dropped: dropped + world.dropped,
        }))
    }
}

/// Appends `more`'s triangles to `mesh` (both with the same attribute arrays).
fn append(mesh: &mut crate::geometry::Mesh, more: crate::geometry::Mesh) {
    mesh.positions.extend(more.positions);
    mesh.material.extend(more.material);
    fn extend<T>(a: &mut Option<Vec<T>>, b: Option<Vec<T>>) {
        if let (Some(a), Some(b)) = (a, b) {
            a.extend(b);
        }
    }
    extend(&mut mesh.normals, more.normals);
    extend(&mut mesh.uv0, more.uv0);
    extend(&mut mesh.uv1, more.uv1);
    extend(&mut mesh.tangents, more.tangents);
}
