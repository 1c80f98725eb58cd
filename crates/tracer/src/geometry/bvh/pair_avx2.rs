//! The watertight test of `packet.rs` on two packets at once — eight triangles in one 8-lane AVX2
//! test — for processors that have AVX2 (chosen at run time, see [`super::simd`]).
//!
//! Every lane performs exactly the operations of [`intersect_packet`](super::packet) and of
//! [`intersect_watertight`], in the same order and without fused multiply-adds, so a lane's
//! verdict, distance and barycentrics are the same bits whichever test ran: an image does not
//! depend on the processor that rendered it.

use super::node::TriPacket;
use super::packet::PacketRay;
use crate::geometry::{intersect_watertight, TriangleHit};
use glam::Vec4;
use std::arch::x86_64::{
    __m128, __m256, _mm256_add_ps, _mm256_and_ps, _mm256_andnot_ps, _mm256_cmp_ps, _mm256_div_ps,
    _mm256_extractf128_ps, _mm256_movemask_ps, _mm256_mul_ps, _mm256_or_ps, _mm256_set1_ps,
    _mm256_set_m128, _mm256_setzero_ps, _mm256_sub_ps, _CMP_EQ_OQ, _CMP_GT_OQ, _CMP_LT_OQ,
};

/// The per-ray constants of the 8-lane test.
#[derive(Clone, Copy)]
pub(super) struct PairRay {
    o: [__m256; 3],
    s: [__m256; 3],
}

impl PairRay {
    /// # Safety
    /// The processor must have AVX2 (as for every function of this file).
    #[inline(always)]
    pub unsafe fn new(r: &PacketRay) -> PairRay {
        let (o, s) = r.splats();
        // SAFETY: the caller guarantees AVX2.
        unsafe {
            PairRay {
                o: [splat(o[0]), splat(o[1]), splat(o[2])],
                s: [splat(s[0]), splat(s[1]), splat(s[2])],
            }
        }
    }
}

/// The hits of two packets: bit k of `mask` set when lane k's triangle is hit in (0, t_max) —
/// lanes 0–3 the first packet's, 4–7 the second's — with its distance and barycentrics in lane k.
#[derive(Clone, Copy, Debug)]
pub(super) struct PairHits {
    pub mask: u32,
    pub t: [f32; 8],
    pub b1: [f32; 8],
    pub b2: [f32; 8],
}

impl PairHits {
    #[inline(always)]
    pub fn get(&self, k: usize) -> TriangleHit {
        TriangleHit {
            t: self.t[k],
            b1: self.b1[k],
            b2: self.b2[k],
        }
    }
}

// The helpers below are `unsafe` `#[inline(always)]` functions rather than `#[target_feature]`
// ones, and use no closures: inlined into the traversal compiled for AVX2
// (`Bvh::closest_from_avx2`, `Bvh::any_from_avx2`), their intrinsics inline there. A
// `#[target_feature]` test would stay an out-of-line call from the traversal.

#[inline(always)]
unsafe fn splat(x: f32) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_set1_ps(x) }
}

#[inline(always)]
unsafe fn sub(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_sub_ps(a, b) }
}

#[inline(always)]
unsafe fn mul(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_mul_ps(a, b) }
}

#[inline(always)]
unsafe fn add(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_add_ps(a, b) }
}

#[inline(always)]
unsafe fn and(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_and_ps(a, b) }
}

#[inline(always)]
unsafe fn or(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_or_ps(a, b) }
}

#[inline(always)]
unsafe fn eq(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(a, b) }
}

#[inline(always)]
unsafe fn lt(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(a, b) }
}

#[inline(always)]
unsafe fn gt(a: __m256, b: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_cmp_ps::<_CMP_GT_OQ>(a, b) }
}

#[inline(always)]
unsafe fn bits(a: __m256) -> u32 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_movemask_ps(a) as u32 }
}

/// Lanes 0–3 from `lo`, 4–7 from `hi`.
#[inline(always)]
unsafe fn join(lo: Vec4, hi: Vec4) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { _mm256_set_m128(__m128::from(hi), __m128::from(lo)) }
}

#[inline(always)]
unsafe fn lanes(x: __m256) -> [f32; 8] {
    // SAFETY: the caller guarantees AVX2.
    let (lo, hi) = unsafe { (_mm256_extractf128_ps::<0>(x), _mm256_extractf128_ps::<1>(x)) };
    let (lo, hi) = (Vec4::from(lo).to_array(), Vec4::from(hi).to_array());
    [lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2], hi[3]]
}

/// The sheared coordinates of one vertex of the eight triangles, as `RayPrecomp::shear` computes
/// them for one: [dx − sx·dz, dy − sy·dz, sz·dz].
#[inline(always)]
unsafe fn shear(k: [usize; 3], pr: &PairRay, v0: &[Vec4; 3], v1: &[Vec4; 3]) -> [__m256; 3] {
    // SAFETY: the caller guarantees AVX2.
    unsafe {
        let dx = sub(join(v0[k[0]], v1[k[0]]), pr.o[0]);
        let dy = sub(join(v0[k[1]], v1[k[1]]), pr.o[1]);
        let dz = sub(join(v0[k[2]], v1[k[2]]), pr.o[2]);
        [
            sub(dx, mul(pr.s[0], dz)),
            sub(dy, mul(pr.s[1], dz)),
            mul(pr.s[2], dz),
        ]
    }
}

/// a·b − c·d
#[inline(always)]
unsafe fn cross(a: __m256, b: __m256, c: __m256, d: __m256) -> __m256 {
    // SAFETY: the caller guarantees AVX2.
    unsafe { sub(mul(a, b), mul(c, d)) }
}

/// Tests the triangles of packets `p0` and `p1` (lanes 0–3 and 4–7) against the ray.
///
/// # Safety
/// The processor must have AVX2.
#[inline(always)]
pub(super) unsafe fn intersect_pair(
    r: &PacketRay,
    pr: &PairRay,
    p0: &TriPacket,
    p1: &TriPacket,
    t_max: f32,
) -> PairHits {
    let k = r.scalar.k;
    let valid = p0.valid | (p1.valid << 4);
    // SAFETY: the caller guarantees AVX2.
    let (mut mask, on_edge, mut out) = unsafe {
        let [ax, ay, az] = shear(k, pr, &p0.v[0], &p1.v[0]);
        let [bx, by, bz] = shear(k, pr, &p0.v[1], &p1.v[1]);
        let [cx, cy, cz] = shear(k, pr, &p0.v[2], &p1.v[2]);
        let u = cross(cx, by, cy, bx);
        let v = cross(ax, cy, ay, cx);
        let w = cross(bx, ay, by, ax);
        let zero = _mm256_setzero_ps();
        let on_edge = bits(or(or(eq(u, zero), eq(v, zero)), eq(w, zero))) & valid;
        let outside = and(
            or(or(lt(u, zero), lt(v, zero)), lt(w, zero)),
            or(or(gt(u, zero), gt(v, zero)), gt(w, zero)),
        );
        let det = add(add(u, v), w);
        let t_scaled = add(add(mul(u, az), mul(v, bz)), mul(w, cz));
        let limit = mul(splat(t_max), det);
        let in_range_pos = and(and(gt(det, zero), gt(t_scaled, zero)), lt(t_scaled, limit));
        let in_range_neg = and(and(lt(det, zero), lt(t_scaled, zero)), gt(t_scaled, limit));
        let hit = _mm256_andnot_ps(outside, or(in_range_pos, in_range_neg));
        let mask = bits(hit) & valid & !on_edge;
        // Divided whether or not a lane was hit, as in the 4-lane test.
        let inv = _mm256_div_ps(splat(1.0), det);
        let out = PairHits {
            mask: 0,
            t: lanes(mul(t_scaled, inv)),
            b1: lanes(mul(v, inv)),
            b2: lanes(mul(w, inv)),
        };
        (mask, on_edge, out)
    };
    // Lanes with an edge function exactly zero (rare): the scalar test decides them in double
    // precision, out of line.
    if on_edge != 0 {
        mask |= resolve_edges(r, p0, p1, t_max, on_edge, &mut out);
    }
    out.mask = mask;
    out
}

/// The lanes of `on_edge`, decided by the scalar test; returns the mask of those hit, their hits
/// written into `out`.
#[cold]
#[inline(never)]
fn resolve_edges(
    r: &PacketRay,
    p0: &TriPacket,
    p1: &TriPacket,
    t_max: f32,
    on_edge: u32,
    out: &mut PairHits,
) -> u32 {
    let mut mask = 0;
    let mut rest = on_edge;
    while rest != 0 {
        let k = rest.trailing_zeros() as usize;
        rest &= rest - 1;
        let tri = if k < 4 {
            p0.triangle(k)
        } else {
            p1.triangle(k - 4)
        };
        if let Some(h) = intersect_watertight(&r.scalar, &tri, t_max) {
            mask |= 1 << k;
            out.t[k] = h.t;
            out.b1[k] = h.b1;
            out.b2[k] = h.b2;
        }
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Ray, RayPrecomp};
    use glam::Vec3;

    /// Every lane of the 8-lane test gives the scalar watertight test's verdict and the same bits
    /// of t and the barycentrics, including the edge cases decided in double precision.
    #[test]
    fn every_lane_matches_the_scalar_test_bit_for_bit() {
        if !super::super::simd::has_avx2() {
            eprintln!("SKIPPED: this processor has no AVX2");
            return;
        }
        let mut u = crate::testing::uniform_stream(0x9e37_79b9_7f4a_7c15u64);
        let (mut hits, mut edges) = (0, 0);
        for case in 0..20_000 {
            let mut p3 = || Vec3::new(u(), u(), u()) * 2.0 - 1.0;
            let mut tris: Vec<[Vec3; 3]> = (0..8).map(|_| [p3(), p3(), p3()]).collect();
            if case % 4 == 0 {
                // Shared edges, and axis-aligned squares hit by axis-aligned rays: exact zeros.
                tris[1] = [tris[0][1], tris[0][0], p3()];
                tris[5] = [tris[4][2], tris[4][1], p3()];
                let (a, b, c, d) = (
                    Vec3::new(-1., -1., 0.),
                    Vec3::new(1., -1., 0.),
                    Vec3::new(1., 1., 0.),
                    Vec3::new(-1., 1., 0.),
                );
                tris[2] = [a, b, c];
                tris[3] = [a, c, d];
                tris[6] = [a, b, c];
                tris[7] = [a, c, d];
            }
            // The second packet may be partial (a leaf's last packet).
            let n1 = 1 + case % 4;
            let p0 = TriPacket::new(&tris[..4], 40);
            let p1 = TriPacket::new(&tris[4..4 + n1], 44);
            let (o, d) = if case % 8 == 0 {
                let q = (p3() * 4.0).round() * 0.25;
                (Vec3::new(q.x, q.y, 2.0), -Vec3::Z)
            } else {
                let o = p3() * 3.0;
                let tri = tris[case % 8];
                let (b1, b2) = (u() * 1.2 - 0.1, u() * 1.2 - 0.1);
                let target = tri[0] + (tri[1] - tri[0]) * b1 * 0.5 + (tri[2] - tri[0]) * b2 * 0.5;
                (o, (target - o).normalize_or(Vec3::X))
            };
            let pre = RayPrecomp::new(&Ray::new(o, d));
            let t_max = if case % 3 == 0 { 1.5 } else { f32::INFINITY };
            let ray = PacketRay::new(&pre);
            // SAFETY: the processor has AVX2 (checked above).
            let got = unsafe { intersect_pair(&ray, &PairRay::new(&ray), &p0, &p1, t_max) };
            for (k, tri) in tris.iter().enumerate() {
                let want = if k < 4 + n1 {
                    intersect_watertight(&pre, tri, t_max)
                } else {
                    None
                };
                assert_eq!(
                    (got.mask >> k) & 1 == 1,
                    want.is_some(),
                    "case {case} lane {k}"
                );
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
            hits > 4_000,
            "{hits} hits: the cases do not exercise the test"
        );
        assert!(
            edges > 50,
            "{edges} edge hits: the double-precision lanes are not exercised"
        );
    }
}
