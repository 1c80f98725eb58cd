//! The acceleration structure: a 4-wide BVH whose nodes test their four children's boxes in one
//! SIMD slab test and whose leaves test four triangles at once (`packet.rs`), built top down by
//! binned SAH (`build.rs`, `binned.rs`).
//!
//! Contract: [`Bvh::closest`] reports the hit with the smallest (t, triangle index) among all
//! triangles hit in (0, t_max) that the filter accepts — ties broken by index, so the answer never
//! depends on traversal order; [`Bvh::any`] reports whether such a hit exists. The box tests are
//! conservative (padded boxes, a widened far distance), so they never cull a triangle that the
//! watertight test would hit.

mod binned;
mod build;
mod bundle;
mod flat;
mod node;
mod packet;
mod pair;
mod stack;
mod top;
mod walk;

pub use bundle::BUNDLE;
pub use pair::RayQuery;
pub(crate) use top::{BoxTree, MAX_BOXES};

use super::{box_reciprocal, Mesh, RayPrecomp, TriangleHit};
use flat::Flat;
use glam::{Vec3, Vec4};
use node::{Node4, NodeRef, TriPacket};
use packet::{intersect_packet, PacketHits, PacketRay};
use walk::{AnyWalk, ClosestWalk};

/// Entries of the traversal stack kept on the machine stack (`stack.rs`). A million-triangle tree
/// needs about three entries per level of its ~12; a deeper traversal continues in a recursive
/// call rather than failing.
const STACK: usize = 32;

/// The slab test widens the far distance by this factor (Ize, "Robust BVH Ray Traversal", 2013:
/// 1 + 2γ₃ covers the rounding of the subtraction and the product).
const FAR_WIDEN: f32 = 1.0 + 4.0 * f32::EPSILON;

/// A BVH over a [`Mesh`], whose leaves name the mesh's triangles by their index in it.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node4>,
    packets: Vec<TriPacket>,
    root: Option<NodeRef>,
    depth: usize,
    /// For a mesh of at most `flat::MAX_TRIANGLES` triangles on a processor with AVX-512F (32
    /// with AVX2): every triangle in 16-lane packets, tested without the tree (`flat.rs`).
    flat: Option<Flat>,
}

/// The per-ray constants of the box tests.
struct BoxRay {
    o: [Vec4; 3],
    inv_d: [Vec4; 3],
    /// Per axis, whether the ray enters the box by its upper bound (a negative direction). A
    /// `bool`, so that indexing the two sides with it needs no bounds check.
    near_upper: [bool; 3],
}

impl BoxRay {
    #[inline(always)]
    fn new(o: Vec3, d: Vec3) -> BoxRay {
        let inv_d = box_reciprocal(d);
        BoxRay {
            o: [Vec4::splat(o.x), Vec4::splat(o.y), Vec4::splat(o.z)],
            inv_d: inv_d.map(Vec4::splat),
            near_upper: inv_d.map(|i| i < 0.0),
        }
    }

    /// [`BoxRay::new`] from the ray's precomputed reciprocal direction (the same values), every
    /// component read where it was stored, one at a time (see `flat::Sheared::new`).
    #[inline(always)]
    fn from_precomp(pre: &RayPrecomp) -> BoxRay {
        let o: &[f32; 3] = pre.o.as_ref();
        let inv_d = pre.inv_d;
        BoxRay {
            o: [Vec4::splat(o[0]), Vec4::splat(o[1]), Vec4::splat(o[2])],
            inv_d: inv_d.map(Vec4::splat),
            near_upper: inv_d.map(|i| i < 0.0),
        }
    }

    /// Lane k: whether the ray meets child k's box within [0, t_max], and where it enters it.
    #[inline(always)]
    fn test(&self, n: &Node4, t_max: f32) -> (u32, Vec4) {
        let slab = |axis: usize, upper: bool| {
            (n.bounds[usize::from(upper)][axis] - self.o[axis]) * self.inv_d[axis]
        };
        let [ux, uy, uz] = self.near_upper;
        let near = slab(0, ux)
            .max(slab(1, uy))
            .max(slab(2, uz).max(Vec4::ZERO));
        let far = slab(0, !ux)
            .min(slab(1, !uy))
            .min(slab(2, !uz).min(Vec4::splat(t_max)))
            * FAR_WIDEN;
        (near.cmple(far).bitmask() & n.valid, near)
    }
}

impl Bvh {
    /// Builds the BVH over `mesh`. The mesh keeps its order: each packet lane names its triangle
    /// (moving every attribute to the tree's order cost a fifth of the build at ten million
    /// triangles, with no render faster for it: docs/benchmarks.md).
    pub fn build(mesh: &Mesh) -> Bvh {
        if mesh.is_empty() {
            return Bvh::default();
        }
        let built = build::build(mesh);
        let flat = if mesh.len() <= flat::MAX_TRIANGLES {
            Flat::new(&mesh.positions)
        } else {
            None
        };
        Bvh {
            nodes: built.nodes,
            packets: built.packets,
            root: Some(built.root),
            depth: built.depth,
            flat,
        }
    }

    /// This BVH with its queries answered by the tree even where the mesh is small enough for the
    /// flat test: the same answers, for tests and benchmarks that compare the two.
    pub fn tree_only(mut self) -> Bvh {
        self.flat = None;
        self
    }

    /// Whether queries skip the tree and test every triangle (`flat.rs`).
    pub fn is_flat(&self) -> bool {
        self.flat.is_some()
    }

    /// Number of BVH nodes (for memory reports).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Depth of the 4-wide tree (the root is depth 1).
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Boxes that together hold every triangle: the children of the tree's inner nodes, opened
    /// breadth-first from the root while the count stays at most `max` (at least 4). `None` for an
    /// empty tree or one that is a single leaf. A placed mesh's world box is the union of these
    /// boxes moved, tighter than its one box moved when the placement rotates it.
    pub fn cover(&self, max: usize) -> Option<Vec<(Vec3, Vec3)>> {
        let root = self.root?;
        if root.is_leaf() {
            return None;
        }
        let children = |r: NodeRef| {
            let n = &self.nodes[r.index()];
            (0..4)
                .filter(move |&k| n.valid & (1 << k) != 0)
                .map(move |k| {
                    let corner = |side: usize| {
                        Vec3::new(
                            n.bounds[side][0][k],
                            n.bounds[side][1][k],
                            n.bounds[side][2][k],
                        )
                    };
                    (corner(0), corner(1), n.child[k])
                })
        };
        let mut open: std::collections::VecDeque<_> = children(root).collect();
        let mut cover = Vec::new();
        while let Some((lo, hi, r)) = open.pop_front() {
            let count = open.len() + cover.len();
            if !r.is_leaf() && count + self.nodes[r.index()].valid.count_ones() as usize <= max {
                open.extend(children(r));
            } else {
                cover.push((lo, hi));
            }
        }
        Some(cover)
    }

    /// Approximate memory in bytes.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node4>()
            + self.packets.len() * std::mem::size_of::<TriPacket>()
            + self.flat.as_ref().map_or(0, Flat::bytes)
    }

    /// The closest hit in (0, t_max) among the triangles `accept(index, hit)` lets through (it
    /// decides alpha cutouts), with ties in t broken towards the smaller triangle index.
    /// Inlined, like [`Bvh::any`], into the scene's ray queries: +1.5 % samples/s (A/B).
    #[inline(always)]
    pub fn closest(
        &self,
        pre: &RayPrecomp,
        d: Vec3,
        t_max: f32,
        accept: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        self.closest_in::<false>(pre, d, t_max, accept)
    }

    /// [`Bvh::closest`], with a flat mesh's test inlined into the caller where `INLINED` (only
    /// for callers compiled for the test's instruction set: see `flat::Flat::closest`).
    #[inline(always)]
    pub fn closest_in<const INLINED: bool>(
        &self,
        pre: &RayPrecomp,
        d: Vec3,
        t_max: f32,
        mut accept: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        if let Some(flat) = &self.flat {
            return flat.closest::<INLINED>(pre, t_max, &mut accept);
        }
        let root = self.root?;
        let ray = PacketRay::new(pre);
        let boxes = BoxRay::new(pre.o, d);
        let mut best = Closest::new(t_max);
        self.closest_from(root, &ray, &boxes, &mut best, &mut accept);
        best.found()
    }

    /// The closest-hit traversal from `root`, one walk run to its end (`walk.rs`).
    #[inline(always)]
    fn closest_from(
        &self,
        root: NodeRef,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        best: &mut Closest,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        let mut walk = ClosestWalk::new(root);
        while walk.live {
            self.closest_step(&mut walk, ray, boxes, best, accept);
        }
    }

    /// The closest-hit traversal of a subtree deeper than the fixed stack: plain recursion,
    /// no fixed stack (such trees are rare; see `trees_deeper_than_the_stack_are_traversed`). Kept
    /// apart from [`Bvh::closest_from`] so that the fast traversal is not recursive and can be
    /// inlined into the ray queries.
    #[inline(never)]
    fn closest_recursive(
        &self,
        node: NodeRef,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        best: &mut Closest,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        if node.is_leaf() {
            self.closest_in_leaf(node, ray, best, accept);
            return;
        }
        let n = &self.nodes[node.index()];
        let (mask, near) = boxes.test(n, best.t);
        let by_far = sort_far_to_near(mask, near, n);
        // Nearest first, so that farther subtrees are culled by the hits found.
        for &key in by_far[..LANES_SET[mask as usize]].iter().rev() {
            if key_near(key) <= best.t {
                self.closest_recursive(key_child(key), ray, boxes, best, accept);
            }
        }
    }

    /// The shadow-ray traversal of a subtree deeper than the fixed stack (see
    /// [`Bvh::closest_recursive`]).
    #[inline(never)]
    fn any_recursive(
        &self,
        node: NodeRef,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        if node.is_leaf() {
            return self.any_in_leaf(node, ray, t_max, accept);
        }
        let n = &self.nodes[node.index()];
        let (mask, _) = boxes.test(n, t_max);
        let mut m = mask;
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            if self.any_recursive(n.child[k], ray, boxes, t_max, accept) {
                return true;
            }
        }
        false
    }

    /// Tests the packets of leaf `node`, updating `best` with every closer (or tying, smaller
    /// index) hit that `accept` lets through.
    #[inline(always)]
    fn closest_in_leaf(
        &self,
        node: NodeRef,
        ray: &PacketRay<'_>,
        best: &mut Closest,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        let mut hits = PacketHits::NONE;
        for p in &self.packets[node.packets()] {
            // Accept ties (t equal to the best so far) so they can be broken by index.
            intersect_packet(ray, p, best.tie_limit(), &mut hits);
            hits.offer(hits.mask, |k| p.ids[k], best, accept);
        }
    }

    /// True if a packet of leaf `node` has a hit in (0, t_max) that `accept` lets through.
    #[inline(always)]
    fn any_in_leaf(
        &self,
        node: NodeRef,
        ray: &PacketRay<'_>,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        let mut hits = PacketHits::NONE;
        for p in &self.packets[node.packets()] {
            intersect_packet(ray, p, t_max, &mut hits);
            if hits.any_accepted(|k| p.ids[k], accept) {
                return true;
            }
        }
        false
    }

    /// True if some triangle that `accept(index, hit)` lets through is hit in (0, t_max).
    #[inline(always)]
    pub fn any(
        &self,
        pre: &RayPrecomp,
        d: Vec3,
        t_max: f32,
        accept: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        self.any_in::<false>(pre, d, t_max, accept)
    }

    /// [`Bvh::any`], `INLINED` as in [`Bvh::closest_in`].
    #[inline(always)]
    pub fn any_in<const INLINED: bool>(
        &self,
        pre: &RayPrecomp,
        d: Vec3,
        t_max: f32,
        mut accept: impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        if let Some(flat) = &self.flat {
            return flat.any::<INLINED>(pre, t_max, &mut accept);
        }
        let Some(root) = self.root else { return false };
        let ray = PacketRay::new(pre);
        let boxes = BoxRay::new(pre.o, d);
        self.any_from(root, &ray, &boxes, t_max, &mut accept)
    }

    /// The shadow-ray traversal from `root`, one walk run to its end (`walk.rs`).
    #[inline(always)]
    fn any_from(
        &self,
        root: NodeRef,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        let mut walk = AnyWalk::new(root);
        while walk.live {
            self.any_step(&mut walk, ray, boxes, t_max, accept);
        }
        walk.hit
    }
}

/// Number of set bits of a 4-bit mask (baseline x86-64 has no `popcnt` instruction).
const LANES_SET: [usize; 16] = [0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4];

/// The children of `n` whose lanes are set in `mask`, ordered by entry distance from farthest to
/// nearest, followed by the others. Which child is nearer is a coin flip the branch predictor
/// loses, so this is a sorting network of integer `max`/`min` (conditional moves, no branches) on
/// keys that pack the entry distance above the child reference: a distance is ≥ 0 (the slab test
/// clamps it), and the bit patterns of non-negative floats are ordered as the floats are. A hit
/// lane's key is its distance's bits + 1, a missed lane's 0, so misses sort last.
#[inline(always)]
fn sort_far_to_near(mask: u32, near: Vec4, n: &Node4) -> [u64; 4] {
    let near = near.to_array();
    let key = |k: usize| {
        let hit = 0u64.wrapping_sub(u64::from(mask >> k & 1));
        ((u64::from(near[k].to_bits()) + 1) << 32 | u64::from(n.child[k].0)) & hit
    };
    sort4_descending([key(0), key(1), key(2), key(3)])
}

/// Four keys, largest first: a sorting network of integer `max`/`min` (conditional moves, no
/// branches), for the walks' child orders (`sort_far_to_near`, and the bundle's).
#[inline(always)]
fn sort4_descending(mut e: [u64; 4]) -> [u64; 4] {
    let mut exchange = |i: usize, j: usize| {
        let (a, b) = (e[i], e[j]);
        e[i] = a.max(b);
        e[j] = a.min(b);
    };
    exchange(0, 1);
    exchange(2, 3);
    exchange(0, 2);
    exchange(1, 3);
    exchange(1, 2);
    e
}

/// The child reference of a sorted key.
#[inline(always)]
fn key_child(key: u64) -> NodeRef {
    NodeRef(key as u32)
}

/// The entry distance of a sorted key (only meaningful for a hit lane's key).
#[inline(always)]
fn key_near(key: u64) -> f32 {
    f32::from_bits(((key >> 32) as u32).wrapping_sub(1))
}

struct Closest {
    /// The best distance so far (t_max until a hit is found).
    t: f32,
    id: u32,
    hit: TriangleHit,
    /// The query's t_max.
    t_max: f32,
}

impl Closest {
    /// Nothing found yet, in (0, t_max).
    #[inline(always)]
    fn new(t_max: f32) -> Closest {
        Closest {
            t: t_max,
            id: u32::MAX,
            hit: TriangleHit {
                t: t_max,
                b1: 0.0,
                b2: 0.0,
            },
            t_max,
        }
    }

    /// Triangle `id`'s hit `hit` is the best so far.
    #[inline(always)]
    fn take(&mut self, id: u32, hit: TriangleHit) {
        (self.t, self.id, self.hit) = (hit.t, id, hit);
    }

    /// The closest hit, if one was found: triangle and hit.
    #[inline(always)]
    fn found(&self) -> Option<(u32, TriangleHit)> {
        (self.id != u32::MAX).then_some((self.id, self.hit))
    }

    /// The distance limit for a leaf test: ties with the best hit so far are let through, so
    /// that they can be broken by index. The limit is a little above the best distance: the test
    /// compares its scaled distance with the scaled limit (t·det against t_max·det), whose
    /// rounding can reject a triangle whose distance, once divided out, equals the best exactly
    /// (a duplicate of the best triangle with a smaller index, met after it: seen once packets
    /// were no longer visited in index order). Hits beyond the best are then turned away by
    /// [`Closest::improved_by`]; the limit never exceeds the query's t_max, so no hit beyond
    /// it is let in.
    #[inline(always)]
    fn tie_limit(&self) -> f32 {
        if self.id == u32::MAX {
            self.t
        } else {
            (self.t * (1.0 + 32.0 * f32::EPSILON)).min(self.t_max)
        }
    }

    /// Whether a hit of triangle `id` at `t` is closer than the best so far, or ties with it
    /// and has the smaller index.
    #[inline(always)]
    fn improved_by(&self, t: f32, id: u32) -> bool {
        t < self.t || (t == self.t && id < self.id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{intersect_watertight, Ray};

    #[test]
    fn tiny_meshes_are_hit() {
        for n in 1..=17 {
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
            let built = Bvh::build(&mesh);
            // Both ways of answering: the flat test where the processor has it, and the tree.
            for bvh in [built.clone(), built.tree_only()] {
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
                    let (id, hit) = bvh
                        .closest(&pre, d, f32::INFINITY, |_, _| true)
                        .unwrap_or_else(|| panic!("{n} triangles: missed {d}"));
                    assert!((hit.t - t).abs() < 1e-4, "{n} triangles, {d}: {}", hit.t);
                    let direct = intersect_watertight(&pre, &mesh.positions[id as usize], 10.0);
                    assert_eq!(direct, Some(hit), "the reported hit is triangle {id}'s");
                    assert!(bvh.any(&pre, d, 10.0, |_, _| true));
                    assert!(
                        !bvh.any(&pre, d, t * 0.99, |_, _| true),
                        "{n}: hit before t"
                    );
                    assert!(
                        !bvh.any(&pre, d, 10.0, |_, _| false),
                        "the filter is obeyed"
                    );
                }
            }
        }
    }

    /// A tree deeper than the fixed traversal stack (triangles at geometrically growing distances
    /// make a chain-like tree): the recursive fallbacks of both traversals give the brute-force
    /// answers.
    #[test]
    fn trees_deeper_than_the_stack_are_traversed() {
        let mut mesh = Mesh::default();
        for k in 0..160 {
            let x = 1.25f32.powi(k);
            for (dy, dz) in [(0.0, 0.0), (0.5, 0.3), (-0.4, 0.7)] {
                let c = Vec3::new(x, dy, dz);
                let s = x * 0.05;
                mesh.positions.push([
                    c + Vec3::new(0.0, -s, -s),
                    c + Vec3::new(0.0, s, -s),
                    c + Vec3::new(0.0, 0.0, s),
                ]);
                mesh.material.push(0);
            }
        }
        let bvh = Bvh::build(&mesh);
        assert!(
            bvh.depth() * 3 > STACK,
            "depth {}: not deeper than the stack",
            bvh.depth()
        );
        let mut checked = 0;
        for k in 0..160 {
            for (dy, dz) in [(0.0, 0.0), (0.5, 0.3), (-0.4, 0.7), (0.2, 0.1)] {
                let target = Vec3::new(1.25f32.powi(k), dy, dz);
                for o in [Vec3::new(-1.0, 0.01, 0.02), Vec3::new(1e16, 0.3, -0.2)] {
                    let d = (target - o).normalize();
                    let pre = RayPrecomp::new(&Ray::new(o, d));
                    let mut want: Option<(u32, TriangleHit)> = None;
                    for (id, tri) in mesh.positions.iter().enumerate() {
                        if let Some(h) = intersect_watertight(&pre, tri, f32::INFINITY) {
                            if want.is_none_or(|(_, b)| h.t < b.t) {
                                want = Some((id as u32, h));
                            }
                        }
                    }
                    assert_eq!(bvh.closest(&pre, d, f32::INFINITY, |_, _| true), want);
                    assert_eq!(bvh.any(&pre, d, f32::INFINITY, |_, _| true), want.is_some());
                    checked += want.is_some() as u32;
                }
            }
        }
        assert!(
            checked > 300,
            "{checked} rays hit: the test does not exercise the tree"
        );
    }

    /// Against brute force over every triangle, on a random soup with shared vertices and ties:
    /// the same (t, index) for every ray, and the same visibility.
    #[test]
    fn matches_brute_force_on_a_random_soup() {
        let mut rng = crate::testing::uniform_stream(0x2545_f491_4f6c_dd1du64);
        // Small triangles around shared vertices, plus exact duplicates (ties).
        let mesh = crate::testing::shared_corner_soup(&mut rng, 600, 3000, 50);
        let bvh = Bvh::build(&mesh);
        assert!(bvh.depth() >= 3, "depth {}", bvh.depth());
        let mut hits = 0;
        for _ in 0..4000 {
            let o = Vec3::new(rng(), rng(), rng()) * 12.0 - 6.0;
            let d = (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize_or(Vec3::Y);
            let pre = RayPrecomp::new(&Ray::new(o, d));
            let t_max = if rng() < 0.5 { 3.0 } else { f32::INFINITY };
            let mut want: Option<(u32, TriangleHit)> = None;
            for (id, tri) in mesh.positions.iter().enumerate() {
                if let Some(h) = intersect_watertight(&pre, tri, t_max) {
                    if want.is_none_or(|(_, b)| h.t < b.t) {
                        want = Some((id as u32, h));
                    }
                }
            }
            let got = bvh.closest(&pre, d, t_max, |_, _| true);
            assert_eq!(got, want, "ray {o} {d}");
            assert_eq!(bvh.any(&pre, d, t_max, |_, _| true), want.is_some());
            hits += want.is_some() as u32;
            // A filter that rejects the nearest triangle finds the next one.
            if let Some((first, _)) = want {
                let next = bvh.closest(&pre, d, t_max, |id, _| id != first);
                let mut brute: Option<(u32, TriangleHit)> = None;
                for (id, tri) in mesh.positions.iter().enumerate() {
                    if id as u32 == first {
                        continue;
                    }
                    if let Some(h) = intersect_watertight(&pre, tri, t_max) {
                        if brute.is_none_or(|(_, b)| h.t < b.t) {
                            brute = Some((id as u32, h));
                        }
                    }
                }
                assert_eq!(next, brute);
            }
        }
        assert!(hits > 500, "{hits}: the rays do not exercise the BVH");
    }
}
