//! Error against time: every configuration of every scene rendered progressively (passes of
//! growing sample counts), measured against the reference after each pass.

use crate::metrics::{log_log_slope, measure, ErrorMeasures};
use crate::reference::Reference;
use crate::render::render_range;
use pathfarm_tracer::{
    Accumulation, DirectStrategy, RenderSettings, RussianRoulette, SamplerKind, Scene,
};
use serde::{Deserialize, Serialize};

/// |z| of the image mean against the reference below which a run "agrees within noise". Four
/// standard errors: with ~100 runs in a report, a correct estimator fails this about once in
/// 150 reports, while a biased one (or one whose noise is badly underestimated) fails it quickly.
pub const AGREEMENT_Z: f64 = 4.0;

/// The passes' sample counts grow by this factor: many points for the chart and the slope fit,
/// while a pass never costs more than half of what was already spent.
const PASS_GROWTH: f64 = 1.5;

/// Passes below this many samples per pixel are left out of the slope fit: at 1–3 spp the error
/// is dominated by pixels with no light found yet, and the time by start-up.
pub const SLOPE_MIN_SPP: u32 = 4;

/// One estimator configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    pub direct: DirectStrategy,
    pub sampler: SamplerKind,
    pub rr: RussianRoulette,
}

impl Config {
    pub fn label(&self) -> String {
        format!("{} · {} · rr {}", self.direct, self.sampler, self.rr)
    }

    pub fn settings(&self, width: u32, height: u32, seed: u64) -> RenderSettings {
        RenderSettings {
            seed,
            direct: self.direct,
            sampler: self.sampler,
            rr: self.rr,
            ..RenderSettings::new(width, height)
        }
    }
}

/// The Russian roulette settings studied besides the default `auto`.
pub fn roulette_variants() -> [RussianRoulette; 4] {
    [
        RussianRoulette::Off,
        RussianRoulette::Fixed(0.8),
        RussianRoulette::Fixed(0.5),
        RussianRoulette::Max,
    ]
}

/// Every configuration measured on each scene: the five strategies with both samplers (roulette
/// `auto`), then MIS with Sobol under each other roulette setting.
pub fn matrix() -> Vec<Config> {
    let mut configs = Vec::new();
    for sampler in [SamplerKind::Sobol, SamplerKind::Independent] {
        for direct in DirectStrategy::ALL {
            configs.push(Config {
                direct,
                sampler,
                rr: RussianRoulette::Auto,
            });
        }
    }
    for rr in roulette_variants() {
        configs.push(Config {
            direct: DirectStrategy::Mis,
            sampler: SamplerKind::Sobol,
            rr,
        });
    }
    configs
}

/// When a progressive run stops.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Seconds of rendering: passes stop once the next would end past ~1.1 × this.
    pub budget: f64,
    /// A fixed sample count instead of the time budget (quick mode: the same passes, hence the
    /// same errors, on every machine and every run).
    pub max_spp: Option<u32>,
}

/// The image after one pass.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PassPoint {
    pub spp: u32,
    /// Rendering time so far.
    pub seconds: f64,
    pub rays: u64,
    pub errors: ErrorMeasures,
}

/// One configuration on one scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunResult {
    pub label: String,
    pub strategy: String,
    pub sampler: String,
    pub rr: String,
    pub passes: Vec<PassPoint>,
    pub spp: u32,
    pub seconds: f64,
    pub samples_per_second: f64,
    pub rays_per_second: f64,
    pub rays_per_sample: f64,
    /// Errors of the final image.
    pub errors: ErrorMeasures,
    /// 1 / (MSE × seconds) of the final image: higher is better, independent of the budget for an
    /// estimator whose error falls as 1/√t. `None` when the error is below the reference's noise.
    pub efficiency: Option<f64>,
    /// Fitted slope of ln RMSE against ln time (−1/2 for plain Monte Carlo).
    pub slope_time: Option<f64>,
    /// Fitted slope of ln RMSE against ln samples per pixel.
    pub slope_spp: Option<f64>,
    /// Largest single-sample luminance seen.
    pub max_sample: f64,
    /// NaN / infinite / negative samples caught (never added to the image).
    pub invalid: u64,
    /// |mean_z| < [`AGREEMENT_Z`].
    pub agrees: bool,
    /// Relative RMSE at each budget of the equal-time ladder (`None`: no pass had finished).
    pub at_budgets: Vec<Option<f64>>,
}

/// The equal-time budgets of the ladder for a largest budget `b`: b/16 … b.
pub fn budget_ladder(b: f64) -> Vec<f64> {
    (0..5).map(|k| b / f64::from(1u32 << (4 - k))).collect()
}

/// Renders `config` progressively and measures it after every pass.
pub fn run(
    scene: &Scene,
    settings: &RenderSettings,
    reference: &Reference,
    limits: Limits,
) -> (RunResult, Accumulation) {
    let config_label = format!(
        "{} · {} · rr {}",
        settings.direct, settings.sampler, settings.rr
    );
    let mut acc = Accumulation::new(0, 0, settings.width, settings.height);
    let mut passes = Vec::new();
    let (mut seconds, mut max_sample, mut invalid) = (0.0f64, 0.0f64, 0u64);
    let mut end = 0u32;
    loop {
        let next = ((end as f64 * PASS_GROWTH).ceil() as u32).max(end + 1);
        let next = limits.max_spp.map_or(next, |m| next.min(m));
        if end > 0 {
            let done = match limits.max_spp {
                Some(m) => end >= m,
                None => {
                    let predicted = seconds * (next - end) as f64 / end as f64;
                    seconds + predicted > limits.budget * 1.1
                }
            };
            if done {
                break;
            }
        }
        let r = render_range(scene, settings, end..next);
        seconds += r.seconds;
        max_sample = max_sample.max(r.max_sample);
        invalid += r.invalid;
        // Same size and origin: the merge cannot fail.
        let _ = acc.merge(&r.acc);
        end = next;
        passes.push(PassPoint {
            spp: end,
            seconds,
            rays: acc.rays,
            errors: measure(&acc, reference),
        });
    }
    let last = passes.last().map(|p| p.errors).unwrap_or_default();
    let samples = u64::from(end) * u64::from(settings.width * settings.height);
    let fit = |x: fn(&PassPoint) -> f64| {
        let pts: Vec<(f64, f64)> = passes
            .iter()
            .filter(|p| p.spp >= SLOPE_MIN_SPP)
            .map(|p| (x(p), p.errors.rmse))
            .collect();
        log_log_slope(&pts)
    };
    let at_budgets = budget_ladder(limits.budget)
        .into_iter()
        .map(|b| {
            passes
                .iter()
                .rfind(|p| p.seconds <= b)
                .map(|p| p.errors.rel_rmse)
        })
        .collect();
    let result = RunResult {
        label: config_label,
        strategy: settings.direct.to_string(),
        sampler: settings.sampler.to_string(),
        rr: settings.rr.to_string(),
        spp: end,
        seconds,
        samples_per_second: samples as f64 / seconds.max(1e-9),
        rays_per_second: acc.rays as f64 / seconds.max(1e-9),
        rays_per_sample: acc.rays as f64 / samples.max(1) as f64,
        errors: last,
        efficiency: (last.mse > 0.0).then(|| 1.0 / (last.mse * seconds.max(1e-9))),
        slope_time: fit(|p| p.seconds),
        slope_spp: fit(|p| p.spp as f64),
        max_sample,
        invalid,
        agrees: last.mean_z.abs() < AGREEMENT_Z,
        at_budgets,
        passes,
    };
    (result, acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_matrix_has_every_strategy_with_both_samplers_and_the_roulette_variants() {
        let m = matrix();
        assert_eq!(m.len(), 14);
        for d in DirectStrategy::ALL {
            for s in [SamplerKind::Sobol, SamplerKind::Independent] {
                assert!(m.iter().any(|c| c.direct == d && c.sampler == s));
            }
        }
        assert!(m.iter().any(|c| c.rr == RussianRoulette::Off));
    }

    #[test]
    fn ladder_doubles_up_to_the_budget() {
        assert_eq!(budget_ladder(8.0), vec![0.5, 1.0, 2.0, 4.0, 8.0]);
    }
}
