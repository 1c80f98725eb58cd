//! A bundle of rays traced through the tree together: the camera rays of a few samples of one
//! pixel (or of neighbours) enter the same boxes, so one walk serves them all, and each box is
//! tested against every ray of the bundle in one vector loop (16 rays per AVX-512 instruction)
//! instead of once per ray with four children per instruction.
//!
//! Each ray's answer is its own [`Bvh::closest`]: a ray goes down a child where its own slab test
//! (the same arithmetic as [`BoxRay::test`]'s, its near plane picked by `min` instead of by the
//! direction's sign: the same value, since the two planes' distances are ordered as the planes
//! are) lets it, and a leaf tests its packets against each of its rays with that ray's own packet
//! test. By the BVH's contract the closest hit does not depend on which nodes were visited as
//! long as no node holding a closer hit was skipped, so the bundle's answers are the single
//! rays' bits. The walk costs what the union of the rays' walks costs; rays that part ways (an
//! edge, a silhouette) make it wider, which is why only rays that start together are bundled.

use super::node::TriPacket;
use super::packet::PacketRay;
use super::stack::Stack;
use super::{sort4_descending, BoxRay, Bvh, Closest, NodeRef, FAR_WIDEN};
use crate::geometry::{intersect_watertight, RayPrecomp, TriangleHit};

/// The most rays in one bundle (the lanes of one AVX-512 register).
pub const BUNDLE: usize = 16;

/// Entries of the bundle's walk stack: up to four children per inner node on a path down a tree
/// of about twenty levels; a deeper walk goes on ray by ray (`Bvh::closest_recursive`).
const STACK: usize = 64;

/// A leaf is tested triangle by triangle against all its rays at once where at least this many
/// of the bundle's rays reach it, and ray by ray (four triangles at a time) where fewer do: the
/// vector test of one triangle costs about what the packet test of four costs for one ray.
const RAYS_FOR_VECTOR_LEAF: u32 = 4;

/// The rays' origins and reciprocal directions by axis, one array per axis, for the box tests.
struct BundleBoxes {
    o: [[f32; BUNDLE]; 3],
    inv_d: [[f32; BUNDLE]; 3],
}

/// The rays' constants of the watertight test ([`RayPrecomp`]'s), one array per component: the
/// axes (kx, ky, kz), the origin's permuted coordinates and the shear.
struct BundleShear {
    k: [[u8; BUNDLE]; 3],
    o: [[f32; BUNDLE]; 3],
    s: [[f32; BUNDLE]; 3],
}

impl BundleShear {
    fn new(ray: impl Fn(usize) -> RayPrecomp) -> BundleShear {
        let mut b = BundleShear {
            k: [[0; BUNDLE]; 3],
            o: [[0.0; BUNDLE]; 3],
            s: [[0.0; BUNDLE]; 3],
        };
        for r in 0..BUNDLE {
            let pre = ray(r);
            let o = pre.o.to_array();
            for a in 0..3 {
                b.k[a][r] = pre.k[a] as u8;
                b.o[a][r] = o[pre.k[a]];
                b.s[a][r] = pre.s[a];
            }
        }
        b
    }

    /// The watertight test of triangle `v` against every ray, ray r within (0, t_max[r]): each
    /// lane performs [`intersect_packet`](super::packet::intersect_packet)'s operations (which are
    /// [`intersect_watertight`]'s) in the same order, so its verdict and numbers are the same
    /// bits. Lanes with an edge function exactly zero are reported in `on_edge`, for the scalar
    /// test to decide.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // one lane index over eleven arrays
    fn test(&self, v: &[glam::Vec3; 3], t_max: &[f32; BUNDLE]) -> RayHits {
        let [va, vb, vc] = v.map(|p| p.to_array());
        let mut out = RayHits {
            hit: [0; BUNDLE],
            on_edge: [0; BUNDLE],
            t_scaled: [0.0; BUNDLE],
            b1_scaled: [0.0; BUNDLE],
            b2_scaled: [0.0; BUNDLE],
            det: [0.0; BUNDLE],
        };
        for r in 0..BUNDLE {
            let pick = |p: &[f32; 3], k: u8| match k {
                0 => p[0],
                1 => p[1],
                _ => p[2],
            };
            let shear = |p: &[f32; 3]| {
                let dx = pick(p, self.k[0][r]) - self.o[0][r];
                let dy = pick(p, self.k[1][r]) - self.o[1][r];
                let dz = pick(p, self.k[2][r]) - self.o[2][r];
                (
                    dx - self.s[0][r] * dz,
                    dy - self.s[1][r] * dz,
                    self.s[2][r] * dz,
                )
            };
            let (ax, ay, az) = shear(&va);
            let (bx, by, bz) = shear(&vb);
            let (cx, cy, cz) = shear(&vc);
            let u = cx * by - cy * bx;
            let v = ax * cy - ay * cx;
            let w = bx * ay - by * ax;
            let on_edge = u == 0.0 || v == 0.0 || w == 0.0;
            let outside = (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0);
            let det = u + v + w;
            let t_scaled = u * az + v * bz + w * cz;
            let limit = t_max[r] * det;
            let in_range_pos = det > 0.0 && t_scaled > 0.0 && t_scaled < limit;
            let in_range_neg = det < 0.0 && t_scaled < 0.0 && t_scaled > limit;
            let hit = !outside && (in_range_pos || in_range_neg) && !on_edge;
            out.hit[r] = u32::from(hit) << r;
            out.on_edge[r] = u32::from(on_edge) << r;
            (out.t_scaled[r], out.b1_scaled[r], out.b2_scaled[r]) = (t_scaled, v, w);
            out.det[r] = det;
        }
        out
    }
}

/// One triangle's test against the rays of a bundle (lane r = ray r), its numbers not yet divided
/// by the determinant (as `LaneHits` keeps them).
struct RayHits {
    /// `1 << r` where ray r hits (and no edge function is zero), else 0 (ORed into a mask by
    /// [`RayHits::mask`]).
    hit: [u32; BUNDLE],
    /// `1 << r` where an edge function of ray r is exactly zero, else 0.
    on_edge: [u32; BUNDLE],
    t_scaled: [f32; BUNDLE],
    b1_scaled: [f32; BUNDLE],
    b2_scaled: [f32; BUNDLE],
    det: [f32; BUNDLE],
}

impl RayHits {
    #[inline(always)]
    fn mask(bits: &[u32; BUNDLE]) -> u32 {
        bits.iter().fold(0, |m, b| m | b)
    }

    /// Ray r's distance and barycentrics, as `LaneHits::get` divides them out.
    #[inline(always)]
    fn get(&self, r: usize) -> TriangleHit {
        let inv = 1.0 / self.det[r];
        TriangleHit {
            t: self.t_scaled[r] * inv,
            b1: self.b1_scaled[r] * inv,
            b2: self.b2_scaled[r] * inv,
        }
    }
}

impl Bvh {
    /// The closest hit of each ray of `pres` (at most [`BUNDLE`]) in (0, t_max) that
    /// `accept(ray, triangle, hit)` lets through, written to `out[ray]`: each ray's
    /// [`Bvh::closest`], the same bits. `INLINED` as in [`Bvh::closest_in`].
    #[inline(always)]
    pub fn closest_bundle_in<const INLINED: bool>(
        &self,
        pres: &[RayPrecomp],
        t_max: f32,
        accept: impl FnMut(usize, u32, &TriangleHit) -> bool,
        out: &mut [Option<(u32, TriangleHit)>],
    ) {
        self.closest_bundle_with::<INLINED, STACK>(pres, t_max, accept, out);
    }

    /// [`Bvh::closest_bundle_in`] with a walk stack of `S` entries (tests give it a small one, so
    /// that the ray-by-ray fallback of a full stack runs).
    #[inline(always)]
    fn closest_bundle_with<const INLINED: bool, const S: usize>(
        &self,
        pres: &[RayPrecomp],
        t_max: f32,
        mut accept: impl FnMut(usize, u32, &TriangleHit) -> bool,
        out: &mut [Option<(u32, TriangleHit)>],
    ) {
        let n = pres.len();
        assert!(n <= BUNDLE && out.len() >= n, "a bundle of {n} rays");
        if let Some(flat) = &self.flat {
            for (r, pre) in pres.iter().enumerate() {
                out[r] = flat.closest::<INLINED>(pre, t_max, &mut |id, h| accept(r, id, h));
            }
            return;
        }
        let Some(root) = self.root else {
            out[..n].fill(None);
            return;
        };
        if n == 0 {
            return;
        }
        // Lanes beyond `n` repeat the last ray and are never in a walk's mask.
        let ray = |r: usize| &pres[r.min(n - 1)];
        let packets: [PacketRay<'_>; BUNDLE] = std::array::from_fn(|r| PacketRay::new(ray(r)));
        let boxes = BundleBoxes {
            o: std::array::from_fn(|a| std::array::from_fn(|r| ray(r).o.to_array()[a])),
            inv_d: std::array::from_fn(|a| std::array::from_fn(|r| ray(r).inv_d[a])),
        };
        let mut best: [Closest; BUNDLE] = std::array::from_fn(|_| Closest::new(t_max));
        let mut best_t = [t_max; BUNDLE];
        let shear = BundleShear::new(|r| *ray(r));
        let all = (1u32 << n) - 1;
        let mut stack: Stack<u64, S> = Stack::new();
        let mut entry = Some((root, all));
        while let Some((node, mask)) = entry {
            if node.is_leaf() && mask.count_ones() >= RAYS_FOR_VECTOR_LEAF {
                for p in &self.packets[node.packets()] {
                    self.closest_in_packet(p, mask, &shear, pres, &mut best, &mut accept);
                }
                for (t, b) in best_t.iter_mut().zip(&best) {
                    *t = b.t;
                }
            } else if node.is_leaf() {
                let mut m = mask;
                while m != 0 {
                    let r = m.trailing_zeros() as usize;
                    m &= m - 1;
                    let mut accept_r = |id: u32, h: &TriangleHit| accept(r, id, h);
                    self.closest_in_leaf(node, &packets[r], &mut best[r], &mut accept_r);
                    best_t[r] = best[r].t;
                }
            } else {
                let node4 = &self.nodes[node.index()];
                let (masks, near) = boxes.test(node4, &best_t, mask);
                if stack.has_room(4) {
                    // Nearest child on top: its hits shorten the others' rays before they are
                    // tested.
                    for k in far_to_near(&masks, &near) {
                        let entry = u64::from(masks[k]) << 32 | u64::from(node4.child[k].0);
                        stack.push_first([entry], usize::from(masks[k] != 0));
                    }
                } else {
                    for (&reached, &child) in masks.iter().zip(&node4.child) {
                        let mut m = reached;
                        while m != 0 {
                            let r = m.trailing_zeros() as usize;
                            m &= m - 1;
                            let single = BoxRay::from_precomp(ray(r));
                            let mut accept_r = |id: u32, h: &TriangleHit| accept(r, id, h);
                            self.closest_recursive(
                                child,
                                &packets[r],
                                &single,
                                &mut best[r],
                                &mut accept_r,
                            );
                            best_t[r] = best[r].t;
                        }
                    }
                }
            }
            entry = stack.pop().map(|e| (NodeRef(e as u32), (e >> 32) as u32));
        }
        for (slot, b) in out.iter_mut().zip(&best[..n]) {
            *slot = b.found();
        }
    }
}

impl Bvh {
    /// Tests packet `p`'s triangles, one at a time, against the rays of `mask`, offering each
    /// hit to its ray's `best` as `Bvh::closest_in_leaf` does.
    #[inline(always)]
    fn closest_in_packet(
        &self,
        p: &TriPacket,
        mask: u32,
        shear: &BundleShear,
        pres: &[RayPrecomp],
        best: &mut [Closest; BUNDLE],
        accept: &mut impl FnMut(usize, u32, &TriangleHit) -> bool,
    ) {
        for (j, &id) in p.ids.iter().enumerate() {
            if id == TriPacket::UNUSED {
                break;
            }
            let tri = p.triangle(j);
            // Ties with each ray's best so far are let through, as in the leaf test.
            let limits: [f32; BUNDLE] = std::array::from_fn(|r| best[r].tie_limit());
            let hits = shear.test(&tri, &limits);
            let mut m = RayHits::mask(&hits.hit) & mask;
            while m != 0 {
                let r = m.trailing_zeros() as usize;
                m &= m - 1;
                let h = hits.get(r);
                if best[r].improved_by(h.t, id) && accept(r, id, &h) {
                    best[r].take(id, h);
                }
            }
            // An edge function exactly zero: the scalar test decides in double precision.
            let mut m = RayHits::mask(&hits.on_edge) & mask;
            while m != 0 {
                let r = m.trailing_zeros() as usize;
                m &= m - 1;
                if let Some(h) = intersect_watertight(&pres[r], &tri, limits[r]) {
                    if best[r].improved_by(h.t, id) && accept(r, id, &h) {
                        best[r].take(id, h);
                    }
                }
            }
        }
    }
}

impl BundleBoxes {
    /// For each child k of `n`: the rays of `mask` that meet its box within [0, best_t] (bit r for
    /// ray r), and the nearest entry distance among them (+∞ where none does).
    #[inline(always)]
    fn test(&self, n: &super::Node4, best_t: &[f32; BUNDLE], mask: u32) -> ([u32; 4], [f32; 4]) {
        let mut masks = [0u32; 4];
        let mut nearest = [f32::INFINITY; 4];
        for k in 0..4 {
            if n.valid >> k & 1 == 0 {
                continue;
            }
            let lower = [n.bounds[0][0][k], n.bounds[0][1][k], n.bounds[0][2][k]];
            let upper = [n.bounds[1][0][k], n.bounds[1][1][k], n.bounds[1][2][k]];
            let mut bits = [0u32; BUNDLE];
            let mut entry = [u32::MAX; BUNDLE];
            for r in 0..BUNDLE {
                let slab = |axis: usize| {
                    let a = (lower[axis] - self.o[axis][r]) * self.inv_d[axis][r];
                    let b = (upper[axis] - self.o[axis][r]) * self.inv_d[axis][r];
                    (min(a, b), max(a, b))
                };
                let ((x0, x1), (y0, y1), (z0, z1)) = (slab(0), slab(1), slab(2));
                // Ordered as `BoxRay::test` orders them (max and min are exact: any order gives
                // the same value).
                let near = max(max(x0, y0), max(z0, 0.0));
                let far = min(min(x1, y1), min(z1, best_t[r])) * FAR_WIDEN;
                let hit = near <= far && mask >> r & 1 == 1;
                bits[r] = u32::from(hit) << r;
                entry[r] = if hit { near.to_bits() } else { u32::MAX };
            }
            masks[k] = bits.iter().fold(0, |m, b| m | b);
            nearest[k] = f32::from_bits(entry.iter().fold(u32::MAX, |m, &e| m.min(e)));
        }
        (masks, nearest)
    }
}

/// The four child slots ordered by entry distance, farthest first (empty ones, at +∞, first of
/// all: they are not pushed).
#[inline(always)]
fn far_to_near(masks: &[u32; 4], near: &[f32; 4]) -> [usize; 4] {
    let key = |k: usize| {
        let d = if masks[k] != 0 {
            near[k]
        } else {
            f32::INFINITY
        };
        // Non-negative floats order as their bits do.
        (u64::from(d.to_bits()) << 2) | k as u64
    };
    sort4_descending([key(0), key(1), key(2), key(3)]).map(|key| (key & 3) as usize)
}

/// `a.min(b)` for values that are never NaN, as one instruction (`f32::min` also handles NaN).
#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `a.max(b)` for values that are never NaN (see [`min`]).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use glam::Vec3;

    /// Bundles of rays from one point into a small cone (camera rays of one pixel), of others
    /// spread over the scene, of parallel rays onto the shared edges of a grid (edge functions
    /// exactly zero), and of every size from 1 to 16, against each ray's own query, on a random
    /// soup with ties and a filter.
    #[test]
    fn every_ray_of_a_bundle_gets_its_own_closest_hit() {
        let mut rng = crate::testing::uniform_stream(0x1234_5678_9abc_def1u64);
        let mut mesh = crate::testing::shared_corner_soup(&mut rng, 800, 5000, 60);
        // A grid of unit squares at z = 6, two triangles each.
        for i in -4..4 {
            for j in -4..4 {
                let p = |di: i32, dj: i32| Vec3::new((i + di) as f32, (j + dj) as f32, 6.0);
                for tri in [[p(0, 0), p(1, 0), p(1, 1)], [p(0, 0), p(1, 1), p(0, 1)]] {
                    mesh.positions.push(tri);
                    mesh.material.push(0);
                }
            }
        }
        let bvh = Bvh::build(&mesh).tree_only();
        let (mut hits, mut edges) = (0, 0);
        for case in 0..1500 {
            let n = case % BUNDLE + 1;
            let o = Vec3::new(rng(), rng(), rng()) * 14.0 - 7.0;
            let axis = (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize_or(Vec3::Z);
            let spread = [0.002, 0.05, 2.0][case % 3];
            let rays: Vec<Ray> = (0..n)
                .map(|_| {
                    let jitter = Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0;
                    if case % 7 == 0 {
                        // Straight down onto the grid from points on a quarter-unit lattice.
                        let q = ((jitter * 4.0 * 4.0).round() * 0.25).with_z(9.0);
                        return Ray::new(q, -Vec3::Z);
                    }
                    let from = if case % 5 == 0 { o + jitter } else { o };
                    Ray::new(from, (axis + jitter * spread).normalize_or(Vec3::X))
                })
                .collect();
            let pres: Vec<RayPrecomp> = rays.iter().map(RayPrecomp::new).collect();
            let t_max = if case % 4 == 0 { 6.0 } else { f32::INFINITY };
            // Every third case rejects triangles whose index is a multiple of 7 for odd rays.
            let filtered = case % 3 == 1;
            let accept = |r: usize, id: u32, _: &TriangleHit| {
                !(filtered && r % 2 == 1 && id.is_multiple_of(7))
            };
            // The walk's own stack, and one so small that most nodes go on ray by ray.
            let mut got = [None; BUNDLE];
            bvh.closest_bundle_in::<false>(&pres, t_max, accept, &mut got);
            let mut small = [None; BUNDLE];
            bvh.closest_bundle_with::<false, 5>(&pres, t_max, accept, &mut small);
            for (r, (ray, pre)) in rays.iter().zip(&pres).enumerate() {
                let want = bvh.closest(pre, ray.d, t_max, |id, h| accept(r, id, h));
                assert_eq!(got[r], want, "case {case}, ray {r} of {n}");
                assert_eq!(small[r], want, "case {case}, ray {r} of {n}, small stack");
                hits += usize::from(want.is_some());
                if let Some((_, h)) = want {
                    edges += usize::from(h.b1 == 0.0 || h.b2 == 0.0 || h.b1 + h.b2 == 1.0);
                }
            }
        }
        assert!(
            hits > 3000,
            "{hits} hits: the rays do not exercise the tree"
        );
        assert!(
            edges > 100,
            "{edges} edge hits: the scalar decisions are not exercised"
        );
    }
}
