//! Meshes of a few dozen triangles without a tree: every triangle tested, sixteen at a time.
//!
//! A 4-wide tree over the Cornell box's 32 triangles still costs a query a chain of dependent steps
//! (about two node tests, two packet tests, the sorting of children, a stack, and the branches
//! between them: about 900 instructions and 4 mispredicted branches per closest hit). With 16-lane
//! vectors the whole mesh is two or four packet tests with no branch between them. Testing every
//! packet with 4-lane vectors was slower than the tree (docs/benchmarks.md); with 16 lanes it is a
//! quarter of the work.
//!
//! The lanes run exactly the operations of the watertight test (`triangle.rs`), in the same order,
//! without fused multiply-adds, so every verdict, distance and barycentric is the scalar test's
//! bits, and the answer is the tree's (the smallest (t, triangle index) that the filter accepts).
//! A lane with an edge function exactly zero goes to the scalar test, as in `packet.rs`.
//!
//! The triangles are grouped into packets by place and size (`group.rs`), and each query tests
//! the packets' boxes first, four at once as a tree node's, skipping the packets whose box the ray
//! misses or enters beyond its closest hit so far: on the Cornell box the walls and the light fill
//! one packet and each block one more, so most rays test one packet instead of two.
//!
//! It needs AVX-512F (a packet is one register) or AVX2 (a packet is two registers, tested one
//! after the other): the build the tracer's one detection names (`crate::isa`, the wavefront's
//! too), asked when the mesh is built; without either, or for larger meshes, the tree is used. (AVX2 once tested both halves side by side, which spilled registers and
//! measured within a few percent of the tree; one half after the other keeps a half's values in
//! registers.)

// Elsewhere than x86-64 a `Flat` cannot exist (see `Backend` below): the test is compiled, unused.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_imports))]

mod group;

use super::node::Node4;
use super::packet::LaneHits;
use super::{build, BoxRay, Closest};
use crate::geometry::{RayPrecomp, TriangleHit};
use glam::{Vec3, Vec4};

/// Lanes of a wide packet.
const WIDE: usize = 16;

/// The largest mesh tested without a tree with AVX-512: four wide packets. Beyond about 60
/// triangles the tree's culling wins (a room with a sphere, `docs/benchmarks.md`).
pub(super) const MAX_TRIANGLES: usize = 64;

/// The largest with AVX2, whose packet test costs twice as much: two wide packets. (The Cornell
/// box's 32 triangles: 133 ns per closest-hit and shadow pair against the tree's 167; with a
/// 20-triangle sphere added, 229 against 145.)
pub(super) const MAX_TRIANGLES_AVX2: usize = 32;

/// Sixteen triangles in structure-of-arrays form: `v[vertex][axis][lane]`. Lane k holds triangle
/// `ids[k]`, in ascending order (so that the first of the lanes tied at the smallest distance has
/// the smallest index); unused lanes repeat the last triangle and are masked out by `valid`.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
struct WidePacket {
    v: [[[f32; WIDE]; 3]; 3],
    ids: [u32; WIDE],
    valid: u32,
}

impl WidePacket {
    fn triangle(&self, k: usize) -> [Vec3; 3] {
        let get = |vertex: usize| {
            let [x, y, z] = &self.v[vertex];
            Vec3::new(x[k], y[k], z[k])
        };
        [get(0), get(1), get(2)]
    }
}

/// Every triangle of a small mesh in wide packets (see the module documentation).
#[derive(Clone, Debug)]
pub(super) struct Flat {
    packets: Vec<WidePacket>,
    /// The packets' boxes, packet k in lane k.
    boxes: PacketBoxes,
    /// The instruction set the test runs in, the proof that the processor has it.
    backend: Backend,
}

impl Flat {
    /// The flat form of `triangles` (triangle k has index k), if the mesh is small enough and the
    /// processor has AVX-512F or AVX2; otherwise `None` (use the tree).
    pub fn new(triangles: &[[Vec3; 3]]) -> Option<Flat> {
        Flat::with_backend(triangles, Backend::detect()?)
    }

    /// [`Flat::new`] with the test in `backend`.
    fn with_backend(triangles: &[[Vec3; 3]], backend: Backend) -> Option<Flat> {
        if triangles.is_empty() || triangles.len() > backend.max_triangles() {
            return None;
        }
        let groups = group::groups(triangles, WIDE, backend.max_triangles() / WIDE);
        let packets = groups
            .iter()
            .map(|ids| {
                let lane = |k: usize| ids[k.min(ids.len() - 1)];
                let mut v = [[[0.0f32; WIDE]; 3]; 3];
                for (vertex, axes) in v.iter_mut().enumerate() {
                    for (axis, lanes) in axes.iter_mut().enumerate() {
                        for (k, x) in lanes.iter_mut().enumerate() {
                            *x = triangles[lane(k) as usize][vertex][axis];
                        }
                    }
                }
                WidePacket {
                    v,
                    ids: std::array::from_fn(lane),
                    valid: (1u32 << ids.len()) - 1,
                }
            })
            .collect();
        let boxes = PacketBoxes::new(triangles, &groups);
        Some(Flat {
            packets,
            boxes,
            backend,
        })
    }

    /// Bytes held (for memory reports).
    pub fn bytes(&self) -> usize {
        self.packets.len() * std::mem::size_of::<WidePacket>()
    }

    /// The closest hit in (0, t_max) that `accept` lets through, ties broken towards the smaller
    /// index: [`super::Bvh::closest`]'s answer.
    ///
    /// The test is a function compiled for its instruction set, called; with `INLINED` its body
    /// is inlined into the caller instead, which saves the call and its set-up (4 % of the
    /// Cornell box's time in the wavefront's steps) but is only fast where the caller is compiled
    /// for that instruction set too (the wavefront's builds, `integrator/wavefront/lanes/builds.rs`):
    /// anywhere else every lane operation would be a call. Either way the answer is the same.
    #[inline(always)]
    pub fn closest<const INLINED: bool>(
        &self,
        pre: &RayPrecomp,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        self.backend
            .closest::<INLINED>(self.mesh(), (pre, t_max), accept)
    }

    /// [`Flat::closest`] of ray `a` and [`Flat::any`] of ray `b`, packet by packet in one loop.
    #[inline(always)]
    pub fn closest_and_any<const INLINED: bool>(
        &self,
        a: Query<'_>,
        accept_a: &mut impl FnMut(u32, &TriangleHit) -> bool,
        b: Query<'_>,
        accept_b: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        self.backend
            .pair::<INLINED>(self.mesh(), a, accept_a, b, accept_b)
    }

    /// Whether some triangle that `accept` lets through is hit in (0, t_max) (`INLINED` as in
    /// [`Flat::closest`]).
    #[inline(always)]
    pub fn any<const INLINED: bool>(
        &self,
        pre: &RayPrecomp,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        self.backend
            .any::<INLINED>(self.mesh(), (pre, t_max), accept)
    }

    #[inline(always)]
    fn mesh(&self) -> Mesh<'_> {
        Mesh {
            packets: &self.packets,
            boxes: &self.boxes,
        }
    }
}

/// A ray of a query: its test constants and t_max.
pub(super) type Query<'a> = (&'a RayPrecomp, f32);

/// What the queries read of a [`Flat`].
#[derive(Clone, Copy)]
struct Mesh<'a> {
    packets: &'a [WidePacket],
    boxes: &'a PacketBoxes,
}

/// The boxes of up to four packets, as a tree node's children, padded as the tree's boxes are
/// (`build.rs`), so the slab test never skips a packet that holds a hit.
#[derive(Clone, Debug)]
struct PacketBoxes {
    node: Node4,
    /// More than one packet: the test can skip some. (With one, it is not made.)
    cull: bool,
}

impl PacketBoxes {
    fn new(triangles: &[[Vec3; 3]], groups: &[Vec<u32>]) -> PacketBoxes {
        let (lo, hi) = group::bounds(triangles);
        let pad = build::box_pad((hi - lo).max_element());
        let mut node = Node4::EMPTY;
        for (k, ids) in groups.iter().enumerate() {
            let (lo, hi) = group::bounds_of(triangles, ids);
            let (lo, hi) = build::padded(lo.into(), hi.into(), pad);
            for axis in 0..3 {
                node.bounds[0][axis][k] = lo[axis];
                node.bounds[1][axis][k] = hi[axis];
            }
            node.valid |= 1 << k;
        }
        PacketBoxes {
            node,
            cull: groups.len() > 1,
        }
    }

    /// Bit k: the ray may hit packet k within t_max; lane k of the second value: the distance at
    /// which it enters the packet's box (a hit in the packet is no nearer).
    #[inline(always)]
    fn test(&self, (pre, t_max): Query<'_>) -> (u32, [f32; 4]) {
        if !self.cull {
            return (self.node.valid, [0.0; 4]);
        }
        let (mask, near) = BoxRay::from_precomp(pre).test(&self.node, t_max);
        (mask, Vec4::to_array(&near))
    }
}

/// The hits of one wide packet.
type WideHits = LaneHits<WIDE>;

/// A query's answer in one `u128`: a closest hit (or none) and a shadow ray's verdict. It is what
/// the `#[target_feature]` functions return, because a `u128` comes back in two registers; as
/// `(Option<(u32, TriangleHit)>, bool)` (and as a struct of four 4-byte fields) the answer went
/// through memory, written in 4-byte pieces and read back in 8-byte loads across them, which the
/// processor cannot forward from its store buffer (a stall after every query: 16–19 % of the
/// code around the queries in `perf annotate` on a Zen 4).
///
/// Bits 0–30: the hit triangle's index, or [`Packed::NONE`]; bit 31: the shadow ray is blocked;
/// then the bits of t, b1 and b2, 32 each.
#[derive(Clone, Copy, Debug)]
struct Packed(u128);

impl Packed {
    /// No closest hit (a flat mesh has at most [`MAX_TRIANGLES`] triangles, far below it).
    const NONE: u32 = u32::MAX >> 1;
    const BLOCKED: u32 = 1 << 31;

    #[inline(always)]
    fn new(found: Option<(u32, TriangleHit)>, blocked: bool) -> Packed {
        let (id, h) = found.unwrap_or((
            Packed::NONE,
            TriangleHit {
                t: 0.0,
                b1: 0.0,
                b2: 0.0,
            },
        ));
        let word = id | if blocked { Packed::BLOCKED } else { 0 };
        Packed(
            u128::from(word)
                | u128::from(h.t.to_bits()) << 32
                | u128::from(h.b1.to_bits()) << 64
                | u128::from(h.b2.to_bits()) << 96,
        )
    }

    #[inline(always)]
    fn word(self, k: u32) -> u32 {
        (self.0 >> (32 * k)) as u32
    }

    #[inline(always)]
    fn found(self) -> Option<(u32, TriangleHit)> {
        let id = self.word(0) & !Packed::BLOCKED;
        (id != Packed::NONE).then(|| {
            let t = f32::from_bits(self.word(1));
            let (b1, b2) = (f32::from_bits(self.word(2)), f32::from_bits(self.word(3)));
            (id, TriangleHit { t, b1, b2 })
        })
    }

    #[inline(always)]
    fn blocked(self) -> bool {
        self.word(0) & Packed::BLOCKED != 0
    }
}

/// The lane operations of the test, for one instruction set (`x86::Avx512`, `x86::Avx2`). A
/// register holds `N` lanes, `N` dividing [`WIDE`]; a packet is tested `N` lanes at a time. Called
/// only inside a function compiled for that instruction set, so that each operation inlines to its
/// instruction.
trait Lanes: Copy {
    /// Lanes of one register.
    const N: usize;
    type F: Copy;
    fn splat(self, x: f32) -> Self::F;
    /// Lanes `at .. at + N` of `x`.
    fn load(self, x: &[f32; WIDE], at: usize) -> Self::F;
    /// Stores `x` in lanes `at .. at + N` of `out`.
    fn store(self, x: Self::F, out: &mut [f32; WIDE], at: usize);
    fn add(self, a: Self::F, b: Self::F) -> Self::F;
    fn sub(self, a: Self::F, b: Self::F) -> Self::F;
    fn mul(self, a: Self::F, b: Self::F) -> Self::F;
    fn div(self, a: Self::F, b: Self::F) -> Self::F;
    /// Bit k (below `N`): lane k of `a` is less than lane k of `b` (false for NaN, as `<`).
    fn lt(self, a: Self::F, b: Self::F) -> u32;
    /// Bit k (below `N`): lane k of `a` equals lane k of `b`.
    fn eq(self, a: Self::F, b: Self::F) -> u32;
    /// Bit k (below `N`): the sign bits of lane k of `a`, `b` and `c` are not all the same.
    fn signs_differ(self, a: Self::F, b: Self::F, c: Self::F) -> u32;
    /// `x` with its sign flipped in the lanes where `s`'s sign bit is set: x · sign(s), exactly.
    fn flip_sign_by(self, x: Self::F, s: Self::F) -> Self::F;
    /// The smallest of the lanes of `x` whose bits are set in `mask` (not 0; any of the `WIDE`).
    fn min_where(self, mask: u32, x: &[f32; WIDE]) -> f32;

    /// Bit k: lane k of `x` equals `value` (any of the `WIDE` lanes).
    #[inline(always)]
    fn lanes_equal(self, x: &[f32; WIDE], value: f32) -> u32 {
        let v = self.splat(value);
        let mut bits = 0;
        let mut at = 0;
        while at < WIDE {
            bits |= self.eq(self.load(x, at), v) << at;
            at += Self::N;
        }
        bits
    }
}

/// The ray's constants of the watertight test, splatted across the lanes. (Functions, not closures:
/// a closure is not inlined into the `#[target_feature]` function, and out of it every intrinsic
/// would be a call.)
struct Sheared<L: Lanes> {
    k: [usize; 3],
    o: [L::F; 3],
    s: [L::F; 3],
}

impl<L: Lanes> Sheared<L> {
    #[inline(always)]
    fn new(l: L, pre: &RayPrecomp) -> Self {
        let [kx, ky, kz] = pre.k;
        // Each component read where it lies, one 4-byte load each: the caller stores the origin
        // a component at a time, and a copy of it (`to_array`) read two of them in one 8-byte load,
        // which the processor cannot forward from two stores: a stall at the start of every
        // query (6 % of the closest-hit query in `perf annotate` on a Zen 4).
        let o: &[f32; 3] = pre.o.as_ref();
        let [sx, sy, sz] = pre.s;
        Sheared {
            k: pre.k,
            o: [l.splat(o[kx]), l.splat(o[ky]), l.splat(o[kz])],
            s: [l.splat(sx), l.splat(sy), l.splat(sz)],
        }
    }

    /// The sheared vertex in lanes `at .. at + N`, as `RayPrecomp::shear`: (dx − sx·dz,
    /// dy − sy·dz, sz·dz).
    #[inline(always)]
    fn shear(&self, l: L, v: &[[f32; WIDE]; 3], at: usize) -> (L::F, L::F, L::F) {
        let [kx, ky, kz] = self.k;
        let dx = l.sub(l.load(&v[kx], at), self.o[0]);
        let dy = l.sub(l.load(&v[ky], at), self.o[1]);
        let dz = l.sub(l.load(&v[kz], at), self.o[2]);
        (
            l.sub(dx, l.mul(self.s[0], dz)),
            l.sub(dy, l.mul(self.s[1], dz)),
            l.mul(self.s[2], dz),
        )
    }
}

/// Tests the ray against the sixteen triangles of `p`: [`intersect_watertight`] lane by lane,
/// into `hits` (one scratch space for a query's packets, not a value returned per packet, which
/// the compiler copied: 3 × 64 bytes per packet).
#[inline(always)]
fn test<L: Lanes>(l: L, pre: &RayPrecomp, p: &WidePacket, t_max: f32, hits: &mut WideHits) {
    let r = Sheared::new(l, pre);
    hits.mask = 0;
    let mut on_edge = 0;
    let mut at = 0;
    while at < WIDE {
        let (mask, edge) = test_lanes(l, &r, p, t_max, at, hits);
        hits.mask |= mask << at;
        on_edge |= edge << at;
        at += L::N;
    }
    hits.decide_edges(on_edge, pre, t_max, |k| p.triangle(k));
}

/// Lanes `at .. at + N` of [`test`]: stores their distances and barycentrics in `hits` and returns
/// (bit k for lane `at + k`) the lanes hit and the lanes whose edge function is exactly zero, left
/// to the scalar test.
#[inline(always)]
fn test_lanes<L: Lanes>(
    l: L,
    r: &Sheared<L>,
    p: &WidePacket,
    t_max: f32,
    at: usize,
    hits: &mut WideHits,
) -> (u32, u32) {
    let (ax, ay, az) = r.shear(l, &p.v[0], at);
    let (bx, by, bz) = r.shear(l, &p.v[1], at);
    let (cx, cy, cz) = r.shear(l, &p.v[2], at);
    let valid = p.valid >> at;
    let u = l.sub(l.mul(cx, by), l.mul(cy, bx));
    let v = l.sub(l.mul(ax, cy), l.mul(ay, cx));
    let w = l.sub(l.mul(bx, ay), l.mul(by, ax));
    let zero = l.splat(0.0);
    let on_edge = (l.eq(u, zero) | l.eq(v, zero) | l.eq(w, zero)) & valid;
    // The scalar test's verdicts with fewer compares (they were a fifth of a packet's
    // instructions), the same in every lane that is not `on_edge` (left to the scalar test):
    // outside, "some edge function negative and some positive", is "their signs differ" once
    // none is zero; and "0 < t_scaled < t_max·det for det > 0, the mirror image for det < 0" is
    // one range test with det's sign taken off both sides (a sign flip is exact). det = ±0 gives
    // a limit of ±0 (or NaN) and fails it, as it failed both; so does a NaN, in either form.
    let outside = l.signs_differ(u, v, w);
    let det = l.add(l.add(u, v), w);
    let t_scaled = l.add(l.add(l.mul(u, az), l.mul(v, bz)), l.mul(w, cz));
    let limit = l.mul(l.splat(t_max), det);
    let (t_unsigned, limit_unsigned) = (l.flip_sign_by(t_scaled, det), l.flip_sign_by(limit, det));
    let in_range = l.lt(zero, t_unsigned) & l.lt(t_unsigned, limit_unsigned);
    let mask = !outside & in_range & valid & !on_edge;
    // Undivided: `LaneHits::get` divides for the lanes a query reads.
    l.store(t_scaled, &mut hits.t_scaled, at);
    l.store(v, &mut hits.b1_scaled, at);
    l.store(w, &mut hits.b2_scaled, at);
    l.store(det, &mut hits.det, at);
    (mask, on_edge)
}

/// Every lane's distance, as [`LaneHits::get`] divides it out (the same operations), for the
/// packets with more than one hit.
#[inline(always)]
fn distances<L: Lanes>(l: L, hits: &WideHits) -> [f32; WIDE] {
    let mut t = [0.0; WIDE];
    let mut at = 0;
    while at < WIDE {
        let inv = l.div(l.splat(1.0), l.load(&hits.det, at));
        l.store(l.mul(l.load(&hits.t_scaled, at), inv), &mut t, at);
        at += L::N;
    }
    t
}

/// Whether packet `k` of a query's box test can still hold a closer hit than `best`'s.
#[inline(always)]
fn worth_testing(boxes: (u32, [f32; 4]), k: usize, best: &Closest) -> bool {
    boxes.0 >> k & 1 != 0 && boxes.1[k] <= best.t
}

#[inline(always)]
fn closest_with<L: Lanes>(
    l: L,
    mesh: Mesh<'_>,
    q: Query<'_>,
    accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
) -> Option<(u32, TriangleHit)> {
    let boxes = mesh.boxes.test(q);
    let mut best = Closest::new(q.1);
    let mut hits = WideHits::NONE;
    for (k, p) in mesh.packets.iter().enumerate() {
        if worth_testing(boxes, k, &best) {
            closest_in_packet(l, p, q.0, &mut best, accept, &mut hits);
        }
    }
    best.found()
}

/// Offers the hits of packet `p` to `best`.
#[inline(always)]
fn closest_in_packet<L: Lanes>(
    l: L,
    p: &WidePacket,
    pre: &RayPrecomp,
    best: &mut Closest,
    accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    hits: &mut WideHits,
) {
    // Ties with the best so far are let through so that the index can break them.
    test(l, pre, p, best.tie_limit(), hits);
    if hits.mask == 0 {
        return;
    }
    // The packet's smallest (t, index), found without a branch per lane: if it is no
    // improvement, no other lane is. A single hit (a wall seen from inside the room: the common
    // case) is its own smallest, without the reduction across the lanes and the compare back.
    let k = if hits.mask & (hits.mask - 1) == 0 {
        hits.mask.trailing_zeros() as usize
    } else {
        let t = distances(l, hits);
        let min = l.min_where(hits.mask, &t);
        (l.lanes_equal(&t, min) & hits.mask).trailing_zeros() as usize
    };
    let h = hits.get(k);
    let id = p.ids[k];
    if !best.improved_by(h.t, id) {
        return;
    }
    if accept(id, &h) {
        best.take(id, h);
        return;
    }
    // The filter rejected it (an alpha cutout): every other lane in turn.
    hits.offer(hits.mask & !(1 << k), |k| p.ids[k], best, accept);
}

/// A closest-hit query and a shadow query, packet by packet in one loop.
#[inline(always)]
fn pair_with<L: Lanes>(
    l: L,
    mesh: Mesh<'_>,
    a: Query<'_>,
    accept_a: &mut impl FnMut(u32, &TriangleHit) -> bool,
    b: Query<'_>,
    accept_b: &mut impl FnMut(u32, &TriangleHit) -> bool,
) -> (Option<(u32, TriangleHit)>, bool) {
    let (boxes_a, boxes_b) = (mesh.boxes.test(a), mesh.boxes.test(b));
    let mut best = Closest::new(a.1);
    let mut blocked = false;
    let (mut hits_a, mut hits_b) = (WideHits::NONE, WideHits::NONE);
    for (k, p) in mesh.packets.iter().enumerate() {
        if worth_testing(boxes_a, k, &best) {
            closest_in_packet(l, p, a.0, &mut best, accept_a, &mut hits_a);
        }
        if !blocked && boxes_b.0 >> k & 1 != 0 {
            test(l, b.0, p, b.1, &mut hits_b);
            blocked = hits_b.any_accepted(|k| p.ids[k], accept_b);
        }
    }
    (best.found(), blocked)
}

#[inline(always)]
fn any_with<L: Lanes>(
    l: L,
    mesh: Mesh<'_>,
    q: Query<'_>,
    accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
) -> bool {
    // A loop, not `Iterator::any` with a closure: a closure that is not inlined is compiled
    // without AVX-512F, and every lane operation in it becomes a call (seen when this was
    // inlined into a larger AVX-512F function: 3.5× slower).
    let boxes = mesh.boxes.test(q);
    let mut hits = WideHits::NONE;
    for (k, p) in mesh.packets.iter().enumerate() {
        if boxes.0 >> k & 1 == 0 {
            continue;
        }
        test(l, q.0, p, q.1, &mut hits);
        if hits.any_accepted(|k| p.ids[k], accept) {
            return true;
        }
    }
    false
}

#[cfg(target_arch = "x86_64")]
use x86::Backend;

/// Elsewhere there is no instruction set for the test: a type without values, so a `Flat` cannot
/// exist.
#[cfg(not(target_arch = "x86_64"))]
#[derive(Clone, Copy, Debug)]
enum Backend {}

#[cfg(not(target_arch = "x86_64"))]
impl Backend {
    fn detect() -> Option<Backend> {
        None
    }
    fn max_triangles(self) -> usize {
        match self {}
    }
    #[cfg(test)]
    fn detected() -> impl Iterator<Item = Backend> {
        std::iter::empty()
    }
    fn closest<const INLINED: bool>(
        self,
        _: Mesh<'_>,
        _: Query<'_>,
        _: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        match self {}
    }
    fn any<const INLINED: bool>(
        self,
        _: Mesh<'_>,
        _: Query<'_>,
        _: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        match self {}
    }
    fn pair<const INLINED: bool>(
        self,
        _: Mesh<'_>,
        _: Query<'_>,
        _: &mut impl FnMut(u32, &TriangleHit) -> bool,
        _: Query<'_>,
        _: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        match self {}
    }
}

#[cfg(target_arch = "x86_64")]
mod x86;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{intersect_watertight, Ray};

    /// The brute-force answer: the smallest (t, index) among the hits `accept` lets through.
    fn brute_force(
        tris: &[[Vec3; 3]],
        pre: &RayPrecomp,
        t_max: f32,
        accept: impl Fn(u32) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        let mut best: Option<(u32, TriangleHit)> = None;
        for (id, tri) in tris.iter().enumerate() {
            if let Some(h) = intersect_watertight(pre, tri, t_max) {
                if accept(id as u32) && best.is_none_or(|(_, b)| h.t < b.t) {
                    best = Some((id as u32, h));
                }
            }
        }
        best
    }

    /// On meshes of 1 to 64 triangles (32 with AVX2) — random ones with shared edges and exact
    /// duplicates (ties), and axis-aligned squares hit by axis-aligned rays (edge functions exactly
    /// zero, decided in double precision) — the wide test of every instruction set the processor
    /// has gives the brute-force scalar answer bit for bit: the same triangle, distance and
    /// barycentrics, with and without a filter, and the same visibility.
    // Elsewhere there is no flat test to check (`Flat::new` is always `None`).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn every_answer_is_the_scalar_tests_bit_for_bit() {
        let backends: Vec<Backend> = Backend::detected().collect();
        if backends.is_empty() {
            eprintln!(
                "SKIPPED: this processor has neither AVX-512F nor AVX2, so meshes use the tree"
            );
            return;
        }
        for backend in backends {
            answers_are_the_scalar_tests(backend);
        }
    }

    #[cfg(target_arch = "x86_64")]
    fn answers_are_the_scalar_tests(backend: Backend) {
        let mut rng = crate::testing::uniform_stream(0x51_7cc1_b727_220a);
        let (mut hits, mut ties, mut edges, mut rejected) = (0, 0, 0, 0);
        // Every mesh size up to the backend's limit, as many rays whatever the limit.
        let limit = backend.max_triangles();
        for case in 0..400 * MAX_TRIANGLES / limit {
            let n = case % limit + 1;
            let mut tris: Vec<[Vec3; 3]> = Vec::new();
            while tris.len() < n {
                let p = |rng: &mut dyn FnMut() -> f32| Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0;
                match tris.len() % 5 {
                    // A quad of two triangles in the plane z = k/4, sharing its diagonal.
                    0 if tris.len() + 2 <= n => {
                        let z = (tris.len() % 7) as f32 * 0.25 - 0.75;
                        let [a, b, c, d] = [(-1., -1.), (1., -1.), (1., 1.), (-1., 1.)]
                            .map(|(x, y)| Vec3::new(x, y, z));
                        tris.push([a, b, c]);
                        tris.push([a, c, d]);
                    }
                    // A duplicate of the previous triangle: a tie broken by index.
                    1 if !tris.is_empty() => tris.push(tris[tris.len() - 1]),
                    // A triangle sharing an edge with the previous one.
                    2 if !tris.is_empty() => {
                        let [a, b, _] = tris[tris.len() - 1];
                        tris.push([b, a, p(&mut rng)]);
                    }
                    // In every fourth mesh, triangles where det is zero or not finite: zero
                    // area (collinear, a repeated corner), in a plane x = k that the
                    // axis-aligned rays below run along, and with coordinates whose products
                    // overflow.
                    3 if case % 4 == 0 => {
                        let (a, b) = (p(&mut rng), p(&mut rng));
                        let x = (tris.len() % 3) as f32 * 0.5 - 0.5;
                        let big = Vec3::new(1e30, -1e30, 1e30);
                        tris.push(match (case / 4 + tris.len()) % 4 {
                            0 => [a, b, (a + b) * 0.5],
                            1 => [a, a, b],
                            2 => [a, b, p(&mut rng)].map(|v| Vec3::new(x, v.y, v.z)),
                            _ => [a * 1e30, b, big],
                        });
                    }
                    _ => tris.push([p(&mut rng), p(&mut rng), p(&mut rng)]),
                }
            }
            let flat = Flat::with_backend(&tris, backend).expect("a small mesh");
            for ray in 0..64 {
                let (o, d) = if ray % 4 == 0 {
                    // Axis-aligned rays through a grid of quarter points: exact edges and corners.
                    let q = (Vec3::new(rng(), rng(), 0.0) * 8.0 - 4.0).round() * 0.25;
                    (Vec3::new(q.x, q.y, 2.0), -Vec3::Z)
                } else {
                    let o = Vec3::new(rng(), rng(), rng()) * 6.0 - 3.0;
                    let tri = tris[ray % n];
                    let target = tri[0] * 0.4 + tri[1] * 0.35 + tri[2] * 0.25;
                    let jitter = Vec3::new(rng(), rng(), rng()) * 0.2 - 0.1;
                    (o, (target + jitter - o).normalize_or(Vec3::X))
                };
                let pre = RayPrecomp::new(&Ray::new(o, d));
                let t_max = if ray % 3 == 0 { 1.7 } else { f32::INFINITY };
                let want = brute_force(&tris, &pre, t_max, |_| true);
                let got = flat.closest::<false>(&pre, t_max, &mut |_, _| true);
                assert_eq!(got, want, "{backend:?}: case {case} ray {ray}");
                // Inlined into this function, which is not compiled for the instruction set: slow
                // (every lane operation a call), the same answers.
                if ray % 8 == 1 {
                    let inlined = flat.closest::<true>(&pre, t_max, &mut |_, _| true);
                    assert_eq!(inlined, want, "{backend:?} inlined: case {case} ray {ray}");
                    let visible = flat.any::<true>(&pre, t_max, &mut |_, _| true);
                    assert_eq!(visible, want.is_some());
                }
                assert_eq!(
                    flat.any::<false>(&pre, t_max, &mut |_, _| true),
                    want.is_some()
                );
                if let Some((id, h)) = want {
                    hits += 1;
                    let tied = tris.iter().enumerate().any(|(other, tri)| {
                        other as u32 != id
                            && intersect_watertight(&pre, tri, t_max).is_some_and(|o| o.t == h.t)
                    });
                    ties += u32::from(tied);
                    edges += u32::from(h.b1 == 0.0 || h.b2 == 0.0 || h.b1 + h.b2 == 1.0);
                    // A filter that rejects the nearest triangle (an alpha cutout) finds the next.
                    let next = flat.closest::<false>(&pre, t_max, &mut |other, _| other != id);
                    assert_eq!(next, brute_force(&tris, &pre, t_max, |other| other != id));
                    let behind = flat.any::<false>(&pre, t_max, &mut |other, _| other != id);
                    assert_eq!(behind, next.is_some());
                    rejected += u32::from(next.is_some());
                }
            }
        }
        assert!(
            hits > 10_000 && ties > 1_000 && edges > 200 && rejected > 3_000,
            "{backend:?}: {hits} hits, {ties} ties, {edges} on edges, {rejected} behind a \
             rejected one: the cases do not exercise the test"
        );
    }

    #[test]
    fn only_small_meshes_are_flat() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        assert!(Flat::new(&[]).is_none());
        assert!(Flat::new(&vec![tri; MAX_TRIANGLES + 1]).is_none());
        assert_eq!(
            Flat::new(&vec![tri; MAX_TRIANGLES_AVX2]).is_some(),
            Backend::detect().is_some()
        );
        for backend in Backend::detected() {
            let limit = backend.max_triangles();
            assert!(Flat::with_backend(&vec![tri; limit + 1], backend).is_none());
            let flat = Flat::with_backend(&vec![tri; limit], backend).expect("small enough");
            assert_eq!(flat.packets.len(), limit / WIDE);
        }
    }
}
