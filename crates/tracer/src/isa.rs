//! The tracer's one instruction-set detection: which build of its vector code this processor
//! runs. The wavefront integrator's steps (`integrator/wavefront/lanes/builds.rs`) and the flat
//! test of small meshes (`geometry/bvh/flat/x86.rs`) are each compiled for AVX-512 and for AVX2,
//! and both run the build [`Isa::detect`] names, so a process never mixes them.
//!
//! `PATHFARM_ISA` (`avx512`, `avx2` or `none`) caps the choice at that build, for comparing the
//! builds on one machine (`none`: the scalar integrator and the tree, as on a processor without
//! AVX2). An unknown value is ignored with a warning. It never widens the choice beyond what the
//! processor has.

use std::sync::OnceLock;

/// An instruction set the vector code is compiled for. A value exists only where the processor
/// was found to have its features: it is the proof that calling that build is sound. Only
/// [`Isa::detected`] makes one, and each build names its own inside the function compiled for it
/// (`lanes/builds.rs`: that function runs only where the features are, so the value is as true
/// there; it makes the build's choice a constant). Nothing else builds one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Isa(pub(crate) Kind);

#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    /// AVX-512F/BW/DQ/VL: one register per 16-lane array.
    Avx512,
    /// AVX2 (with BMI1/2, LZCNT, POPCNT, as x86-64-v3 without FMA: a fused multiply-add would
    /// round differently from the scalar code): two registers per 16-lane array.
    Avx2,
}

/// Elsewhere than x86-64 there is no build of the vector code (the scalar paths run).
#[cfg(not(target_arch = "x86_64"))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {}

/// The environment variable that caps the detected build (see the module documentation).
pub const ISA_VARIABLE: &str = "PATHFARM_ISA";

impl Isa {
    /// The build this process runs: the widest the processor has, at most what `PATHFARM_ISA`
    /// allows; `None` without AVX2 (the scalar paths run). Decided once per process. The baseline
    /// build (SSE2: 4 lanes, no gathers, no rounding instruction) measured slower than the scalar
    /// integrator (2.28 against 2.88 M samples/s on the Cornell box), so it is not kept.
    pub(crate) fn detect() -> Option<Isa> {
        static CHOSEN: OnceLock<Option<Isa>> = OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let cap = std::env::var(ISA_VARIABLE).ok();
            let chosen = Isa::capped(cap.as_deref());
            tracing::debug!(isa = ?chosen, cap = ?cap, "the vector code's instruction set");
            chosen
        })
    }

    /// The widest build the processor has that `cap` (a `PATHFARM_ISA` value) allows.
    fn capped(cap: Option<&str>) -> Option<Isa> {
        let rank = |isa: &Isa| match isa.0 {
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => 2,
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => 1,
        };
        let most = match cap.map(str::trim).map(str::to_ascii_lowercase).as_deref() {
            None | Some("") | Some("avx512") => 2,
            Some("avx2") => 1,
            Some("none") => 0,
            Some(other) => {
                tracing::warn!(
                    value = other,
                    "{ISA_VARIABLE} is not avx512, avx2 or none: ignored"
                );
                2
            }
        };
        Isa::detected().find(|isa| rank(isa) <= most)
    }

    /// Every build this processor runs, widest first, whatever `PATHFARM_ISA` says (tests check
    /// each).
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

#[cfg(test)]
mod tests {
    use super::Isa;

    #[test]
    fn the_cap_never_widens_and_none_turns_the_vector_code_off() {
        let all: Vec<Isa> = Isa::detected().collect();
        assert_eq!(Isa::capped(None), all.first().copied());
        assert_eq!(Isa::capped(Some("avx512")), all.first().copied());
        assert_eq!(Isa::capped(Some(" AVX512 ")), all.first().copied());
        assert_eq!(Isa::capped(Some("nonsense")), all.first().copied());
        assert_eq!(Isa::capped(Some("none")), None);
        // AVX2 is the narrowest build: capped there, the processor runs it if it has it.
        assert_eq!(Isa::capped(Some("avx2")), all.last().copied());
        if all.len() == 2 {
            assert_ne!(Isa::capped(Some("avx2")), Isa::capped(None));
        }
    }
}
