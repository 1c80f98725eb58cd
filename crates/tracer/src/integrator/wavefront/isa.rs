//! Which build of the wavefront's vector steps this processor runs.

/// An instruction set the vector steps are compiled for. A value exists only where the processor
/// was found to have its features: it is the proof that calling that build is sound. Only
/// [`Isa::detected`] makes one, and each build names its own inside the function compiled for it
/// (`lanes/builds.rs`: that function runs only where the features are, so the value is as true
/// there; it makes the build's choice a constant). Nothing else in `wavefront/` builds one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Isa(pub(super) Kind);

#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    /// AVX-512F/BW/DQ/VL: one register per 16-lane array.
    Avx512,
    /// AVX2 (with BMI1/2, LZCNT, POPCNT, as x86-64-v3 without FMA: a fused multiply-add would
    /// round differently from the scalar code): two registers per 16-lane array.
    Avx2,
}

/// Elsewhere than x86-64 there is no build of the lanes (the scalar integrator runs).
#[cfg(not(target_arch = "x86_64"))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {}

impl Isa {
    /// The build the wavefront runs on this processor, the widest it has; `None` without AVX2
    /// (the scalar integrator runs). The baseline build (SSE2: 4 lanes, no gathers, no rounding
    /// instruction) measured slower than the scalar integrator (2.28 against 2.88 M samples/s on
    /// the Cornell box), so it is not kept.
    pub(crate) fn detect() -> Option<Isa> {
        Isa::detected().next()
    }

    /// Every build this processor runs, widest first (tests check each).
    pub(crate) fn detected() -> impl Iterator<Item = Isa> {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            let avx512 =
                has!("avx512f") && has!("avx512bw") && has!("avx512dq") && has!("avx512vl");
            let avx2 =
                has!("avx2") && has!("bmi1") && has!("bmi2") && has!("lzcnt") && has!("popcnt");
            [
                avx512.then_some(Isa(Kind::Avx512)),
                avx2.then_some(Isa(Kind::Avx2)),
            ]
            .into_iter()
            .flatten()
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            std::iter::empty()
        }
    }
}
