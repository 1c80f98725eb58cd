//! The BSDF sampling check shared by `bsdf_distributions/` and `layer_lobes/`: draw samples,
//! check each against eval and pdf, histogram the directions and run the chi-square test against
//! the pdf integrated over the bins, at four view angles on each side asked for.

use super::bins::Binning;
use super::Pcg32;
use glam::{Vec2, Vec3};
use pathfarm_tracer::bsdf::{Bsdf, BsdfSample};
use pathfarm_tracer::stats::chi_square_test;

/// The p-value below which a histogram fails.
pub const MIN_P: f64 = 1e-4;

/// The cosines of the view angles every configuration is checked at (down to grazing).
pub const VIEW_COS: [f32; 4] = [0.95, 0.6, 0.25, 0.05];

/// wo at cos θ = `cos` (front side) or −`cos` (back side), in the xz plane.
pub fn wo_at(cos: f32, front: bool) -> Vec3 {
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    Vec3::new(sin, 0.0, if front { cos } else { -cos })
}

/// What one histogram found.
pub struct RunStats {
    pub p_value: f64,
    pub dof: usize,
    pub max_weight_err: f64,
    pub max_pdf_err: f64,
    pub non_delta: usize,
}

impl RunStats {
    /// The histogram fits, every weight is eval/pdf, every pdf is pdf(wo, wi), and enough samples
    /// were not delta to judge.
    pub fn passes(&self) -> bool {
        self.p_value > MIN_P
            && self.max_weight_err <= 1e-3
            && self.max_pdf_err <= 1e-3
            && self.non_delta >= 1000
    }
}

/// How the histogram's local directions map to the BSDF's world directions (a tilted surface).
pub struct Frame<'a> {
    pub to_local: &'a dyn Fn(Vec3) -> Vec3,
    pub to_world: &'a dyn Fn(Vec3) -> Vec3,
}

/// The identity: the BSDF's normal is the histogram's z axis.
pub const WORLD: Frame<'static> = Frame {
    to_local: &|v| v,
    to_world: &|v| v,
};

/// Draws `n` samples of `b` at `wo` (world), histograms the non-delta ones in `bins` (local),
/// checks eval_pdf against eval and pdf and the weight against eval/pdf for each, hands each to
/// `check` with its recomputed pdf for what the caller asserts besides, and runs the chi-square
/// test against ∫ pdf over the bins.
pub fn run_chi2(
    b: &Bsdf,
    wo: Vec3,
    bins: &Binning,
    frame: &Frame,
    n: usize,
    seed: u64,
    check: &dyn Fn(&BsdfSample, f32),
) -> RunStats {
    let mut observed = vec![0.0f64; bins.len()];
    let mut rng = Pcg32::new(seed, 7);
    let (mut max_weight_err, mut max_pdf_err, mut non_delta) = (0.0f64, 0.0f64, 0usize);
    for _ in 0..n {
        let u_lobe = rng.f32();
        let u = Vec2::new(rng.f32(), rng.f32());
        let Some(s) = b.sample(wo, u_lobe, u) else {
            continue;
        };
        assert!(
            s.weight.is_finite() && s.weight.min_element() >= 0.0 && s.pdf > 0.0,
            "bad sample {s:?}"
        );
        assert!((s.wi.length() - 1.0).abs() < 1e-4);
        if s.delta {
            check(&s, s.pdf);
            continue;
        }
        non_delta += 1;
        let k = bins
            .bin((frame.to_local)(s.wi))
            .unwrap_or_else(|| panic!("sample outside the bins: {:?}", s.wi));
        observed[k] += 1.0;
        let e = b.eval(wo, s.wi);
        let pdf = b.pdf(wo, s.wi);
        let (ep, combined_pdf) = b.eval_pdf(wo, s.wi);
        assert_eq!(ep, e, "eval_pdf disagrees with eval");
        assert_eq!(combined_pdf, pdf, "eval_pdf disagrees with pdf");
        check(&s, pdf);
        max_pdf_err = max_pdf_err.max(((pdf - s.pdf) / s.pdf).abs() as f64);
        let scale = s.weight.max_element().max(1e-6);
        let w = e / pdf;
        max_weight_err = max_weight_err.max(((w - s.weight).abs().max_element() / scale) as f64);
    }
    let expected: Vec<f64> = bins
        .integrate(|w| b.pdf(wo, (frame.to_world)(w)) as f64, &observed)
        .iter()
        .map(|e| e * n as f64)
        .collect();
    let chi = chi_square_test(&observed, &expected, 5.0);
    RunStats {
        p_value: chi.p_value,
        dof: chi.dof,
        max_weight_err,
        max_pdf_err,
        non_delta,
    }
}

/// Runs `run(wo, seed)` at every view angle of [`VIEW_COS`] on each side in `sides` (true: the
/// front), prints each result and asserts that all pass.
pub fn check_view_angles(
    name: &str,
    sides: &[bool],
    seed: u64,
    mut run: impl FnMut(Vec3, u64) -> RunStats,
) {
    let mut failures = Vec::new();
    for (si, &front) in sides.iter().enumerate() {
        for (ci, &c) in VIEW_COS.iter().enumerate() {
            let st = run(wo_at(c, front), seed * 1000 + (si * 10 + ci) as u64);
            println!(
                "{name:<34} {} cos {c:<4}: p = {:.4} (dof {:4}), non-delta {:7}, max |w − eval/pdf| {:.1e}, max pdf err {:.1e}",
                if front { "front" } else { "back " },
                st.p_value,
                st.dof,
                st.non_delta,
                st.max_weight_err,
                st.max_pdf_err
            );
            if !st.passes() {
                failures.push(format!(
                    "{name} front={front} cos={c}: p={} w_err={} pdf_err={} non-delta={}",
                    st.p_value, st.max_weight_err, st.max_pdf_err, st.non_delta
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The test's power: the p-values of samples of `b` against `b`'s own pdf and against `wrong`'s,
/// histogrammed in `bins` (the BSDFs' normal is z), from `n` samples at `wo`.
pub fn p_right_and_wrong(b: &Bsdf, wrong: &Bsdf, wo: Vec3, bins: &Binning, n: usize) -> (f64, f64) {
    let mut observed = vec![0.0f64; bins.len()];
    let mut rng = Pcg32::new(99, 1);
    for _ in 0..n {
        if let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) {
            if !s.delta {
                observed[bins.bin(s.wi).expect("sample inside the bins")] += 1.0;
            }
        }
    }
    let expect = |bsdf: &Bsdf| -> Vec<f64> {
        bins.integrate(|w| bsdf.pdf(wo, w) as f64, &observed)
            .iter()
            .map(|e| e * n as f64)
            .collect()
    };
    let right = chi_square_test(&observed, &expect(b), 5.0);
    let bad = chi_square_test(&observed, &expect(wrong), 5.0);
    (right.p_value, bad.p_value)
}
