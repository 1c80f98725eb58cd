//! The x86-64 lanes: AVX-512F (a packet in one register) and AVX2 (a packet in two). Every
//! intrinsic needs its CPU feature, so every call is `unsafe`; the safety argument is the
//! [`Avx512`] or [`Avx2`] value itself, which only [`Backend::of`] makes, from an [`Isa`] (the
//! tracer's one detection).

use super::{any_with, closest_with, pair_with, Lanes, Mesh, Packed, Query, WIDE};
use crate::geometry::TriangleHit;
use crate::isa::{Isa, Kind};
use std::arch::x86_64::*;

/// The instruction set a flat mesh is tested in.
#[derive(Clone, Copy, Debug)]
pub(super) enum Backend {
    Avx512(Avx512),
    Avx2(Avx2),
}

impl Backend {
    /// The build this process runs ([`Isa::detect`], the tracer's one detection), if any.
    pub fn detect() -> Option<Backend> {
        Isa::detect().map(Backend::of)
    }

    /// Every one this processor has, widest first (tests check each).
    #[cfg(test)]
    pub fn detected() -> impl Iterator<Item = Backend> {
        Isa::detected().map(Backend::of)
    }

    /// The test's build for `isa`, whose existence proves the features it needs (AVX-512F, or
    /// AVX2).
    fn of(isa: Isa) -> Backend {
        match isa.0 {
            Kind::Avx512 => Backend::Avx512(Avx512(())),
            Kind::Avx2 => Backend::Avx2(Avx2(())),
        }
    }

    /// The largest mesh tested without a tree in this instruction set.
    pub fn max_triangles(self) -> usize {
        match self {
            Backend::Avx512(_) => super::MAX_TRIANGLES,
            Backend::Avx2(_) => super::MAX_TRIANGLES_AVX2,
        }
    }

    /// [`closest_with`] in this instruction set: called, compiled for it, or with `INLINED` its
    /// body inlined into the caller (see [`super::Flat::closest`]).
    #[inline(always)]
    pub fn closest<const INLINED: bool>(
        self,
        mesh: Mesh<'_>,
        q: Query<'_>,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        if INLINED {
            return match self {
                Backend::Avx512(l) => closest_with(l, mesh, q, accept),
                Backend::Avx2(l) => closest_with(l, mesh, q, accept),
            };
        }
        // SAFETY (each call): the value exists, so the processor has its features.
        let packed = match self {
            Backend::Avx512(l) => unsafe { l.closest(mesh, q, accept) },
            Backend::Avx2(l) => unsafe { l.closest(mesh, q, accept) },
        };
        packed.found()
    }

    /// [`pair_with`] in this instruction set, as `closest`.
    #[inline(always)]
    pub fn pair<const INLINED: bool>(
        self,
        mesh: Mesh<'_>,
        a: Query<'_>,
        accept_a: &mut impl FnMut(u32, &TriangleHit) -> bool,
        b: Query<'_>,
        accept_b: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        if INLINED {
            return match self {
                Backend::Avx512(l) => pair_with(l, mesh, a, accept_a, b, accept_b),
                Backend::Avx2(l) => pair_with(l, mesh, a, accept_a, b, accept_b),
            };
        }
        // SAFETY (each call): as in `closest`.
        let packed = match self {
            Backend::Avx512(l) => unsafe { l.pair(mesh, a, accept_a, b, accept_b) },
            Backend::Avx2(l) => unsafe { l.pair(mesh, a, accept_a, b, accept_b) },
        };
        (packed.found(), packed.blocked())
    }

    /// [`any_with`] in this instruction set, as `closest`.
    #[inline(always)]
    pub fn any<const INLINED: bool>(
        self,
        mesh: Mesh<'_>,
        q: Query<'_>,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        if INLINED {
            return match self {
                Backend::Avx512(l) => any_with(l, mesh, q, accept),
                Backend::Avx2(l) => any_with(l, mesh, q, accept),
            };
        }
        // SAFETY (each call): as in `closest`.
        match self {
            Backend::Avx512(l) => unsafe { l.any(mesh, q, accept) },
            Backend::Avx2(l) => unsafe { l.any(mesh, q, accept) },
        }
    }
}

/// The three queries compiled with `$features`. The whole loop is compiled with the features, so
/// that the generic test and the `Lanes` operations inline into it (they are `#[inline(always)]`;
/// a function compiled without the features could not inline the intrinsics, and every operation
/// would be a call). Each is `unsafe` only because the compiler requires it for calls into
/// `#[target_feature]` functions: `self`'s existence proves the features. They answer in a
/// [`Packed`], which comes back in registers.
macro_rules! queries_compiled_for {
    ($features:literal) => {
        #[target_feature(enable = $features)]
        unsafe fn closest(
            self,
            mesh: Mesh<'_>,
            q: Query<'_>,
            accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
        ) -> Packed {
            Packed::new(closest_with(self, mesh, q, accept), false)
        }

        #[target_feature(enable = $features)]
        unsafe fn pair(
            self,
            mesh: Mesh<'_>,
            a: Query<'_>,
            accept_a: &mut impl FnMut(u32, &TriangleHit) -> bool,
            b: Query<'_>,
            accept_b: &mut impl FnMut(u32, &TriangleHit) -> bool,
        ) -> Packed {
            let (found, blocked) = pair_with(self, mesh, a, accept_a, b, accept_b);
            Packed::new(found, blocked)
        }

        #[target_feature(enable = $features)]
        unsafe fn any(
            self,
            mesh: Mesh<'_>,
            q: Query<'_>,
            accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
        ) -> bool {
            any_with(self, mesh, q, accept)
        }
    };
}

/// Proof that the processor has AVX-512F (the field is private: only `Backend::of` makes
/// one). Its [`Lanes`] operations are one 16-lane register each; compares give a 16-bit mask.
#[derive(Clone, Copy, Debug)]
pub(super) struct Avx512(());

impl Avx512 {
    queries_compiled_for!("avx512f");
}

/// Proof that the processor has AVX2 (only `Backend::of` makes one). Its [`Lanes`]
/// operations are one 8-lane register each: a packet is two halves.
#[derive(Clone, Copy, Debug)]
pub(super) struct Avx2(());

impl Avx2 {
    queries_compiled_for!("avx2");
}

// SAFETY (every `unsafe` block of this impl): an `Avx512` exists, so the processor has
// AVX-512F; the loads and stores go through references to 16 `f32`s, which the unaligned
// forms accept at any address.
impl Lanes for Avx512 {
    const N: usize = WIDE;
    type F = __m512;
    #[inline(always)]
    fn splat(self, x: f32) -> __m512 {
        unsafe { _mm512_set1_ps(x) }
    }
    #[inline(always)]
    fn load(self, x: &[f32; WIDE], at: usize) -> __m512 {
        let x: &[f32; 16] = x[at..][..16].try_into().expect("16 lanes");
        unsafe { _mm512_loadu_ps(x.as_ptr()) }
    }
    #[inline(always)]
    fn store(self, x: __m512, out: &mut [f32; WIDE], at: usize) {
        let out: &mut [f32; 16] = (&mut out[at..][..16]).try_into().expect("16 lanes");
        unsafe { _mm512_storeu_ps(out.as_mut_ptr(), x) };
    }
    #[inline(always)]
    fn add(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_add_ps(a, b) }
    }
    #[inline(always)]
    fn sub(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_sub_ps(a, b) }
    }
    #[inline(always)]
    fn mul(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_mul_ps(a, b) }
    }
    #[inline(always)]
    fn div(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_div_ps(a, b) }
    }
    #[inline(always)]
    fn lt(self, a: __m512, b: __m512) -> u32 {
        u32::from(unsafe { _mm512_cmp_ps_mask::<_CMP_LT_OQ>(a, b) })
    }
    #[inline(always)]
    fn eq(self, a: __m512, b: __m512) -> u32 {
        u32::from(unsafe { _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(a, b) })
    }
    #[inline(always)]
    fn signs_differ(self, a: __m512, b: __m512, c: __m512) -> u32 {
        unsafe {
            let (a, b, c) = (
                _mm512_castps_si512(a),
                _mm512_castps_si512(b),
                _mm512_castps_si512(c),
            );
            // (a ^ b) | (a ^ c): 0 only where a, b and c agree (truth table 0x7E).
            let differ = _mm512_ternarylogic_epi32::<0x7E>(a, b, c);
            u32::from(_mm512_test_epi32_mask(differ, _mm512_set1_epi32(i32::MIN)))
        }
    }
    #[inline(always)]
    fn flip_sign_by(self, x: __m512, s: __m512) -> __m512 {
        unsafe {
            let (x, s) = (_mm512_castps_si512(x), _mm512_castps_si512(s));
            // x ^ (s & sign bit) (truth table 0x78).
            let flipped = _mm512_ternarylogic_epi32::<0x78>(x, s, _mm512_set1_epi32(i32::MIN));
            _mm512_castsi512_ps(flipped)
        }
    }
    #[inline(always)]
    fn min_where(self, mask: u32, x: &[f32; WIDE]) -> f32 {
        unsafe { _mm512_mask_reduce_min_ps(mask as __mmask16, self.load(x, 0)) }
    }
}

// SAFETY (every `unsafe` block of this impl): an `Avx2` exists, so the processor has AVX2; the
// loads and stores go through references to 8 `f32`s, which the unaligned forms accept at any
// address.
impl Lanes for Avx2 {
    const N: usize = 8;
    type F = __m256;
    #[inline(always)]
    fn splat(self, x: f32) -> __m256 {
        unsafe { _mm256_set1_ps(x) }
    }
    #[inline(always)]
    fn load(self, x: &[f32; WIDE], at: usize) -> __m256 {
        let x: &[f32; 8] = x[at..][..8].try_into().expect("8 lanes");
        unsafe { _mm256_loadu_ps(x.as_ptr()) }
    }
    #[inline(always)]
    fn store(self, x: __m256, out: &mut [f32; WIDE], at: usize) {
        let out: &mut [f32; 8] = (&mut out[at..][..8]).try_into().expect("8 lanes");
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), x) };
    }
    #[inline(always)]
    fn add(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_add_ps(a, b) }
    }
    #[inline(always)]
    fn sub(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_sub_ps(a, b) }
    }
    #[inline(always)]
    fn mul(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_mul_ps(a, b) }
    }
    #[inline(always)]
    fn div(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_div_ps(a, b) }
    }
    #[inline(always)]
    fn lt(self, a: __m256, b: __m256) -> u32 {
        (unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(a, b)) }) as u32
    }
    #[inline(always)]
    fn eq(self, a: __m256, b: __m256) -> u32 {
        (unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(a, b)) }) as u32
    }
    #[inline(always)]
    fn signs_differ(self, a: __m256, b: __m256, c: __m256) -> u32 {
        // The sign bits of (a ^ b) | (a ^ c).
        let differ = unsafe { _mm256_or_ps(_mm256_xor_ps(a, b), _mm256_xor_ps(a, c)) };
        (unsafe { _mm256_movemask_ps(differ) }) as u32
    }
    #[inline(always)]
    fn flip_sign_by(self, x: __m256, s: __m256) -> __m256 {
        unsafe { _mm256_xor_ps(x, _mm256_and_ps(s, _mm256_set1_ps(-0.0))) }
    }
    #[inline(always)]
    fn min_where(self, mask: u32, x: &[f32; WIDE]) -> f32 {
        // Hits are few (one or two lanes of a packet, mostly): one at a time.
        let mut rest = mask;
        let mut min = f32::INFINITY;
        while rest != 0 {
            min = min.min(x[rest.trailing_zeros() as usize]);
            rest &= rest - 1;
        }
        min
    }
}
