//! The acceleration structure: an 8-wide compressed BVH (CWBVH) built by `obvhs` (PLOC with
//! reinsertion), traversed with its SIMD node test.

use super::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::{builder::build_cwbvh, CwBvh};
use obvhs::ray::Ray as ObRay;
use obvhs::{Boundable, BvhBuildParams};
use std::time::Duration;

/// The direction the node tests use. obvhs' CWBVH node test misses boxes for rays with a direction
/// component of exactly zero (e.g. every ray of an orthographic camera looking down an axis), so
/// such components are nudged to a tiny value. Only the box tests see it: triangles are intersected
/// with the true direction, and the padded boxes cover the nudge's displacement.
#[inline]
fn traversal_direction(d: Vec3) -> Vec3A {
    let nudge = |c: f32| {
        if c.abs() < 1e-9 {
            1e-9f32.copysign(c)
        } else {
            c
        }
    };
    Vec3A::new(nudge(d.x), nudge(d.y), nudge(d.z))
}

/// A triangle's (padded) bounding box, as the BVH builder sees it.
struct PaddedBox(Aabb);

impl Boundable for PaddedBox {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

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
        // Every triangle's box is padded by a small fraction of the scene's size. Flat boxes (a
        // triangle in an axis-aligned plane alone in a node) defeat the quantized child boxes of the
        // CWBVH nodes and were missed entirely; padding also keeps the box test conservative at the
        // exact boundary where the watertight triangle test still reports a hit.
        let mut scene = Aabb::empty();
        for t in &mesh.positions {
            for v in t {
                scene.extend(Vec3A::from(*v));
            }
        }
        let pad = Vec3A::splat(scene.diagonal().max_element() * 1e-6 + f32::MIN_POSITIVE);
        let boxes: Vec<PaddedBox> = mesh
            .positions
            .iter()
            .map(|t| {
                let b =
                    Aabb::from_points(&[Vec3A::from(t[0]), Vec3A::from(t[1]), Vec3A::from(t[2])]);
                let ulps = |v: Vec3A| v.abs() * (4.0 * f32::EPSILON);
                PaddedBox(Aabb::new(
                    b.min - pad - ulps(b.min),
                    b.max + pad + ulps(b.max),
                ))
            })
            .collect();
        // No spatial pre-splits: every primitive appears exactly once, so the mesh can be reordered.
        let mut params = BvhBuildParams::medium_build();
        params.pre_split = false;
        params.max_prims_per_leaf = 3;
        let bvh = build_cwbvh(&boxes, params, &mut Duration::default());
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
        let ray = ObRay::new(o.into(), traversal_direction(d), 0.0, t_max);
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
        let ray = ObRay::new(o.into(), traversal_direction(d), 0.0, t_max);
        !bvh.ray_traverse_miss(ray, |r, id| intersect(id, r.tmax))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{intersect_watertight, Ray, RayPrecomp};

    #[test]
    fn tiny_meshes_are_hit() {
        for n in 1..=9 {
            let mut mesh = Mesh::default();
            for k in 0..n {
                let z = -(k as f32) - 1.0;
                let (a, b, c) = (
                    Vec3::new(-1., -1., z),
                    Vec3::new(1., -1., z),
                    Vec3::new(0., 1., z),
                );
                mesh.positions.push([a, b, c]);
                mesh.material.push(0);
            }
            let (bvh, order) = Bvh::build(&mesh);
            mesh.reorder(&order);
            for (o, d, t) in [
                (
                    Vec3::new(0.01, 0.02, 0.5),
                    Vec3::new(0.001, 0.002, -1.0).normalize(),
                    1.5,
                ),
                // Axis-parallel rays (every ray of an orthographic camera).
                (Vec3::new(0.1, 0.2, 0.0), -Vec3::Z, 1.0),
                (Vec3::ZERO, -Vec3::Z, 1.0),
            ] {
                let pre = RayPrecomp::new(&Ray::new(o, d));
                let mut best = f32::INFINITY;
                let hit = bvh.closest(o, d, f32::INFINITY, |id, tm| {
                    match intersect_watertight(&pre, &mesh.positions[id], tm) {
                        Some(h) => {
                            best = best.min(h.t);
                            h.t
                        }
                        None => f32::INFINITY,
                    }
                });
                assert!(hit, "{n} triangles: missed {d}");
                assert!((best - t).abs() < 1e-4, "{n} triangles, {d}: {best}");
                let blocked = bvh.any(o, d, 10.0, |id, tm| {
                    intersect_watertight(&pre, &mesh.positions[id], tm)
                        .map_or(f32::INFINITY, |h| h.t)
                });
                assert!(blocked, "{n} triangles: shadow ray {d} not blocked");
            }
        }
    }
}
