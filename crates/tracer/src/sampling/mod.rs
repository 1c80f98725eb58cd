//! Sampling routines: warps from uniform random numbers in [0,1)ᵈ to the distributions the estimators
//! need, each with its density. One concept per file; every routine is chi-square tested against its
//! pdf (see `tests/sampling_distributions.rs`).

mod discrete;
mod disk;
mod distribution2d;
mod inverse_cdf;
mod sphere;
mod spherical_triangle;
mod triangle;

pub use discrete::Distribution1D;
pub use disk::{sample_concentric_disk, sample_uniform_disk};
pub use distribution2d::Distribution2D;
pub use inverse_cdf::{cubic_falloff_pdf, sample_cubic_falloff};
pub use sphere::{
    cosine_hemisphere_pdf, sample_cosine_hemisphere, sample_uniform_hemisphere,
    sample_uniform_sphere, uniform_hemisphere_pdf, uniform_sphere_pdf,
};
pub use spherical_triangle::{barycentrics_along, barycentrics_along_unchecked, SphericalTriangle};
pub use triangle::sample_uniform_triangle;

/// Multiple importance sampling: the power heuristic (β = 2) weight of a strategy with density `pa`
/// against one with density `pb`, each drawing one sample.
#[inline]
pub fn power_heuristic(pa: f32, pb: f32) -> f32 {
    let a = pa * pa;
    let b = pb * pb;
    if a.is_infinite() {
        return 1.0;
    }
    if a + b == 0.0 {
        0.0
    } else {
        a / (a + b)
    }
}
