//! The acceleration structure: an 8-wide compressed BVH (CWBVH) built by `obvhs` (PLOC with
//! reinsertion), traversed with its SIMD node test.

use super::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::{builder::build_cwbvh_from_tris, CwBvh};
use obvhs::ray::Ray as ObRay;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use std::time::Duration;

/// A BVH over a [`Mesh`]. After [`Bvh::build`] the mesh must be reordered with the returned order, so
/// that BVH primitive `i` is mesh triangle `i` (no indirection on the hot path).
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    inner: Option<CwBvh>,
}

impl Bvh {
    /// Builds the BVH; returns it and the triangle order (`order[k]` = old index of new triangle k).
    pub fn build(mesh: &Mesh) -> (Bvh, Vec<u32>) {
        if mesh.is_empty() {
            return (Bvh { inner: None }, Vec::new());
        }
        let tris: Vec<Triangle> = mesh
            .positions
            .iter()
            .map(|[a, b, c]| Triangle {
                v0: Vec3A::from(*a),
                v1: Vec3A::from(*b),
                v2: Vec3A::from(*c),
            })
            .collect();
        // No spatial pre-splits: every primitive appears exactly once, so the mesh can be reordered.
        let mut params = BvhBuildParams::medium_build();
        params.pre_split = false;
        params.max_prims_per_leaf = 3;
        let bvh = build_cwbvh_from_tris(&tris, params, &mut Duration::default());
        let mut order = bvh.primitive_indices.clone();
        let mut bvh = bvh;
        for (i, p) in bvh.primitive_indices.iter_mut().enumerate() {
            *p = i as u32;
        }
        order.truncate(mesh.len());
        (Bvh { inner: Some(bvh) }, order)
    }

    /// Number of BVH nodes (for memory reports).
    pub fn node_count(&self) -> usize {
        self.inner.as_ref().map_or(0, |b| b.nodes.len())
    }

    /// Approximate memory in bytes.
    pub fn bytes(&self) -> usize {
        self.inner
            .as_ref()
            .map_or(0, |b| b.nodes.len() * 80 + b.primitive_indices.len() * 4)
    }

    /// Finds the closest primitive along the ray in (0, t_max). `intersect(id, t_max)` tests primitive
    /// `id` and returns its distance if it is hit closer than `t_max` (or +∞).
    #[inline]
    pub fn closest(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        mut intersect: impl FnMut(usize, f32) -> f32,
    ) -> bool {
        let Some(bvh) = &self.inner else { return false };
        let ray = ObRay::new(o.into(), d.into(), 0.0, t_max);
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray, &mut hit, |r, id| intersect(id, r.tmax))
    }

    /// True if any primitive blocks the ray in (0, t_max). `intersect(id, t_max)` as for
    /// [`Bvh::closest`].
    #[inline]
    pub fn any(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        mut intersect: impl FnMut(usize, f32) -> f32,
    ) -> bool {
        let Some(bvh) = &self.inner else { return false };
        let ray = ObRay::new(o.into(), d.into(), 0.0, t_max);
        !bvh.ray_traverse_miss(ray, |r, id| intersect(id, r.tmax))
    }
}
