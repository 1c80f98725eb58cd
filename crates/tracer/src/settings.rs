//! Render settings: everything besides the scene that determines the bits of an image.

use std::fmt;
use std::str::FromStr;

/// How direct lighting is estimated at each path vertex. All strategies are unbiased and converge to
/// the same image; they differ only in variance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum DirectStrategy {
    /// Uniform hemisphere (sphere, for transmissive surfaces) directions, pdf 1/2π.
    Hemisphere,
    /// Cosine-weighted directions, pdf cos θ / π.
    Cosine,
    /// BSDF importance sampling only: emission is found by the path's own continuation ray.
    Bsdf,
    /// A point on a light's area, pdf 1/A, with the cos θ cos θ' / r² change of variables.
    Light,
    /// Light and BSDF sampling combined with the power heuristic.
    #[default]
    Mis,
}

impl DirectStrategy {
    pub const ALL: [DirectStrategy; 5] = [
        DirectStrategy::Hemisphere,
        DirectStrategy::Cosine,
        DirectStrategy::Bsdf,
        DirectStrategy::Light,
        DirectStrategy::Mis,
    ];

    pub fn name(self) -> &'static str {
        match self {
            DirectStrategy::Hemisphere => "hemisphere",
            DirectStrategy::Cosine => "cosine",
            DirectStrategy::Bsdf => "bsdf",
            DirectStrategy::Light => "light",
            DirectStrategy::Mis => "mis",
        }
    }
}

impl fmt::Display for DirectStrategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for DirectStrategy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        DirectStrategy::ALL
            .into_iter()
            .find(|d| d.name() == s)
            .ok_or_else(|| format!("unknown direct-lighting strategy {s:?} (expected hemisphere, cosine, bsdf, light or mis)"))
    }
}

/// Russian roulette: unbiased path termination (survivors are divided by the survival probability).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum RussianRoulette {
    /// Never terminate early (paths end by escaping, by absorption, or at `max_depth`).
    Off,
    /// The textbook rule, `0.5@0.25` of [`RussianRoulette::Threshold`]: after the second path
    /// vertex, a path whose throughput's luminance is below 0.25 ends with probability ½ (its
    /// survivors doubled). A bright path never ends by roulette, and a survivor's weight stays
    /// below 0.5 in luminance, so no rare path is amplified far above its neighbours. It was the
    /// most efficient setting (error² × time) on six of the seven bench scenes, ahead of
    /// [`RussianRoulette::Max`] (the default until November 26) by 7–73 %, and it traces 5.5 %
    /// fewer rays per sample on the Cornell box (docs/benchmarks.md).
    #[default]
    Auto,
    /// After the fourth path vertex, survive with probability min(1, max component of the
    /// throughput). Written `max`.
    Max,
    /// After the second path vertex, survive with this fixed probability in (0, 1].
    Fixed(f32),
    /// After the second path vertex, terminate with probability `terminate` ∈ (0, 1) whenever the
    /// throughput's luminance is below `below` (> 0); brighter paths always go on. Written
    /// `TERMINATE@BELOW`, e.g. `0.5@0.25`: "terminate 50 % below luminance 0.25", the classic
    /// textbook form.
    Threshold { terminate: f32, below: f32 },
}

impl fmt::Display for RussianRoulette {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RussianRoulette::Off => f.write_str("off"),
            RussianRoulette::Auto => f.write_str("auto"),
            RussianRoulette::Max => f.write_str("max"),
            RussianRoulette::Fixed(p) => write!(f, "{p}"),
            RussianRoulette::Threshold { terminate, below } => write!(f, "{terminate}@{below}"),
        }
    }
}

impl FromStr for RussianRoulette {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(RussianRoulette::Off),
            "auto" => Ok(RussianRoulette::Auto),
            "max" => Ok(RussianRoulette::Max),
            _ if s.contains('@') => {
                let bad = || format!("invalid Russian roulette {s:?} (expected TERMINATE@BELOW, e.g. 0.5@0.25: terminate with probability TERMINATE in (0, 1) when the throughput's luminance is below BELOW > 0)");
                let (t, b) = s.split_once('@').ok_or_else(bad)?;
                let terminate: f32 = t.parse().map_err(|_| bad())?;
                let below: f32 = b.parse().map_err(|_| bad())?;
                if terminate > 0.0 && terminate < 1.0 && below > 0.0 && below.is_finite() {
                    Ok(RussianRoulette::Threshold { terminate, below })
                } else {
                    Err(bad())
                }
            }
            _ => match s.parse::<f32>() {
                Ok(p) if p > 0.0 && p <= 1.0 => Ok(RussianRoulette::Fixed(p)),
                _ => Err(format!("invalid Russian roulette {s:?} (expected off, auto, max, a survival probability in (0, 1], or TERMINATE@BELOW)")),
            },
        }
    }
}

/// The sample generator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum SamplerKind {
    /// Owen-scrambled Sobol (randomized quasi-Monte Carlo).
    #[default]
    Sobol,
    /// Independent uniform random numbers (plain Monte Carlo).
    Independent,
}

impl fmt::Display for SamplerKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SamplerKind::Sobol => "sobol",
            SamplerKind::Independent => "independent",
        })
    }
}

impl FromStr for SamplerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sobol" => Ok(SamplerKind::Sobol),
            "independent" => Ok(SamplerKind::Independent),
            _ => Err(format!(
                "unknown sampler {s:?} (expected sobol or independent)"
            )),
        }
    }
}

/// A hard safety cap on path length when `max_depth` is unlimited, so a scene of perfectly white,
/// perfectly closed walls with roulette off still terminates. Not reachable in any physical scene
/// before the throughput underflows.
pub const SAFETY_MAX_DEPTH: u32 = 1 << 16;

/// Everything besides the scene that determines an image's bits.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    pub direct: DirectStrategy,
    pub rr: RussianRoulette,
    /// Maximum number of bounces (0 = emission seen directly only). `None` is unlimited: the default
    /// and the only unbiased choice; a cap drops the light of longer paths.
    pub max_depth: Option<u32>,
    pub sampler: SamplerKind,
}

impl RenderSettings {
    pub fn new(width: u32, height: u32) -> Self {
        RenderSettings {
            width,
            height,
            seed: 0,
            direct: DirectStrategy::Mis,
            rr: RussianRoulette::Auto,
            max_depth: None,
            sampler: SamplerKind::Sobol,
        }
    }

    pub(crate) fn depth_limit(&self) -> u32 {
        self.max_depth
            .unwrap_or(SAFETY_MAX_DEPTH)
            .min(SAFETY_MAX_DEPTH)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn russian_roulette_round_trips_and_rejects_nonsense() {
        for s in ["off", "auto", "max", "0.5", "1", "0.5@0.25", "0.9@0.1"] {
            let rr: RussianRoulette = s.parse().unwrap();
            assert_eq!(
                rr.to_string().parse::<RussianRoulette>().unwrap(),
                rr,
                "{s}"
            );
        }
        assert_eq!(
            "0.5@0.25".parse::<RussianRoulette>().unwrap(),
            RussianRoulette::Threshold {
                terminate: 0.5,
                below: 0.25
            }
        );
        for bad in [
            "0", "1.5", "0@0.25", "1@0.25", "0.5@0", "0.5@", "@0.2", "0.5@x", "x",
        ] {
            let err = bad.parse::<RussianRoulette>().unwrap_err();
            assert!(err.contains(bad), "{bad}: {err}");
        }
    }
}
