//! Watertight ray/triangle intersection (Woop, Benthin & Wald, "Watertight Ray/Triangle
//! Intersection", JCGT 2013). Edges shared by two triangles are hit by exactly one of them (or both),
//! never by neither, so light cannot leak through the seams of a closed mesh.

use super::Ray;
use glam::Vec3;

/// Per-ray constants of the watertight test: the axis permutation (kx, ky, kz) that makes `d.z`
/// the largest component, and the shear (sx, sy, sz) that maps the ray onto +z. A vertex's sheared
/// coordinates are x' = (v−o)[kx] − sx·(v−o)[kz], y' = (v−o)[ky] − sy·(v−o)[kz],
/// z' = sz·(v−o)[kz], as in the paper (which divides for sx = d[kx]/d[kz] and sy where this
/// multiplies by sz = 1/d[kz]); the packet tests of the BVH and of flat meshes perform the same
/// operations lane by lane, so all give the same bits.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    pub o: Vec3,
    pub(crate) k: [usize; 3],
    pub(crate) s: [f32; 3],
    /// [`box_reciprocal`] of the direction: for the flat mesh's box test, which would otherwise
    /// divide in every query, its result waited for by the packet tests behind it.
    pub(crate) inv_d: [f32; 3],
}

/// 1/d per axis for the slab tests of boxes, a component smaller than 1e-9 nudged to ±1e-9 first:
/// a component of exactly zero would make 0 · ∞ = NaN at a slab through the origin; nudged, the
/// slab is crossed at a huge but finite distance, and the padded boxes cover the nudge's
/// displacement. Only the box tests see it. All three components at once: the nudge is a select,
/// not a branch per component.
#[inline(always)]
pub(crate) fn box_reciprocal(d: Vec3) -> [f32; 3] {
    nudged(d, glam::Vec3A::ONE / glam::Vec3A::from(d))
}

/// [`box_reciprocal`] given 1/d: a component of d smaller than 1e-9 gets ±(1/1e-9) instead (the
/// quotient of the nudged component, the same bits: one division per lane either way).
#[inline(always)]
fn nudged(d: Vec3, reciprocal: glam::Vec3A) -> [f32; 3] {
    let d = glam::Vec3A::from(d);
    let tiny = d.abs().cmplt(glam::Vec3A::splat(1e-9));
    let nudge = glam::Vec3A::splat(1.0 / 1e-9f32).copysign(d);
    glam::Vec3A::select(tiny, nudge, reciprocal).to_array()
}

impl RayPrecomp {
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        // Arrays rather than glam's `Vec3[i]`, which is a `match` on i: the axes depend on the
        // direction, which is random, so every such branch would be mispredicted half the time.
        // For the same reason the axis choice is written as selects.
        let d = ray.d.to_array();
        let a = ray.d.abs();
        // kz: the largest |d| component (x, then y, then z on ties, as in the paper's code).
        let x_over_y = a.x > a.y;
        let (larger, larger_axis) = if x_over_y { (a.x, 0) } else { (a.y, 1) };
        let kz = if larger > a.z { larger_axis } else { 2 };
        // (kx, ky) = the two axes after kz in cyclic order, swapped for a negative d[kz] (which
        // keeps the winding of the sheared triangle). A table, so no switch on kz is generated.
        const AXES: [[[usize; 2]; 2]; 3] = [[[1, 2], [2, 1]], [[2, 0], [0, 2]], [[0, 1], [1, 0]]];
        let [kx, ky] = AXES[kz][usize::from(d[kz] < 0.0)];
        // One division for the three reciprocals, which the shear and the box tests share: the
        // shear multiplies by 1/d[kz] where the paper divides by d[kz] (any fixed shear per ray
        // keeps the test watertight: the shared vertices of two triangles are transformed alike).
        let reciprocal = glam::Vec3A::ONE / glam::Vec3A::from(ray.d);
        let sz = reciprocal.to_array()[kz];
        RayPrecomp {
            o: ray.o,
            k: [kx, ky, kz],
            s: [d[kx] * sz, d[ky] * sz, sz],
            inv_d: nudged(ray.d, reciprocal),
        }
    }

    /// A vertex's sheared coordinates.
    #[inline(always)]
    fn shear(&self, v: Vec3) -> Vec3 {
        let [kx, ky, kz] = self.k;
        // (v − o)[k] as v[k] − o[k] (the same operation), each component of `o` read by its
        // index: one 4-byte load each where the caller stored them one at a time. A load of the
        // whole of `o` spans two of those stores and cannot be forwarded from them (a stall that
        // showed at the start of the flat queries, which hoist this for their edge cases).
        let (v, o): ([f32; 3], &[f32; 3]) = (v.to_array(), self.o.as_ref());
        let d = |k: usize| v[k] - o[k];
        let [sx, sy, sz] = self.s;
        let dz = d(kz);
        Vec3::new(d(kx) - sx * dz, d(ky) - sy * dz, sz * dz)
    }
}

/// Where a ray hits a triangle: distance and barycentrics (b0 for v0, b1 for v1, b2 for v2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    pub t: f32,
    pub b1: f32,
    pub b2: f32,
}

/// Intersects the ray with triangle `v` for t in (0, t_max). Both faces are hit.
#[inline(always)]
pub fn intersect_watertight(r: &RayPrecomp, v: &[Vec3; 3], t_max: f32) -> Option<TriangleHit> {
    let a = r.shear(v[0]);
    let b = r.shear(v[1]);
    let c = r.shear(v[2]);
    let (ax, ay, bx, by, cx, cy) = (a.x, a.y, b.x, b.y, c.x, c.y);
    let mut u = cx * by - cy * bx;
    let mut vv = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    if u == 0.0 || vv == 0.0 || w == 0.0 {
        // Exactly on an edge in single precision: decide in double precision so the shared edge is
        // classified the same way for both triangles.
        u = (cx as f64 * by as f64 - cy as f64 * bx as f64) as f32;
        vv = (ax as f64 * cy as f64 - ay as f64 * cx as f64) as f32;
        w = (bx as f64 * ay as f64 - by as f64 * ax as f64) as f32;
    }
    if (u < 0.0 || vv < 0.0 || w < 0.0) && (u > 0.0 || vv > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + vv + w;
    let t_scaled = u * a.z + vv * b.z + w * c.z;
    // t = t_scaled / det must lie in (0, t_max); compare without dividing, minding det's sign
    // (det = 0 fails both). Written as comparisons that must hold, so that a NaN (from
    // coordinates whose products overflow) is a miss, as in the lanes of the packet tests, and
    // never a hit at a NaN distance.
    let in_range = if det > 0.0 {
        0.0 < t_scaled && t_scaled < t_max * det
    } else {
        det < 0.0 && t_scaled < 0.0 && t_max * det < t_scaled
    };
    if !in_range {
        return None;
    }
    let inv = 1.0 / det;
    Some(TriangleHit {
        t: t_scaled * inv,
        b1: vv * inv,
        b2: w * inv,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3, v: &[Vec3; 3]) -> Option<TriangleHit> {
        intersect_watertight(&RayPrecomp::new(&Ray::new(o, d)), v, f32::INFINITY)
    }

    #[test]
    fn hits_inside_and_reports_barycentrics() {
        let v = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let h = hit(Vec3::new(0.25, 0.5, 1.0), -Vec3::Z, &v).expect("hit");
        assert!((h.t - 1.0).abs() < 1e-6);
        assert!((h.b1 - 0.25).abs() < 1e-6 && (h.b2 - 0.5).abs() < 1e-6);
        // Back face too.
        assert!(hit(Vec3::new(0.25, 0.25, -1.0), Vec3::Z, &v).is_some());
        assert!(hit(Vec3::new(0.75, 0.75, 1.0), -Vec3::Z, &v).is_none());
        assert!(
            hit(Vec3::new(0.25, 0.25, 1.0), Vec3::Z, &v).is_none(),
            "behind the origin"
        );
    }

    #[test]
    fn overflowing_coordinates_are_a_miss_not_a_nan_hit() {
        // Products of these coordinates overflow, so det or t_scaled is NaN: once reported as a
        // hit at a NaN distance (the NaN slipped past comparisons meant to reject).
        let big = [
            [
                Vec3::new(3e30, -2e30, 1e30),
                Vec3::new(-1e30, 4e30, -2e30),
                Vec3::ZERO,
            ],
            [
                Vec3::new(1e30, -1e30, 1e30),
                Vec3::new(0.2, -0.3, 0.1),
                Vec3::new(-3e30, 2e30, 5e29),
            ],
        ];
        let mut rng = crate::testing::uniform_stream(7);
        for _ in 0..2000 {
            let o = Vec3::new(rng(), rng(), rng()) * 4.0 - 2.0;
            let d = (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize_or(Vec3::X);
            for v in &big {
                if let Some(h) = hit(o, d, v) {
                    assert!(h.t.is_finite() && h.t > 0.0, "{h:?} from {o} along {d}");
                }
            }
        }
    }

    #[test]
    fn shared_edges_are_watertight() {
        // Two triangles sharing the diagonal of the unit square; rays aimed exactly at the diagonal
        // from many directions must hit at least one of them.
        let t0 = [
            Vec3::ZERO,
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        let t1 = [
            Vec3::ZERO,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let mut misses = 0;
        for i in 0..2000 {
            let s = (i as f32 + 0.5) / 2000.0;
            let target = Vec3::new(s, s, 0.0);
            let o = Vec3::new(
                0.3 + 0.1 * (i as f32).sin(),
                0.7,
                1.3 + 0.2 * (i as f32).cos(),
            );
            let d = (target - o).normalize();
            if hit(o, d, &t0).is_none() && hit(o, d, &t1).is_none() {
                misses += 1;
            }
        }
        assert_eq!(misses, 0);
    }
}
