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
    /// `0.5@0.1` of [`RussianRoulette::Threshold`]: after the second path vertex, a path whose
    /// throughput's luminance is below 0.1 ends with probability ½ (its survivors doubled). A
    /// bright path never ends by roulette, and a survivor's weight stays below 0.2 in luminance,
    /// so no rare path is amplified far above its neighbours. The textbook `0.5@0.25` was the
    /// default from November 26 (ahead of [`RussianRoulette::Max`] by 7–73 % then); once rays got
    /// cheaper against a sample's fixed costs, `0.5@0.1` measured the lower error at equal time on
    /// all eight peer scenes (by 1–14 %) and on five of six Blender suite scenes
    /// (docs/benchmarks.md, December 6).
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
    /// Parses what [`fmt::Display`] writes. The numbers are plain decimals (no sign, no
    /// exponent) of at most six significant digits ([`roulette_numbers`]), so every string
    /// accepted is one the API contract's pattern for `rr` accepts and the other way round, and
    /// each value's written form parses back to it.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(RussianRoulette::Off),
            "auto" => Ok(RussianRoulette::Auto),
            "max" => Ok(RussianRoulette::Max),
            _ if s.contains('@') => {
                let bad = || format!("invalid Russian roulette {s:?} (expected TERMINATE@BELOW, e.g. 0.5@0.25: terminate with probability TERMINATE in (0, 1) when the throughput's luminance is below BELOW in (0, 1000000), plain decimals of at most 6 significant digits)");
                let (t, b) = s.split_once('@').ok_or_else(bad)?;
                if !(roulette_numbers::is_fraction(t) && roulette_numbers::is_threshold(b)) {
                    return Err(bad());
                }
                let terminate: f32 = t.parse().map_err(|_| bad())?;
                let below: f32 = b.parse().map_err(|_| bad())?;
                Ok(RussianRoulette::Threshold { terminate, below })
            }
            _ if roulette_numbers::is_probability(s) => s
                .parse::<f32>()
                .map(RussianRoulette::Fixed)
                .map_err(|e| format!("invalid Russian roulette {s:?}: {e}")),
            _ => Err(format!("invalid Russian roulette {s:?} (expected off, auto, max, a survival probability in (0, 1], or TERMINATE@BELOW; plain decimals of at most 6 significant digits)")),
        }
    }
}

/// The numbers of a written Russian roulette, as plain decimals (digits and at most one point, no
/// sign, no exponent) of at most six significant digits (trailing zeros aside). Six digits is
/// what a float32 keeps exactly (`f32::DIGITS`): each such decimal parses to its own float, and
/// the shortest form `Display` writes of that float is the same decimal again, so stored
/// settings parse back. The bounds are decided on the digits, so no decimal is refused for a
/// rounding (`0.9999999` would be 1.0 as a float32, where TERMINATE must stay below 1).
///
/// The same grammar as regular expressions (the API contract's `rr` patterns, tested equal):
/// [`FRACTION`](roulette_numbers::FRACTION) and the others.
pub mod roulette_numbers {
    /// A number in (0, 1) of at most 6 significant digits, at least 10⁻³¹.
    pub const FRACTION: &str = r"0*\.0{0,30}[1-9][0-9]{0,5}0*";
    /// A number in (0, 1]: a [`FRACTION`] or one.
    pub const PROBABILITY: &str = r"0*\.0{0,30}[1-9][0-9]{0,5}0*|0*1(\.0*)?";
    /// A number in (0, 10⁶): a [`FRACTION`], or 1 to 6 integer digits and at most 6
    /// significant digits in all.
    pub const THRESHOLD: &str = r"0*\.0{0,30}[1-9][0-9]{0,5}0*|0*[1-9](\.[0-9]{0,5}0*)?|0*[1-9][0-9](\.[0-9]{0,4}0*)?|0*[1-9][0-9]{2}(\.[0-9]{0,3}0*)?|0*[1-9][0-9]{3}(\.[0-9]{0,2}0*)?|0*[1-9][0-9]{4}(\.[0-9]{0,1}0*)?|0*[1-9][0-9]{5}(\.0*)?";

    /// The most significant digits a number may have.
    const DIGITS: usize = 6;
    /// The most zeros between the point and a fraction's first significant digit.
    const LEADING_ZEROS: usize = 30;

    fn all_digits(s: &str) -> bool {
        s.bytes().all(|b| b.is_ascii_digit())
    }

    /// The significant digits of `digits` that start with a non-zero digit: its length without
    /// the trailing zeros.
    fn significant(digits: &str) -> usize {
        digits.trim_end_matches('0').len()
    }

    /// [`FRACTION`].
    pub fn is_fraction(s: &str) -> bool {
        let Some(rest) = s.trim_start_matches('0').strip_prefix('.') else {
            return false;
        };
        let digits = rest.trim_start_matches('0');
        all_digits(rest)
            && rest.len() - digits.len() <= LEADING_ZEROS
            && digits.starts_with(|c: char| c != '0')
            && (1..=DIGITS).contains(&significant(digits))
    }

    /// [`PROBABILITY`].
    pub fn is_probability(s: &str) -> bool {
        let one = s
            .trim_start_matches('0')
            .strip_prefix('1')
            .is_some_and(|rest| {
                rest.is_empty()
                    || rest
                        .strip_prefix('.')
                        .is_some_and(|z| z.bytes().all(|b| b == b'0'))
            });
        one || is_fraction(s)
    }

    /// [`THRESHOLD`].
    pub fn is_threshold(s: &str) -> bool {
        if is_fraction(s) {
            return true;
        }
        let s = s.trim_start_matches('0');
        let (int, frac) = s.split_once('.').unwrap_or((s, ""));
        !int.is_empty()
            && !int.starts_with('0')
            && int.len() <= DIGITS
            && all_digits(int)
            && all_digits(frac)
            && int.len() + significant(frac) <= DIGITS
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
            "0",
            "1.5",
            "0@0.25",
            "1@0.25",
            "0.5@0",
            "0.5@",
            "@0.2",
            "0.5@x",
            "x",
            "+0.5",
            "5e-1",
            "0.9999999",
            "0.5@1000000",
            "inf",
            "NaN",
            ".",
            "0.1234567",
        ] {
            let err = bad.parse::<RussianRoulette>().unwrap_err();
            assert!(err.contains(bad), "{bad}: {err}");
        }
    }

    /// Strings near the grammar: digits (zeros often), points, and now and then a sign, an
    /// exponent or a letter, from a fixed seed.
    fn near_decimals(n: usize) -> Vec<String> {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move |m: u64| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) % m
        };
        (0..n)
            .map(|_| {
                let len = 1 + next(14) as usize;
                (0..len)
                    .map(|_| match next(20) {
                        0..=5 => '0',
                        6..=8 => '.',
                        9 => ['+', '-', 'e', 'x'][next(4) as usize],
                        10 => '1',
                        11 => '9',
                        _ => char::from(b'0' + next(10) as u8),
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn the_roulette_numbers_match_their_regular_expressions() {
        use roulette_numbers::*;
        type Grammar = fn(&str) -> bool;
        let whole = |re: &str| regex::Regex::new(&format!("^({re})$")).unwrap();
        let checks: [(&str, regex::Regex, Grammar); 3] = [
            ("FRACTION", whole(FRACTION), is_fraction),
            ("PROBABILITY", whole(PROBABILITY), is_probability),
            ("THRESHOLD", whole(THRESHOLD), is_threshold),
        ];
        let mut accepted = [0; 3];
        for s in near_decimals(200_000) {
            for (i, (name, re, f)) in checks.iter().enumerate() {
                assert_eq!(re.is_match(&s), f(&s), "{name} on {s:?}");
                accepted[i] += usize::from(f(&s));
            }
        }
        // The inputs reach both sides of every grammar.
        assert!(accepted.iter().all(|&n| n > 1000), "{accepted:?}");
    }

    #[test]
    fn every_accepted_roulette_is_in_range_and_written_back_the_same() {
        let mut seen = 0;
        let near = near_decimals(100_000);
        let pairs = near.chunks(2).map(|p| format!("{}@{}", p[0], p[1]));
        for s in near.iter().cloned().chain(pairs) {
            let Ok(rr) = s.parse::<RussianRoulette>() else {
                continue;
            };
            seen += 1;
            match rr {
                RussianRoulette::Fixed(p) => assert!(p > 0.0 && p <= 1.0, "{s}: {p}"),
                RussianRoulette::Threshold { terminate, below } => assert!(
                    terminate > 0.0 && terminate < 1.0 && below > 0.0 && below < 1e6,
                    "{s}: {terminate}@{below}"
                ),
                other => panic!("{s} parsed as {other:?}"),
            }
            let written = rr.to_string();
            assert_eq!(
                written.parse::<RussianRoulette>(),
                Ok(rr),
                "{s} written {written}"
            );
        }
        assert!(seen > 1000, "{seen}");
    }
}
