//! The AVX-512F lanes. Every intrinsic needs its CPU feature, so every call is `unsafe`; the
//! safety argument is the [`Avx512`] value itself, which only [`Avx512::detect`] makes.

use super::{any_with, closest_with, pair_with, Lanes, WidePacket, WIDE};
use crate::geometry::{RayPrecomp, TriangleHit};
use std::arch::x86_64::*;

/// Proof that the processor has AVX-512F (the field is private: only `detect` makes one).
/// Its [`Lanes`] operations are one 16-lane register each; compares give a 16-bit mask.
#[derive(Clone, Copy, Debug)]
pub(super) struct Avx512(());

impl Avx512 {
    pub fn detect() -> Option<Avx512> {
        is_x86_feature_detected!("avx512f").then_some(Avx512(()))
    }

    /// [`closest_with`] compiled for AVX-512F. The whole loop is compiled with the feature, so
    /// that the generic test and the `Lanes` operations inline into it (they are
    /// `#[inline(always)]`; a function compiled without the feature could not inline the
    /// intrinsics, and every operation would be a call).
    ///
    /// # Safety
    /// None beyond `self`'s existence (the processor has AVX-512F); `unsafe` only because the
    /// compiler requires it for calls into `#[target_feature]` functions.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn closest(
        self,
        packets: &[WidePacket],
        pre: &RayPrecomp,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> Option<(u32, TriangleHit)> {
        closest_with(self, packets, pre, t_max, accept)
    }

    /// [`pair_with`] compiled for AVX-512F.
    ///
    /// # Safety
    /// As [`Avx512::closest`].
    #[target_feature(enable = "avx512f")]
    pub unsafe fn pair(
        self,
        packets: &[WidePacket],
        a: (&RayPrecomp, f32),
        accept_a: &mut impl FnMut(u32, &TriangleHit) -> bool,
        b: (&RayPrecomp, f32),
        accept_b: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> (Option<(u32, TriangleHit)>, bool) {
        pair_with(self, packets, a, accept_a, b, accept_b)
    }

    /// [`any_with`] compiled for AVX-512F.
    ///
    /// # Safety
    /// As [`Avx512::closest`].
    #[target_feature(enable = "avx512f")]
    pub unsafe fn any(
        self,
        packets: &[WidePacket],
        pre: &RayPrecomp,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) -> bool {
        any_with(self, packets, pre, t_max, accept)
    }
}

// SAFETY (every `unsafe` block of this impl): an `Avx512` exists, so the processor has
// AVX-512F; the loads and stores go through references to 16 `f32`s, which the unaligned
// forms accept at any address.
impl Lanes for Avx512 {
    type F = __m512;
    #[inline(always)]
    fn splat(self, x: f32) -> __m512 {
        unsafe { _mm512_set1_ps(x) }
    }
    #[inline(always)]
    fn load(self, x: &[f32; WIDE]) -> __m512 {
        unsafe { _mm512_loadu_ps(x.as_ptr()) }
    }
    #[inline(always)]
    fn store(self, x: __m512) -> [f32; WIDE] {
        let mut out = [0.0f32; WIDE];
        unsafe { _mm512_storeu_ps(out.as_mut_ptr(), x) };
        out
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
    fn min_where(self, mask: u32, x: &[f32; WIDE]) -> f32 {
        unsafe { _mm512_mask_reduce_min_ps(mask as __mmask16, self.load(x)) }
    }
}
