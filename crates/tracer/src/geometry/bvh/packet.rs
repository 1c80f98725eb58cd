//! The watertight ray/triangle test of `triangle.rs`, four triangles at once.
//!
//! Every lane performs exactly the operations of [`intersect_watertight`], in the same order and
//! without fused multiply-adds, so a lane's verdict, distance and barycentrics are the same bits as
//! the scalar test's: the images do not depend on which test found a hit. The one branch the
//! scalar test takes rarely — an edge function exactly zero in single precision, decided again in
//! double precision — is left to the scalar test for the lanes that need it.

use super::node::TriPacket;
use super::Closest;
use crate::geometry::{intersect_watertight, RayPrecomp, TriangleHit};
use glam::{Vec3, Vec4};

/// The per-ray constants of the test, splatted across lanes once per ray.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PacketRay<'a> {
    /// The ray's own constants, by reference: a copy read them back in 16-byte loads across the
    /// narrower stores that had just written them, which the processor cannot forward (a stall
    /// per query).
    pub scalar: &'a RayPrecomp,
    /// The origin's permuted coordinates (o[kx], o[ky], o[kz]).
    o: [Vec4; 3],
    /// The shear (sx, sy, sz).
    s: [Vec4; 3],
}

impl<'a> PacketRay<'a> {
    #[inline]
    pub fn new(pre: &'a RayPrecomp) -> PacketRay<'a> {
        let [kx, ky, kz] = pre.k;
        // Indexed loads (not `Vec3[i]`'s match on a random axis), one component each.
        let o: &[f32; 3] = pre.o.as_ref();
        PacketRay {
            scalar: pre,
            o: [Vec4::splat(o[kx]), Vec4::splat(o[ky]), Vec4::splat(o[kz])],
            s: pre.s.map(Vec4::splat),
        }
    }

    /// The sheared coordinates of one vertex of the four triangles, as `RayPrecomp::shear` computes
    /// them for one.
    #[inline(always)]
    fn shear(&self, v: &[Vec4; 3]) -> [Vec4; 3] {
        let [kx, ky, kz] = self.scalar.k;
        let dx = v[kx] - self.o[0];
        let dy = v[ky] - self.o[1];
        let dz = v[kz] - self.o[2];
        [dx - self.s[0] * dz, dy - self.s[1] * dz, self.s[2] * dz]
    }
}

/// The hits of a packet of N triangles: bit k of `mask` set when lane k's triangle is hit in
/// (0, t_max). Lane k keeps the test's numerators and denominator (t·det, b1·det, b2·det and det),
/// and [`LaneHits::get`] divides them out, as the scalar test does: the division, the slowest
/// instruction of the test (about 20 cycles for 16 lanes), is then made only for the lanes a query
/// reads, after the mask has decided, instead of on the way to every verdict. Which triangle lane
/// k holds the packet says (`id(k)` below). Shared by the 4-lane test below and the 16-lane one of
/// `flat.rs`.
#[derive(Clone, Copy, Debug)]
pub(super) struct LaneHits<const N: usize> {
    pub mask: u32,
    pub t_scaled: [f32; N],
    pub b1_scaled: [f32; N],
    pub b2_scaled: [f32; N],
    pub det: [f32; N],
}

/// The hits of one 4-triangle packet.
pub(super) type PacketHits = LaneHits<4>;

impl<const N: usize> LaneHits<N> {
    /// No hits: the scratch space packet tests write into, one per leaf or query rather than a
    /// value returned per packet, which the compiler copied — 64 bytes per 4-lane packet, read
    /// back in one load across the four 16-byte stores that had just written them, which the
    /// processor cannot forward (a stall per packet test).
    pub const NONE: LaneHits<N> = LaneHits {
        mask: 0,
        t_scaled: [0.0; N],
        b1_scaled: [0.0; N],
        b2_scaled: [0.0; N],
        det: [0.0; N],
    };

    /// Lane k's distance and barycentrics: the scalar test's `inv = 1 / det` and its three
    /// products, the same bits.
    #[inline(always)]
    pub fn get(&self, k: usize) -> TriangleHit {
        let inv = 1.0 / self.det[k];
        TriangleHit {
            t: self.t_scaled[k] * inv,
            b1: self.b1_scaled[k] * inv,
            b2: self.b2_scaled[k] * inv,
        }
    }

    /// Lane k's hit as the scalar test gave it: its values over a denominator of 1 (x / 1 = x).
    #[inline(always)]
    fn set(&mut self, k: usize, h: TriangleHit) {
        self.mask |= 1 << k;
        self.t_scaled[k] = h.t;
        self.b1_scaled[k] = h.b1;
        self.b2_scaled[k] = h.b2;
        self.det[k] = 1.0;
    }

    /// Decides the lanes of `on_edge` (an edge function exactly zero in single precision) with
    /// the scalar test, which redoes them in double precision; `triangle(k)` is lane k's triangle.
    #[inline(always)]
    pub fn decide_edges(
        &mut self,
        on_edge: u32,
        pre: &RayPrecomp,
        t_max: f32,
        triangle: impl Fn(usize) -> [Vec3; 3],
    ) {
        let mut rest = on_edge;
        while rest != 0 {
            let k = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            if let Some(h) = intersect_watertight(pre, &triangle(k), t_max) {
                self.set(k, h);
            }
        }
    }

    /// Offers the hit lanes of `lanes` to `best` in lane order: each that is closer (or ties with a
    /// smaller index) and that `accept` lets through becomes the best. Lane k holds triangle
    /// `id(k)`.
    #[inline(always)]
    pub fn offer(
        &self,
        lanes: u32,
        id: impl Fn(usize) -> u32,
        best: &mut Closest,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        let mut m = lanes;
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            let h = self.get(k);
            let id = id(k);
            if best.improved_by(h.t, id) && accept(id, &h) {
                best.take(id, h);
            }
        }
    }

    /// Whether `accept` lets through one of the hits (lane k holds triangle `id(k)`).
    #[inline(always)]
    pub fn any_accepted(
        &self,
        id: impl Fn(usize) -> u32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        let mut m = self.mask;
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            if accept(id(k), &self.get(k)) {
                return true;
            }
        }
        false
    }
}

/// Tests the ray against the four triangles of `p`, into `out` (see [`LaneHits::NONE`]).
#[inline(always)]
pub(super) fn intersect_packet(r: &PacketRay<'_>, p: &TriPacket, t_max: f32, out: &mut PacketHits) {
    let [ax, ay, az] = r.shear(&p.v[0]);
    let [bx, by, bz] = r.shear(&p.v[1]);
    let [cx, cy, cz] = r.shear(&p.v[2]);
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    let zero = Vec4::ZERO;
    let valid = p.valid();
    let on_edge = (u.cmpeq(zero) | v.cmpeq(zero) | w.cmpeq(zero)).bitmask() & valid;
    let outside = (u.cmplt(zero) | v.cmplt(zero) | w.cmplt(zero))
        & (u.cmpgt(zero) | v.cmpgt(zero) | w.cmpgt(zero));
    let det = u + v + w;
    let t_scaled = u * az + v * bz + w * cz;
    let limit = Vec4::splat(t_max) * det;
    let in_range_pos = det.cmpgt(zero) & t_scaled.cmpgt(zero) & t_scaled.cmplt(limit);
    let in_range_neg = det.cmplt(zero) & t_scaled.cmplt(zero) & t_scaled.cmpgt(limit);
    let hit = !outside & (in_range_pos | in_range_neg);
    out.mask = hit.bitmask() & valid & !on_edge;
    t_scaled.write_to_slice(&mut out.t_scaled);
    v.write_to_slice(&mut out.b1_scaled);
    w.write_to_slice(&mut out.b2_scaled);
    det.write_to_slice(&mut out.det);
    // Lanes with an edge function exactly zero: the scalar test decides them in double precision.
    out.decide_edges(on_edge, r.scalar, t_max, |k| p.triangle(k));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use glam::Vec3;

    /// A small deterministic generator (xorshift), so the test needs no dependency.
    fn rng(state: &mut u64) -> f32 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn every_lane_matches_the_scalar_test_bit_for_bit() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut hits = 0;
        let mut edges = 0;
        for case in 0..20_000 {
            let mut p3 = || Vec3::new(rng(&mut s), rng(&mut s), rng(&mut s)) * 2.0 - 1.0;
            let mut tris: Vec<[Vec3; 3]> = (0..4).map(|_| [p3(), p3(), p3()]).collect();
            // Shared edges and axis-aligned geometry hit by axis-aligned rays: the exact-zero
            // edge functions that go to double precision.
            if case % 4 == 0 {
                tris[1] = [tris[0][1], tris[0][0], p3()];
                tris[2] = [
                    Vec3::new(-1., -1., 0.),
                    Vec3::new(1., -1., 0.),
                    Vec3::new(1., 1., 0.),
                ];
                tris[3] = [
                    Vec3::new(-1., -1., 0.),
                    Vec3::new(1., 1., 0.),
                    Vec3::new(-1., 1., 0.),
                ];
            }
            let n = if case % 4 == 0 { 4 } else { case % 4 };
            let ids: Vec<u32> = (0..n as u32).collect();
            let packet = TriPacket::new(&tris, &ids);
            let (o, d) = if case % 8 == 0 {
                let q = (p3() * 4.0).round() * 0.25;
                (Vec3::new(q.x, q.y, 2.0), -Vec3::Z)
            } else {
                // Aim at a point of one of the triangles (or just beside it), so most rays hit.
                let o = p3() * 3.0;
                let tri = tris[case % n];
                let (b1, b2) = (rng(&mut s) * 1.2 - 0.1, rng(&mut s) * 1.2 - 0.1);
                let target = tri[0] + (tri[1] - tri[0]) * b1 * 0.5 + (tri[2] - tri[0]) * b2 * 0.5;
                (o, (target - o).normalize_or(Vec3::X))
            };
            let pre = RayPrecomp::new(&Ray::new(o, d));
            let t_max = if case % 3 == 0 { 1.5 } else { f32::INFINITY };
            let mut got = PacketHits::NONE;
            intersect_packet(&PacketRay::new(&pre), &packet, t_max, &mut got);
            for (k, tri) in tris.iter().enumerate() {
                let want = if k < n {
                    intersect_watertight(&pre, tri, t_max)
                } else {
                    None
                };
                let lane = (got.mask >> k) & 1 == 1;
                assert_eq!(lane, want.is_some(), "case {case} lane {k}");
                if let Some(h) = want {
                    hits += 1;
                    let g = got.get(k);
                    assert_eq!(
                        (g.t.to_bits(), g.b1.to_bits(), g.b2.to_bits()),
                        (h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()),
                        "case {case} lane {k}"
                    );
                    if h.b1 == 0.0 || h.b2 == 0.0 || h.b1 + h.b2 == 1.0 {
                        edges += 1;
                    }
                }
            }
        }
        assert!(
            hits > 2_000,
            "{hits} hits: the cases do not exercise the test"
        );
        assert!(
            edges > 50,
            "{edges} edge hits: the double-precision lanes are not exercised"
        );
    }
}
