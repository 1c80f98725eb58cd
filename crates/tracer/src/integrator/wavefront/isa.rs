//! Which build of the wavefront's vector steps this processor runs.

/// An instruction set the vector steps are compiled for. A value exists only where the processor
/// was found to have its features: it is the proof that calling that build is sound. Only
/// [`Isa::detect`] makes one (its field is visible to `lanes.rs`, which matches on it, and nothing
/// else in `wavefront/` builds it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Isa(pub(super) Kind);

#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Avx512,
}

/// Elsewhere than x86-64 there is no build of the lanes (the scalar integrator runs).
#[cfg(not(target_arch = "x86_64"))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {}

impl Isa {
    /// AVX-512 (16 lanes a register), if this processor has it. Without it the scalar integrator
    /// runs: the same steps compiled for AVX2 (8 lanes) measured no faster than it on the Cornell
    /// box (2.87 against 2.88 M samples/s), and for the baseline (SSE2: 4 lanes, no gathers, no
    /// rounding instruction) slower (2.28 M), so neither is kept.
    pub(crate) fn detect() -> Option<Isa> {
        #[cfg(target_arch = "x86_64")]
        {
            let avx512 = std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512dq")
                && std::arch::is_x86_feature_detected!("avx512vl");
            avx512.then_some(Isa(Kind::Avx512))
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            None
        }
    }
}
