//! Instancing without flattening: a two-level BVH.
//!
//! A mesh that several nodes place is kept once, in its own (object) space, with its own 4-wide BVH
//! (a [`Prototype`]); each placement is an [`Instance`] (a transform and its inverse), and a 4-wide
//! tree over the instances' world boxes ([`BoxTree`]) finds the instances a ray may hit. A ray entering an instance
//! is moved into object space (o and d by the inverse transform; d is not renormalised, so t is
//! the same parameter in both spaces) and answered by the prototype's BVH. Which meshes are kept
//! this way is the loader's decision (`gltf::instancing`); hand-built scenes pass their own.
//!
//! Contract (the one of [`super::Bvh`], across levels): the closest hit is the one with the
//! smallest `(t, instance, triangle)` among all accepted hits in (0, t_max), so the answer never
//! depends on the order the tree is walked in; the instance boxes are padded so that they never cull
//! an instance whose object-space test would hit.

mod flatten;
mod place;
#[cfg(test)]
mod tests;
mod trace;

pub use flatten::flatten_into;
pub use place::usable_placements;
pub use trace::InstanceHit;

use super::bvh::BoxTree;
use super::{Bvh, Mesh};
use glam::{Affine3A, DAffine3, DMat3, DMat4, DVec3, Mat3A, Vec3, Vec3A};
use std::sync::Arc;

/// A mesh kept once in object space, with its BVH.
#[derive(Clone, Debug)]
pub struct Prototype {
    pub mesh: Mesh,
    pub bvh: Bvh,
    /// Object-space boxes that together hold every triangle (see [`Bvh::cover`]): what a
    /// placement's world box is made of.
    cover: Vec<(Vec3, Vec3)>,
}

/// The most boxes of a prototype's tree moved into world space to bound one placement: three
/// levels of a 4-wide tree.
const COVER_BOXES: usize = 64;

/// Where a loader places a prototype: its index and the node's world transform (an affine matrix;
/// the last row is ignored, as glTF requires it to be 0 0 0 1).
#[derive(Clone, Debug)]
pub struct Placement {
    pub prototype: u32,
    pub to_world: DMat4,
}

/// One placement of a prototype, with what a hit needs to move into world space.
#[derive(Clone, Debug)]
pub struct Instance {
    pub prototype: u32,
    pub to_world: Affine3A,
    pub to_object: Affine3A,
    /// The inverse transpose of the linear part times |det| (the cofactor matrix times the sign of
    /// the determinant): world normals up to length, computed as the flattening loader does.
    pub normal_matrix: Mat3A,
    /// The transform mirrors (negative determinant): two corners of each triangle swap, so that
    /// the counter-clockwise side stays the front, as the flattening loader does.
    pub flip: bool,
}

/// Every instance of the scene and the tree over them. Empty for a scene without instances, and
/// then free: its queries return at once. The prototypes are shared (an animated scene's frames
/// place the same prototypes, each built once).
#[derive(Clone, Debug, Default)]
pub struct Instances {
    pub prototypes: Vec<Arc<Prototype>>,
    /// In the top-level tree's leaf order (the index is the instance's identity in hits).
    pub instances: Vec<Instance>,
    tree: BoxTree,
}

/// Placements dropped for a singular or non-finite transform, and the triangles they would have
/// placed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Unplaced {
    pub placements: usize,
    pub triangles: usize,
}

/// Why placements cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum InstanceError {
    #[error("instance {instance} places prototype {prototype}, but there are {count} prototypes")]
    Prototype {
        instance: usize,
        prototype: u32,
        count: usize,
    },
    #[error("{count} instances: at most {max} can be placed")]
    TooMany { count: usize, max: usize },
}

impl Prototype {
    /// Builds the prototype's BVH. The mesh must hold only renderable triangles (as
    /// [`crate::scene::Scene::build`] leaves them).
    pub fn new(mesh: Mesh) -> Prototype {
        let bvh = Bvh::build(&mesh);
        let cover = bvh
            .cover(COVER_BOXES)
            .unwrap_or_else(|| vec![mesh.bounds()]);
        Prototype { mesh, bvh, cover }
    }

    /// Approximate bytes held.
    pub fn bytes(&self) -> usize {
        self.mesh.bytes() + self.bvh.bytes()
    }
}

impl Instance {
    /// The instance of `prototype` under `to_world`, or `None` when the transform is singular or
    /// not finite (nothing of it could be hit or shaded).
    fn new(prototype: u32, to_world: &DMat4) -> Option<Instance> {
        let affine = DAffine3::from_mat4(*to_world);
        let m3 = affine.matrix3;
        let det = m3.determinant();
        if !(det.is_finite() && det != 0.0 && affine.translation.is_finite()) {
            return None;
        }
        let inverse = affine.inverse();
        if !(inverse.matrix3.is_finite() && inverse.translation.is_finite()) {
            return None;
        }
        let sign = if det < 0.0 { -1.0 } else { 1.0 };
        let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
        let normal_matrix = DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign;
        let f32_affine = |a: DAffine3| {
            Affine3A::from_mat3_translation(a.matrix3.as_mat3(), a.translation.as_vec3())
        };
        Some(Instance {
            prototype,
            to_world: f32_affine(affine),
            to_object: f32_affine(inverse),
            normal_matrix: Mat3A::from(normal_matrix.as_mat3()),
            flip: det < 0.0,
        })
    }

    /// The world box of the object boxes `cover` under this instance, from the f64 transform,
    /// padded for the rounding of the object-space ray: a small fraction of its size and position.
    fn world_box(to_world: &DMat4, cover: &[(Vec3, Vec3)]) -> (Vec3A, Vec3A) {
        let (mut wlo, mut whi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (k, &(lo, hi)) in (0..8).flat_map(|k| cover.iter().map(move |b| (k, b))) {
            let pick = |bit: usize, a: f32, b: f32| if k & bit == 0 { a } else { b } as f64;
            let corner = DVec3::new(
                pick(1, lo.x, hi.x),
                pick(2, lo.y, hi.y),
                pick(4, lo.z, hi.z),
            );
            let w = to_world.transform_point3(corner);
            wlo = wlo.min(w);
            whi = whi.max(w);
        }
        let scale = (whi - wlo)
            .max_element()
            .max(wlo.abs().max(whi.abs()).max_element());
        let pad = DVec3::splat(scale * 1e-5 + f32::MIN_POSITIVE as f64);
        (
            Vec3A::from((wlo - pad).as_vec3()),
            Vec3A::from((whi + pad).as_vec3()),
        )
    }
}

impl Instances {
    /// Whether the scene has any instance.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.instances.is_empty()
    }

    /// The world-space box of everything instanced, or `None` without instances.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.tree.bounds()
    }

    /// Triangles stored once per prototype.
    pub fn stored_triangles(&self) -> usize {
        self.prototypes.iter().map(|p| p.mesh.len()).sum()
    }

    /// Triangles the instances place in the world (each prototype's count once per instance).
    pub fn placed_triangles(&self) -> u64 {
        self.instances
            .iter()
            .map(|i| self.prototypes[i.prototype as usize].mesh.len() as u64)
            .sum()
    }

    /// Approximate bytes held: prototypes, instances and the tree.
    pub fn bytes(&self) -> usize {
        self.prototypes.iter().map(|p| p.bytes()).sum::<usize>()
            + self.instances.len() * std::mem::size_of::<Instance>()
            + self.tree.bytes()
    }

    /// The instance and its prototype.
    #[inline(always)]
    pub fn get(&self, instance: u32) -> (&Instance, &Prototype) {
        let inst = &self.instances[instance as usize];
        (inst, &self.prototypes[inst.prototype as usize])
    }
}
