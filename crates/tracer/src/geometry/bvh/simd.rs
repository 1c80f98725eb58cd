//! Which SIMD width the BVH's leaf tests use, chosen at run time.
//!
//! Every x86-64 processor has SSE2, and the traversal is written for it (4-lane node and packet
//! tests). Where the processor also has AVX2, the traversal is compiled a second time for it and a
//! leaf's packets are tested two at a time, eight triangles in one test. Both give the same bits
//! (each lane does the scalar test's exact operations), so the choice changes speed, never an
//! image; [`set_wide`] exists to measure one against the other and to test that they agree.

use std::sync::atomic::{AtomicBool, Ordering};

static WIDE_ALLOWED: AtomicBool = AtomicBool::new(true);

/// Allows (the default) or forbids the 8-lane AVX2 leaf test for the whole process.
pub fn set_wide(allowed: bool) {
    WIDE_ALLOWED.store(allowed, Ordering::Relaxed);
}

/// True when the 8-lane AVX2 leaf test is used: the processor has AVX2 and [`set_wide`] has not
/// forbidden it.
#[inline]
pub fn wide() -> bool {
    WIDE_ALLOWED.load(Ordering::Relaxed) && has_avx2()
}

/// True if the processor has AVX2 (detected once, then a cached flag).
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
