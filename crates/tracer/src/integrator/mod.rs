//! The path integrator: one path per sample, solving the rendering equation with unbiased estimators.
//!
//! At every path vertex:
//! 1. emission seen by the ray is added, weighted so that no light is counted twice (see
//!    [`EmissionWeight`]);
//! 2. direct lighting is estimated for the BSDF's non-delta lobes with the chosen
//!    [`DirectStrategy`], plus one sample of the punctual lights (which no ray can hit);
//! 3. the path continues in a BSDF-sampled direction (delta lobes are always sampled from the lobe);
//! 4. Russian roulette may end it, dividing survivors by the survival probability.

mod direct;
mod path;
mod wavefront;

pub use path::{trace_path, PathResult};
pub(crate) use wavefront::{DiffuseScene, Wavefront};

use glam::Vec3;

/// How emission found by a BSDF-sampled ray is counted at the next vertex. This is what keeps every
/// strategy unbiased: emission is counted by exactly one estimator (or split between two by MIS).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum EmissionWeight {
    /// Camera rays and rays leaving delta lobes: no other estimator can reach this light.
    Full,
    /// Direct lighting at the previous vertex already accounted for area lights, and for the
    /// environment where `environment` (a light sample that may choose it, or a direction
    /// sample, which finds it).
    Skip { environment: bool },
    /// MIS with light sampling: the power-heuristic weight of the BSDF strategy, whose solid-angle
    /// pdf was this.
    Mis {
        bsdf_pdf: f32,
        /// Where the vertex that sampled the ray is, and its geometric normal: the light choice
        /// there depends on them (`AreaLights::pdf`).
        from: Vec3,
        n: Vec3,
    },
}
