//! The textbook inverse-CDF example: p(x) = 3(1 − x)² on [0, 1].
//!
//! CDF P(x) = 1 − (1 − x)³, so x = P⁻¹(ξ) = 1 − (1 − ξ)^{1/3}. It samples distances that fall off
//! towards the end of a segment, and it is tested like every other routine.

/// Sample x ∈ [0,1) with density 3(1 − x)².
#[inline]
pub fn sample_cubic_falloff(u: f32) -> f32 {
    1.0 - (1.0 - u).cbrt()
}

#[inline]
pub fn cubic_falloff_pdf(x: f32) -> f32 {
    if (0.0..=1.0).contains(&x) {
        3.0 * (1.0 - x) * (1.0 - x)
    } else {
        0.0
    }
}
