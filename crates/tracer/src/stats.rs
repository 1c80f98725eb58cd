//! Statistics used to *test* the renderer: Pearson's chi-square goodness-of-fit test for sampling
//! routines, and histogram helpers over the unit sphere. Public because tests, benches and the
//! `pathfarm bench` report all use them; nothing on the rendering path does.

use glam::Vec3;
use std::f64::consts::PI;

/// Outcome of a chi-square goodness-of-fit test.
#[derive(Clone, Copy, Debug)]
pub struct ChiSquare {
    /// Pearson's statistic Σ (O − E)² / E over the pooled bins.
    pub statistic: f64,
    /// Degrees of freedom (pooled bins − 1).
    pub dof: usize,
    /// Probability of a statistic at least this large if the samples follow the expected law.
    pub p_value: f64,
}

/// Pearson's chi-square test of `observed` counts against `expected` counts (same binning, the
/// expected counts summing to the number of samples that *should* have been drawn).
///
/// Bins whose expected count is below `min_expected` are pooled together (sorted by expectation, as in
/// Mitsuba's `ChiSquareTest`), so that the chi-square approximation holds. A bin with zero expected
/// count but observed samples is an immediate failure (p = 0): the sampler produced something its pdf
/// says is impossible.
pub fn chi_square_test(observed: &[f64], expected: &[f64], min_expected: f64) -> ChiSquare {
    assert_eq!(observed.len(), expected.len(), "histograms differ in size");
    let mut order: Vec<usize> = (0..expected.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let mut statistic = 0.0;
    let mut bins = 0usize;
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for &i in &order {
        if expected[i] <= 0.0 {
            if observed[i] > 0.0 {
                return ChiSquare {
                    statistic: f64::INFINITY,
                    dof: 0,
                    p_value: 0.0,
                };
            }
            continue;
        }
        if expected[i] < min_expected {
            pool_o += observed[i];
            pool_e += expected[i];
            if pool_e >= min_expected {
                statistic += (pool_o - pool_e).powi(2) / pool_e;
                bins += 1;
                pool_o = 0.0;
                pool_e = 0.0;
            }
        } else {
            statistic += (observed[i] - expected[i]).powi(2) / expected[i];
            bins += 1;
        }
    }
    if pool_e > 0.0 {
        statistic += (pool_o - pool_e).powi(2) / pool_e;
        bins += 1;
    }
    let dof = bins.saturating_sub(1).max(1);
    ChiSquare {
        statistic,
        dof,
        p_value: chi_square_sf(statistic, dof as f64),
    }
}

/// Survival function of the chi-square distribution with `k` degrees of freedom: Q(k/2, x/2).
pub fn chi_square_sf(x: f64, k: f64) -> f64 {
    if !x.is_finite() {
        return 0.0;
    }
    if x <= 0.0 {
        return 1.0;
    }
    regularized_gamma_q(0.5 * k, 0.5 * x)
}

/// Upper regularized incomplete gamma function Q(a, x) (Numerical Recipes: series for x < a + 1,
/// continued fraction otherwise).
pub fn regularized_gamma_q(a: f64, x: f64) -> f64 {
    if x < a + 1.0 {
        let mut sum = 1.0 / a;
        let mut term = sum;
        let mut n = a;
        for _ in 0..10_000 {
            n += 1.0;
            term *= x / n;
            sum += term;
            if term.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        let p = sum * (-x + a * x.ln() - ln_gamma(a)).exp();
        (1.0 - p).clamp(0.0, 1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        ((-x + a * x.ln() - ln_gamma(a)).exp() * h).clamp(0.0, 1.0)
    }
}

/// ln Γ(x) for x > 0 (Lanczos approximation, g = 7, n = 9).
pub fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// A histogram over the unit sphere with `n_theta` bins in cos θ (equal solid angle each) and `n_phi`
/// bins in φ. Directions are in the local frame (z up).
#[derive(Clone, Copy, Debug)]
pub struct SphereBins {
    pub n_theta: usize,
    pub n_phi: usize,
}

impl SphereBins {
    pub fn len(&self) -> usize {
        self.n_theta * self.n_phi
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The bin of direction `w` (need not be normalized exactly).
    pub fn bin(&self, w: Vec3) -> usize {
        let w = w.as_dvec3().normalize();
        let t = ((1.0 - w.z.clamp(-1.0, 1.0)) * 0.5 * self.n_theta as f64) as usize;
        let mut phi = w.y.atan2(w.x);
        if phi < 0.0 {
            phi += 2.0 * PI;
        }
        let p = (phi / (2.0 * PI) * self.n_phi as f64) as usize;
        t.min(self.n_theta - 1) * self.n_phi + p.min(self.n_phi - 1)
    }

    /// ∫ pdf dω over every bin, by the midpoint rule on `sub × sub` cells per bin (in cos θ and φ,
    /// where dω = d(cos θ) dφ, so the rule has no Jacobian).
    pub fn integrate(&self, pdf: impl Fn(Vec3) -> f64, sub: usize) -> Vec<f64> {
        let mut out = vec![0.0; self.len()];
        let dz = 2.0 / (self.n_theta * sub) as f64;
        let dphi = 2.0 * PI / (self.n_phi * sub) as f64;
        for t in 0..self.n_theta {
            for p in 0..self.n_phi {
                let mut acc = 0.0;
                for i in 0..sub {
                    let z = 1.0 - (t * sub + i) as f64 * dz - 0.5 * dz;
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    for j in 0..sub {
                        let phi = (p * sub + j) as f64 * dphi + 0.5 * dphi;
                        let w = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
                        acc += pdf(w);
                    }
                }
                out[t * self.n_phi + p] = acc * dz * dphi;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi_square_sf_matches_tables() {
        // Critical values from standard tables: P(X > x) for k dof.
        assert!((chi_square_sf(3.841, 1.0) - 0.05).abs() < 1e-3);
        assert!((chi_square_sf(18.307, 10.0) - 0.05).abs() < 1e-3);
        assert!((chi_square_sf(124.342, 100.0) - 0.05).abs() < 1e-3);
        assert!((chi_square_sf(2.0, 2.0) - (-1.0f64).exp()).abs() < 1e-9);
    }

    #[test]
    fn sphere_bins_integrate_a_uniform_pdf_to_one() {
        let bins = SphereBins {
            n_theta: 10,
            n_phi: 20,
        };
        let e = bins.integrate(|_| 1.0 / (4.0 * PI), 2);
        assert!((e.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        assert_eq!(bins.bin(Vec3::Z), 0);
        assert_eq!(bins.bin(-Vec3::Z) / bins.n_phi, 9);
    }

    #[test]
    fn chi_square_rejects_a_wrong_law() {
        let expected = vec![100.0; 10];
        let mut observed = vec![100.0; 10];
        observed[0] = 160.0;
        observed[1] = 40.0;
        assert!(chi_square_test(&observed, &expected, 5.0).p_value < 1e-6);
        assert!(chi_square_test(&expected, &expected, 5.0).p_value > 0.99);
    }
}
