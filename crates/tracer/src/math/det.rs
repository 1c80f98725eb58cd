//! Deterministic elementary functions: plain f32 multiply-adds (Rust never fuses them into FMA), so
//! they return the same bits on every CPU and every C library.
//!
//! Why: `f32::sin`, `exp`, … call the platform's libm, which on x86-64 glibc picks FMA or non-FMA
//! code at run time and on other platforms is a different implementation altogether. Workers on
//! different machines must render the same bits, so everything on the sample path (and everything
//! the scene loader derives that samples depend on) uses these instead. Accuracy is a few ULP, far
//! below Monte Carlo noise.

use std::f32::consts::{LN_2, LOG2_E, PI};

/// A nearest integer to `x` for |x| < 2³¹, without a call: on baseline x86-64 (no SSE4.1)
/// `f32::round` is a call into libm, and the samplers round on every direction. It is `x.round()`
/// except where x ± 0.5 itself rounds (e.g. 0.49999997 gives 1): the argument reductions that use
/// it only need an integer within a hair of the nearest, their polynomials stay accurate just past
/// the interval's ends. Deterministic, as everything here.
#[inline(always)]
fn round_to_int(x: f32) -> i64 {
    (x + 0.5f32.copysign(x)) as i64
}

/// The Taylor polynomials of (sin r, cos r) on [−π/4, π/4], truncation error < 1e-9.
#[inline(always)]
fn sin_cos_reduced(r: f32) -> (f32, f32) {
    let r2 = r * r;
    let s = r
        * (1.0
            + r2 * (-1.0 / 6.0
                + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0)))));
    let c = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40_320.0))));
    (s, c)
}

/// Rotates (sin r, cos r) by k quarter turns.
///
/// k mod 4 = 0, 1, 2, 3 gives (s, c), (c, −s), (−s, −c), (−c, s): a swap when k is odd, then sign
/// flips, done on the bits (flipping the sign bit is exactly negation). k comes from a random
/// angle, so a branch on it would be mispredicted on most calls.
#[inline(always)]
fn quarter_turns((s, c): (f32, f32), k: i64) -> (f32, f32) {
    let k = k as u32; // two's complement: the low two bits are k mod 4 for a negative k too
    let swap = 0u32.wrapping_sub(k & 1);
    let (sb, cb) = (s.to_bits(), c.to_bits());
    let first = (sb & !swap) | (cb & swap);
    let second = (cb & !swap) | (sb & swap);
    let sign_first = (k & 2) << 30;
    let sign_second = (k.wrapping_add(1) & 2) << 30;
    (
        f32::from_bits(first ^ sign_first),
        f32::from_bits(second ^ sign_second),
    )
}

/// (sin x, cos x) for |x| up to a few thousand radians.
#[inline]
pub fn sin_cos(x: f32) -> (f32, f32) {
    if !x.is_finite() {
        return (f32::NAN, f32::NAN);
    }
    let y = x * (2.0 / PI);
    if y.abs() >= 1e6 {
        let k = y.round() as i64;
        return quarter_turns(sin_cos_reduced(reduce(x, k)), k);
    }
    sin_cos_moderate(x)
}

/// [`sin_cos`] for |x| < 1.5 · 10⁶ (NaN for a NaN), its bits, without a branch: the form that
/// vectorises across lanes (`light::area`'s solid-angle samples).
#[inline(always)]
pub fn sin_cos_moderate(x: f32) -> (f32, f32) {
    // The quadrant as `round_to_int` gives it, in 32 bits (|k| < 10⁶: the same integer), which
    // converts in vector registers on AVX2 as well.
    let y = x * (2.0 / PI);
    let k = (y + 0.5f32.copysign(y)) as i32;
    quarter_turns(sin_cos_reduced(reduce(x, k as i64)), k as i64)
}

/// x − k · π/2, in double precision (still plain IEEE operations, so still deterministic): r ∈
/// [−π/4, π/4] for k the nearest multiple.
#[inline(always)]
fn reduce(x: f32, k: i64) -> f32 {
    (x as f64 - k as f64 * std::f64::consts::FRAC_PI_2) as f32
}

/// (sin 2πt, cos 2πt) for t ∈ [0, 1): the angle of a uniform random number, reduced exactly in
/// turns before converting to radians.
#[inline(always)]
pub fn sin_cos_turns(t: f32) -> (f32, f32) {
    if t.is_nan() || t.abs() >= 1e6 {
        return sin_cos(t * (2.0 * PI));
    }
    // Quarter turns: q = nearest quarter, f ∈ [−1/8, 1/8] of a turn, both exact in f32, so the
    // angle f · 2π is already within [−π/4, π/4].
    let q = round_to_int(t * 4.0);
    let f = t - q as f32 * 0.25;
    quarter_turns(sin_cos_reduced(f * (2.0 * PI)), q)
}

/// (sin x, cos x) for |x| ≤ π/4, the range of the reduced argument: no reduction, no quarter
/// turns, only the two polynomials. For callers whose angle is in that range by construction
/// (the concentric disk's wedges); outside it the error grows quickly.
#[inline]
pub fn sin_cos_quarter(x: f32) -> (f32, f32) {
    debug_assert!(x.is_nan() || x.abs() <= std::f32::consts::FRAC_PI_4 * 1.000_001);
    sin_cos_reduced(x)
}

/// tan x (via [`sin_cos`]).
#[inline]
pub fn tan(x: f32) -> f32 {
    let (s, c) = sin_cos(x);
    s / c
}

/// cos x (via [`sin_cos`]).
#[inline]
pub fn cos(x: f32) -> f32 {
    sin_cos(x).1
}

/// eˣ. Underflows to 0 below −87.3, overflows to +∞ above 88.7.
#[inline]
pub fn exp(x: f32) -> f32 {
    if x.is_nan() {
        return x;
    }
    if x < -87.3 {
        return 0.0;
    }
    if x > 88.7 {
        return f32::INFINITY;
    }
    // eˣ = 2ⁿ · eʳ with n = round(x / ln 2) and r ∈ [−ln2/2, ln2/2].
    let n = round_to_int(x * LOG2_E) as f32;
    const LN2_HI: f32 = 0.693_145_75; // exact product with small n
    const LN2_LO: f32 = LN_2 - LN2_HI;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    // Taylor to degree 7: error < 2e-9 relative on the interval.
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0
                        + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    let n = n as i32;
    // Scale by 2ⁿ in two steps so that n down to −126 − 24 stays representable.
    let half = n / 2;
    p * f32::from_bits(((half + 127) as u32) << 23)
        * f32::from_bits(((n - half + 127) as u32) << 23)
}

/// Natural logarithm of x > 0 (NaN for x < 0, −∞ at 0).
#[inline]
pub fn ln(x: f32) -> f32 {
    if x.is_nan() || x < 0.0 {
        return f32::NAN;
    }
    if x == 0.0 {
        return f32::NEG_INFINITY;
    }
    if x.is_infinite() {
        return x;
    }
    // Normalise subnormals, then x = m · 2ᵉ with m ∈ [√½, √2).
    let (x, bias) = if x < f32::MIN_POSITIVE {
        (x * 16_777_216.0, -24)
    } else {
        (x, 0)
    };
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127 + bias;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    if m > std::f32::consts::SQRT_2 {
        m *= 0.5;
        e += 1;
    }
    // ln m = 2 atanh(s), s = (m − 1)/(m + 1) ∈ (−0.172, 0.172): odd series to s¹¹.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let atanh = s
        * (1.0
            + s2 * (1.0 / 3.0
                + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0 + s2 * (1.0 / 11.0))))));
    2.0 * atanh + e as f32 * LN_2
}

/// atan x for x ≥ 0: Cephes' `atanf` (range reduced to [0, tan π/8], then its degree-9 odd
/// polynomial; relative error about 2e-7). Without branches: one division whichever the range
/// (x / 1 is x exactly), so that it vectorises.
#[inline(always)]
fn atan_nonnegative(x: f32) -> f32 {
    const TAN_3PI_8: f32 = 2.414_213_6;
    const TAN_PI_8: f32 = 0.414_213_57;
    let (big, mid) = (x > TAN_3PI_8, x > TAN_PI_8);
    let select = |c: bool, a: f32, b: f32| if c { a } else { b };
    let base = select(
        big,
        std::f32::consts::FRAC_PI_2,
        select(mid, std::f32::consts::FRAC_PI_4, 0.0),
    );
    let num = select(big, -1.0, select(mid, x - 1.0, x));
    let den = select(big, x, select(mid, x + 1.0, 1.0));
    let t = num / den;
    let z = t * t;
    let p = (((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z - 3.333_295e-1) * z;
    base + (p * t + t)
}

/// atan2(y, x): the angle of (x, y) in (−π, π], 0 for (0, 0). Used to map directions to
/// environment-map texels, which must be the same texels on every machine, and for solid angles.
/// Without branches, so that it vectorises across lanes.
#[inline(always)]
pub fn atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    // The angle in the first quadrant, from the smaller ratio for accuracy.
    let flat = ay <= ax; // false for a NaN, as the branch it replaces had it
    let (num, den) = if flat { (ay, ax) } else { (ax, ay) };
    let t = atan_nonnegative(num / den);
    let a = if flat {
        t
    } else {
        std::f32::consts::FRAC_PI_2 - t
    };
    let a = if x < 0.0 { PI - a } else { a };
    let a = if y < 0.0 { -a } else { a };
    if ax == 0.0 && ay == 0.0 {
        0.0
    } else {
        a
    }
}

/// arccos x in radians, for x ∈ [−1, 1] (NaN outside), computed in `f64` and rounded once: it
/// agrees with `(x as f64).acos() as f32` (what the MikkTSpace reference computes, through the C
/// library's `acos` in double precision) except where that result lies within a rounding error of
/// the half-way point between two floats; measured: identical bits on every one of the 2²⁰ evenly
/// spaced arguments of the test, and at most 1 ulp apart anywhere.
///
/// The method is fdlibm's (`e_acos.c`, as musl and Rust's `libm` have it): a rational
/// approximation of asin on |x| < ½, and the half-angle identity acos x = 2 asin √((1 − x)/2)
/// beyond, its error below 1 ulp of `f64`. Only IEEE operations and `f64::sqrt` (correctly rounded
/// by IEEE 754, one instruction on x86-64 and AArch64): the same bits everywhere. Used by the
/// MikkTSpace tangents at load time (`gltf::tangents`), not on the sample path.
pub fn acos(x: f32) -> f32 {
    acos_f64(x as f64) as f32
}

fn acos_f64(x: f64) -> f64 {
    const PIO2_HI: f64 = std::f64::consts::FRAC_PI_2; // π/2 rounded to f64
    const PIO2_LO: f64 = 6.123233995736766e-17; // π/2 − PIO2_HI

    // asin(√z)/√z − 1 ≈ z · P(z)/Q(z) on [0, ¼] (fdlibm's coefficients).
    fn r(z: f64) -> f64 {
        const PS0: f64 = 0.16666666666666666;
        const PS1: f64 = -0.3255658186224009;
        const PS2: f64 = 0.20121253213486293;
        const PS3: f64 = -0.04005553450067941;
        const PS4: f64 = 0.0007915349942898145;
        const PS5: f64 = 3.479331075960212e-5;
        const QS1: f64 = -2.403394911734414;
        const QS2: f64 = 2.0209457602335057;
        const QS3: f64 = -0.6882839716054533;
        const QS4: f64 = 0.07703815055590194;
        let p = z * (PS0 + z * (PS1 + z * (PS2 + z * (PS3 + z * (PS4 + z * PS5)))));
        let q = 1.0 + z * (QS1 + z * (QS2 + z * (QS3 + z * QS4)));
        p / q
    }
    if x.is_nan() || x.abs() > 1.0 {
        return f64::NAN;
    }
    if x == 1.0 {
        return 0.0;
    }
    if x == -1.0 {
        return 2.0 * PIO2_HI + 2.0 * PIO2_LO;
    }
    if x.abs() < 0.5 {
        // π/2 − asin x, asin x = x + x·r(x²).
        return PIO2_HI - (x - (PIO2_LO - x * r(x * x)));
    }
    if x < 0.0 {
        // acos x = π − 2 asin √((1 + x)/2).
        let z = (1.0 + x) * 0.5;
        let s = z.sqrt();
        let w = r(z) * s - PIO2_LO;
        return 2.0 * (PIO2_HI - (s + w));
    }
    // acos x = 2 asin √((1 − x)/2), with √ split into a 32-bit head and a correction so that the
    // small result keeps full relative precision.
    let z = (1.0 - x) * 0.5;
    let s = z.sqrt();
    let df = f64::from_bits(s.to_bits() & 0xffff_ffff_0000_0000);
    let c = (z - df * df) / (s + df);
    let w = r(z) * s + c;
    2.0 * (df + w)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAC_PI_2_F32: f32 = std::f32::consts::FRAC_PI_2;

    #[test]
    fn atan2_is_accurate_in_every_quadrant() {
        let mut worst = 0.0f64;
        let n = 2000;
        for i in 0..n {
            // Angles all round the circle, and radii from tiny to huge.
            let phi =
                -std::f64::consts::PI + 2.0 * std::f64::consts::PI * (i as f64 + 0.37) / n as f64;
            for r in [1e-20f64, 1e-3, 1.0, 7.5, 1e6, 1e30] {
                let (x, y) = ((r * phi.cos()) as f32, (r * phi.sin()) as f32);
                let want = (y as f64).atan2(x as f64);
                let got = atan2(y, x) as f64;
                worst = worst.max((got - want).abs());
            }
        }
        assert!(worst < 5e-7, "worst error {worst} rad");
        assert_eq!(atan2(0.0, 0.0), 0.0);
        assert_eq!(atan2(0.0, 1.0), 0.0);
        assert!((atan2(0.0, -1.0) - PI).abs() < 1e-6);
        assert!((atan2(1.0, 0.0) - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((atan2(-1.0, 0.0) + std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!(atan2(f32::NAN, 1.0).is_nan());
    }

    /// The branch-free forms the lanes vectorise give the bits of the branching forms they
    /// replaced (arctangent) or that callers outside the lanes take (sine and cosine).
    #[test]
    fn branch_free_forms_give_the_branching_bits() {
        fn atan2_branching(y: f32, x: f32) -> f32 {
            let (ax, ay) = (x.abs(), y.abs());
            if ax == 0.0 && ay == 0.0 {
                return 0.0;
            }
            let atan = |x: f32| {
                let (base, t) = if x > 2.414_213_6 {
                    (std::f32::consts::FRAC_PI_2, -1.0 / x)
                } else if x > 0.414_213_57 {
                    (std::f32::consts::FRAC_PI_4, (x - 1.0) / (x + 1.0))
                } else {
                    (0.0, x)
                };
                let z = t * t;
                let p = (((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z
                    - 3.333_295e-1)
                    * z;
                base + (p * t + t)
            };
            let a = if ay <= ax {
                atan(ay / ax)
            } else {
                std::f32::consts::FRAC_PI_2 - atan(ax / ay)
            };
            let a = if x < 0.0 { PI - a } else { a };
            if y < 0.0 {
                -a
            } else {
                a
            }
        }
        let mut bits = 0x2545_f491_u32;
        let mut next = || {
            bits ^= bits << 13;
            bits ^= bits >> 17;
            bits ^= bits << 5;
            bits
        };
        let specials = [
            0.0f32,
            -0.0,
            1.0,
            -1.0,
            f32::INFINITY,
            f32::NAN,
            2.414_213_6,
        ];
        for i in 0..200_000 {
            let (y, x) = if i < specials.len().pow(2) {
                (specials[i / specials.len()], specials[i % specials.len()])
            } else {
                let scale =
                    |b: u32| (b as f32 / u32::MAX as f32 - 0.5) * 10f32.powi((b % 9) as i32 - 4);
                (scale(next()), scale(next()))
            };
            let (got, want) = (atan2(y, x), atan2_branching(y, x));
            assert!(
                got.to_bits() == want.to_bits() || got.is_nan() && want.is_nan(),
                "atan2({y}, {x})"
            );
        }
        for i in 0..200_000 {
            // Across the whole range, and beside the half-way points between quadrants.
            let x = match i % 2 {
                0 => (next() as f32 / u32::MAX as f32 - 0.5) * 3.0e6,
                _ => {
                    let k = (next() % 2_000_001) as f32 - 1_000_000.0;
                    f32::from_bits(
                        ((k + 0.5) * FRAC_PI_2_F32)
                            .to_bits()
                            .wrapping_add(next() % 5)
                            .wrapping_sub(2),
                    )
                }
            };
            if (x * (2.0 / PI)).abs() >= 1e6 {
                continue;
            }
            let (got, want) = (sin_cos_moderate(x), sin_cos(x));
            assert_eq!(
                (got.0.to_bits(), got.1.to_bits()),
                (want.0.to_bits(), want.1.to_bits()),
                "{x}"
            );
        }
        assert!(sin_cos_moderate(f32::NAN).0.is_nan());
    }

    #[test]
    fn quarter_turns_are_the_rotations() {
        for (s, c) in [(0.25f32, -0.0f32), (-0.75, 0.5), (0.0, 1.0)] {
            for k in -9i64..9 {
                let want = match k.rem_euclid(4) {
                    0 => (s, c),
                    1 => (c, -s),
                    2 => (-s, -c),
                    _ => (-c, s),
                };
                let got = quarter_turns((s, c), k);
                assert_eq!(
                    (got.0.to_bits(), got.1.to_bits()),
                    (want.0.to_bits(), want.1.to_bits()),
                    "k = {k}"
                );
            }
        }
    }

    #[test]
    fn sin_cos_matches_libm() {
        let mut worst: f32 = 0.0;
        for i in -20_000..=20_000 {
            let x = i as f32 * 0.001_3;
            let (s, c) = sin_cos(x);
            worst = worst.max((s - x.sin()).abs()).max((c - x.cos()).abs());
        }
        assert!(worst < 5e-7, "worst error {worst}");
        for i in 0..10_000 {
            let t = i as f32 / 10_000.0;
            let (s, c) = sin_cos_turns(t);
            let a = (t as f64) * std::f64::consts::TAU;
            assert!(
                (s as f64 - a.sin()).abs() < 4e-7 && (c as f64 - a.cos()).abs() < 4e-7,
                "t = {t}"
            );
        }
        assert!((tan(0.3) - 0.3f32.tan()).abs() < 1e-6);
        for i in -10_000..=10_000 {
            let x = i as f32 / 10_000.0 * std::f32::consts::FRAC_PI_4;
            let (s, c) = sin_cos_quarter(x);
            let a = x as f64;
            assert!(
                (s as f64 - a.sin()).abs() < 2e-7 && (c as f64 - a.cos()).abs() < 2e-7,
                "x = {x}"
            );
        }
    }

    /// The call-free rounding is off by one only right beside the half-way points; the reductions
    /// stay accurate there, at the quarter-turn boundaries and far from zero.
    #[test]
    fn reductions_hold_at_their_boundaries() {
        for q in 0..8u32 {
            let eighth = q as f32 * 0.125;
            let mut t = eighth;
            for _ in 0..8 {
                t = f32::from_bits(t.to_bits().saturating_sub(1));
            }
            for _ in 0..16 {
                let (s, c) = sin_cos_turns(t);
                let a = (t as f64) * std::f64::consts::TAU;
                assert!(
                    (s as f64 - a.sin()).abs() < 4e-7 && (c as f64 - a.cos()).abs() < 4e-7,
                    "t = {t:e}"
                );
                t = f32::from_bits(t.to_bits() + 1);
            }
        }
        assert_eq!(round_to_int(2.5), 3);
        assert_eq!(round_to_int(-2.5), -3);
        assert_eq!(round_to_int(0.49999997), 1); // documented: x + 0.5 rounds up to 1
        for x in [1e7f32, -3.3e6, 12_345.678] {
            let (s, c) = sin_cos(x);
            let (ws, wc) = (x as f64).sin_cos();
            assert!(
                (s as f64 - ws).abs() < 1e-3 && (c as f64 - wc).abs() < 1e-3,
                "{x}"
            );
        }
        assert!(sin_cos(f32::NAN).0.is_nan() && sin_cos_turns(f32::INFINITY).1.is_nan());
    }

    #[test]
    fn exp_and_ln_match_libm() {
        for i in -8700..=8800 {
            let x = i as f32 * 0.01;
            let rel = (exp(x) as f64 / (x as f64).exp() - 1.0).abs();
            assert!(rel < 1e-6, "exp({x}): rel {rel}");
        }
        assert_eq!(exp(-100.0), 0.0);
        assert_eq!(exp(0.0), 1.0);
        for i in 1..10_000 {
            let x = i as f32 * 0.37e-3 * (i as f32);
            assert!(
                (ln(x) as f64 - (x as f64).ln()).abs() < 1e-6 * (1.0 + (x as f64).ln().abs()),
                "ln({x})"
            );
        }
        assert!((ln(1e-40) as f64 - (1e-40f64).ln()).abs() < 1e-4);
        assert!(ln(-1.0).is_nan());
    }

    /// Against the platform's double-precision acos rounded to f32 (what the MikkTSpace reference
    /// uses): the same bits on 2²⁰ + 1 evenly spaced arguments and the ends, and within 1 ulp on
    /// arguments spread over every binade near ±1 and 0.
    #[test]
    fn acos_matches_double_precision_libm() {
        let n = 1 << 20;
        let mut differ = 0;
        for i in 0..=n {
            let x = -1.0 + 2.0 * (i as f32 / n as f32);
            let (got, want) = (acos(x), (x as f64).acos() as f32);
            differ += (got.to_bits() != want.to_bits()) as u32;
            assert!(
                (got.to_bits() as i64 - want.to_bits() as i64).abs() <= 1,
                "acos({x:e}) = {got:e}, libm {want:e}"
            );
        }
        assert_eq!(
            differ, 0,
            "{differ} of {n} arguments differ from libm in the last bit"
        );
        // Near ±1 (where the half-angle branch matters) and near 0, every few thousandth float.
        for start in [1.0f32, -1.0, 0.5, -0.5, 1e-3, -1e-3] {
            let mut bits = start.to_bits();
            for _ in 0..20_000 {
                let x = f32::from_bits(bits);
                let (got, want) = (acos(x), (x as f64).acos() as f32);
                assert!(
                    (got.to_bits() as i64 - want.to_bits() as i64).abs() <= 1,
                    "acos({x:e}) = {got:e}, libm {want:e}"
                );
                bits -= 97;
            }
        }
        assert_eq!(acos(1.0), 0.0);
        assert_eq!(acos(-1.0), std::f32::consts::PI);
        assert_eq!(acos(0.0), std::f32::consts::FRAC_PI_2);
        assert!(acos(1.0000001).is_nan() && acos(f32::NAN).is_nan());
    }
}
