//! Two rays traced together: a closest-hit ray and a shadow ray, or two of a kind.
//!
//! A single ray's traversal is a chain of dependent steps (test a node, pick the nearest child,
//! load it, test it, …), and on the small trees of typical scenes the chain's latency, not the
//! number of instructions, is most of its time. At a path vertex the continuation ray and the
//! shadow ray towards the sampled light point are independent, so the two traversals are advanced
//! in the same loop, one step of each per iteration: the processor overlaps the two chains. The
//! wavefront's lanes pair their closest-hit rays the same way where a lane has no shadow ray (a
//! sky left to the BSDF, a specular bounce), two lanes' rays a walk, and their lamps' shadow rays.
//!
//! The three pairs' loops are written out: one generic helper taking each walk's step as a
//! closure made smaller code that ran 1.8–2.0 % slower on two peer scenes (docs/benchmarks.md).
//!
//! Each traversal is exactly [`Bvh::closest`] or [`Bvh::any`] (the same walks, `walk.rs`),
//! so the answers are the same: by the BVH's contract the closest hit does not depend on the order
//! in which nodes are visited, and here it is not even changed.

use super::packet::PacketRay;
use super::walk::{AnyWalk, ClosestWalk};
use super::{BoxRay, Bvh, Closest};
use crate::geometry::{RayPrecomp, TriangleHit};
use glam::Vec3;

/// A hit as [`Bvh::closest`] reports it: the triangle and where the ray meets it.
type BvhHit = (u32, TriangleHit);

/// One query's ray: its precomputed constants, its direction, and its distance limit.
#[derive(Clone, Copy, Debug)]
pub struct RayQuery<'a> {
    pub pre: &'a RayPrecomp,
    pub d: Vec3,
    pub t_max: f32,
}

impl Bvh {
    /// [`Bvh::closest`] of ray `a` and [`Bvh::any`] of ray `b`, traced together (see the module
    /// documentation): the same answers as the two calls.
    #[inline(always)]
    pub fn closest_and_any(
        &self,
        a: RayQuery,
        accept_a: impl FnMut(u32, &TriangleHit) -> bool,
        b: RayQuery,
        accept_b: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        self.closest_and_any_in::<false>(a, accept_a, b, accept_b)
    }

    /// [`Bvh::closest_and_any`], `INLINED` as in [`Bvh::closest_in`].
    #[inline(always)]
    pub fn closest_and_any_in<const INLINED: bool>(
        &self,
        a: RayQuery,
        mut accept_a: impl FnMut(u32, &TriangleHit) -> bool,
        b: RayQuery,
        mut accept_b: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        if let Some(flat) = &self.flat {
            // No chains of dependent steps to interleave: the two queries one after the other.
            return flat.closest_and_any::<INLINED>(
                (a.pre, a.t_max),
                &mut accept_a,
                (b.pre, b.t_max),
                &mut accept_b,
            );
        }
        let Some(root) = self.root else {
            return (None, false);
        };
        let (ray_a, boxes_a) = (PacketRay::new(a.pre), BoxRay::new(a.pre.o, a.d));
        let (ray_b, boxes_b) = (PacketRay::new(b.pre), BoxRay::new(b.pre.o, b.d));
        let mut best = Closest::new(a.t_max);
        let (mut wa, mut wb) = (ClosestWalk::new(root), AnyWalk::new(root));
        while wa.live && wb.live {
            self.closest_step(&mut wa, &ray_a, &boxes_a, &mut best, &mut accept_a);
            self.any_step(&mut wb, &ray_b, &boxes_b, b.t_max, &mut accept_b);
        }
        while wa.live {
            self.closest_step(&mut wa, &ray_a, &boxes_a, &mut best, &mut accept_a);
        }
        while wb.live {
            self.any_step(&mut wb, &ray_b, &boxes_b, b.t_max, &mut accept_b);
        }
        (best.found(), wb.hit)
    }

    /// [`Bvh::any_in`] of rays `a` and `b`, traced together (see the module documentation): the
    /// same answers as the two calls.
    #[inline(always)]
    pub fn any_pair_in<const INLINED: bool>(
        &self,
        a: RayQuery,
        mut accept_a: impl FnMut(u32, &TriangleHit) -> bool,
        b: RayQuery,
        mut accept_b: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (bool, bool) {
        if let Some(flat) = &self.flat {
            return (
                flat.any::<INLINED>(a.pre, a.t_max, &mut accept_a),
                flat.any::<INLINED>(b.pre, b.t_max, &mut accept_b),
            );
        }
        let Some(root) = self.root else {
            return (false, false);
        };
        let (ray_a, boxes_a) = (PacketRay::new(a.pre), BoxRay::new(a.pre.o, a.d));
        let (ray_b, boxes_b) = (PacketRay::new(b.pre), BoxRay::new(b.pre.o, b.d));
        let (mut wa, mut wb) = (AnyWalk::new(root), AnyWalk::new(root));
        while wa.live && wb.live {
            self.any_step(&mut wa, &ray_a, &boxes_a, a.t_max, &mut accept_a);
            self.any_step(&mut wb, &ray_b, &boxes_b, b.t_max, &mut accept_b);
        }
        while wa.live {
            self.any_step(&mut wa, &ray_a, &boxes_a, a.t_max, &mut accept_a);
        }
        while wb.live {
            self.any_step(&mut wb, &ray_b, &boxes_b, b.t_max, &mut accept_b);
        }
        (wa.hit, wb.hit)
    }

    /// [`Bvh::closest_in`] of rays `a` and `b`, traced together (see the module documentation):
    /// the same answers as the two calls.
    #[inline(always)]
    pub fn closest_pair_in<const INLINED: bool>(
        &self,
        a: RayQuery,
        mut accept_a: impl FnMut(u32, &TriangleHit) -> bool,
        b: RayQuery,
        mut accept_b: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<BvhHit>, Option<BvhHit>) {
        if let Some(flat) = &self.flat {
            return (
                flat.closest::<INLINED>(a.pre, a.t_max, &mut accept_a),
                flat.closest::<INLINED>(b.pre, b.t_max, &mut accept_b),
            );
        }
        let Some(root) = self.root else {
            return (None, None);
        };
        let (ray_a, boxes_a) = (PacketRay::new(a.pre), BoxRay::new(a.pre.o, a.d));
        let (ray_b, boxes_b) = (PacketRay::new(b.pre), BoxRay::new(b.pre.o, b.d));
        let (mut best_a, mut best_b) = (Closest::new(a.t_max), Closest::new(b.t_max));
        let (mut wa, mut wb) = (ClosestWalk::new(root), ClosestWalk::new(root));
        while wa.live && wb.live {
            self.closest_step(&mut wa, &ray_a, &boxes_a, &mut best_a, &mut accept_a);
            self.closest_step(&mut wb, &ray_b, &boxes_b, &mut best_b, &mut accept_b);
        }
        while wa.live {
            self.closest_step(&mut wa, &ray_a, &boxes_a, &mut best_a, &mut accept_a);
        }
        while wb.live {
            self.closest_step(&mut wb, &ray_b, &boxes_b, &mut best_b, &mut accept_b);
        }
        (best_a.found(), best_b.found())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Mesh, Ray, RayPrecomp};

    /// Traced together, a closest-hit ray and a shadow ray, two closest-hit rays or two shadow
    /// rays get the answers they get alone: on a random soup (shared vertices, duplicate
    /// triangles, so ties) and on a chain deeper than the traversal stack (the recursive
    /// fallbacks), with and without filters, with finite and infinite limits, whichever walk ends
    /// first.
    #[test]
    fn the_pair_answers_as_the_two_queries_do() {
        let mut rng = crate::testing::uniform_stream(0x9e37_79b9_7f4a_7c15u64);
        let soup = crate::testing::triangle_soup(&mut rng, 2000, 40, |rng| {
            Vec3::new(rng(), rng(), rng()) * 10.0 - 5.0
        });
        let mut chain = Mesh::default();
        for k in 0..160 {
            let c = Vec3::new(1.25f32.powi(k), 0.0, 0.0);
            let s = c.x * 0.05;
            chain.positions.push([
                c + Vec3::new(0.0, -s, -s),
                c + Vec3::new(0.0, s, -s),
                c + Vec3::new(0.0, 0.0, s),
            ]);
            chain.material.push(0);
        }
        // Few enough triangles for the flat test (`flat.rs`), where the processor has it.
        let small = crate::testing::triangle_soup(&mut rng, 24, 4, |rng| {
            Vec3::new(rng(), rng(), rng()) * 1.5 - 0.75
        });
        assert!(small.len() <= super::super::flat::MAX_TRIANGLES_AVX2);
        for (name, mesh, scale) in [
            ("soup", soup, 12.0f32),
            ("chain", chain, 0.1),
            ("small", small, 2.0),
        ] {
            let bvh = Bvh::build(&mesh);
            if name == "chain" {
                let depth = bvh.depth();
                assert!(
                    depth * 3 > super::super::STACK,
                    "chain depth {depth}: too shallow"
                );
            }
            let ray = |rng: &mut dyn FnMut() -> f32| {
                let o = if name == "chain" {
                    Vec3::new(
                        -1.0,
                        rng() * scale - scale / 2.0,
                        rng() * scale - scale / 2.0,
                    )
                } else {
                    Vec3::new(rng(), rng(), rng()) * scale - scale / 2.0
                };
                let d = if name == "chain" {
                    (Vec3::X + (Vec3::new(0.0, rng(), rng()) - 0.5) * 1e-3).normalize()
                } else {
                    (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize_or(Vec3::Y)
                };
                // The chain's first triangle is 2 away: half the rays stop short of it.
                let short = if name == "chain" { 1.5 } else { 4.0 };
                let t_max = if rng() < 0.5 { short } else { f32::INFINITY };
                (RayPrecomp::new(&Ray::new(o, d)), d, t_max)
            };
            let (mut closest_hits, mut blocked) = (0, 0);
            for case in 0..3000 {
                let (pa, da, ta) = ray(&mut rng);
                let (pb, db, tb) = ray(&mut rng);
                // Every third case rejects odd triangles in one query and even ones in the other.
                let filtered = case % 3 == 0;
                let fa = |id: u32, _: &TriangleHit| !filtered || id.is_multiple_of(2);
                let fb = |id: u32, _: &TriangleHit| !filtered || !id.is_multiple_of(2);
                let alone = (bvh.closest(&pa, da, ta, fa), bvh.any(&pb, db, tb, fb));
                let a = RayQuery {
                    pre: &pa,
                    d: da,
                    t_max: ta,
                };
                let b = RayQuery {
                    pre: &pb,
                    d: db,
                    t_max: tb,
                };
                assert_eq!(
                    bvh.closest_and_any(a, fa, b, fb),
                    alone,
                    "{name} case {case}"
                );
                let both = (alone.0, bvh.closest(&pb, db, tb, fb));
                assert_eq!(
                    bvh.closest_pair_in::<false>(a, fa, b, fb),
                    both,
                    "{name} case {case}: closest pair"
                );
                let both = (bvh.any(&pa, da, ta, fa), alone.1);
                assert_eq!(
                    bvh.any_pair_in::<false>(a, fa, b, fb),
                    both,
                    "{name} case {case}: shadow pair"
                );
                closest_hits += alone.0.is_some() as u32;
                blocked += alone.1 as u32;
            }
            assert!(
                closest_hits > 300 && blocked > 300 && blocked < 2700,
                "{name}: {closest_hits} hits, {blocked} blocked: the rays do not exercise the BVH"
            );
        }
    }
}
