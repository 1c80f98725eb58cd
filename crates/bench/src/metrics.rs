//! Error measures of an image against a reference, and the fitted convergence slope.

use crate::reference::{luminance, Reference};
use pathfarm_tracer::Accumulation;
use serde::{Deserialize, Serialize};

/// The ε of the relative MSE, (x − r)² / (r² + ε): keeps black pixels from dominating.
pub const REL_MSE_EPSILON: f64 = 0.01;

/// How far an image is from the reference, on luminance.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct ErrorMeasures {
    /// Mean squared error with the reference's own noise taken out (never below 0).
    pub mse: f64,
    /// The MSE as measured, reference noise included.
    pub mse_raw: f64,
    /// √mse.
    pub rmse: f64,
    /// RMSE as a fraction of the reference's mean.
    pub rel_rmse: f64,
    /// Mean of (x − r)² / (r² + ε), reference noise taken out.
    pub rel_mse: f64,
    /// The image's mean luminance.
    pub mean: f64,
    /// Its standard error, from the per-pixel sample variances.
    pub mean_se: f64,
    /// (mean − reference mean) / combined standard error; 0 when neither has an error estimate.
    pub mean_z: f64,
}

/// Measures `acc` against `reference` (same size).
pub fn measure(acc: &Accumulation, reference: &Reference) -> ErrorMeasures {
    let n = acc.pixels.len().max(1) as f64;
    let (mut se, mut rel, mut rel_noise, mut sum, mut var_sum) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, p) in acc.pixels.iter().enumerate() {
        let x = luminance(p.mean());
        let r = reference.luminance[i];
        let d = x - r;
        se += d * d;
        rel += d * d / (r * r + REL_MSE_EPSILON);
        rel_noise += reference.variance[i] / (r * r + REL_MSE_EPSILON);
        sum += x;
        var_sum += p.variance_of_mean().unwrap_or(0.0);
    }
    let mse_raw = se / n;
    let mse = (mse_raw - reference.noise_mse()).max(0.0);
    let ref_mean = reference.mean();
    let mean = sum / n;
    let mean_se = var_sum.sqrt() / n;
    let combined = (mean_se * mean_se + reference.mean_standard_error().powi(2)).sqrt();
    ErrorMeasures {
        mse,
        mse_raw,
        rmse: mse.sqrt(),
        rel_rmse: if ref_mean > 0.0 {
            mse.sqrt() / ref_mean
        } else {
            0.0
        },
        rel_mse: ((rel - rel_noise) / n).max(0.0),
        mean,
        mean_se,
        mean_z: if combined > 0.0 {
            (mean - ref_mean) / combined
        } else {
            0.0
        },
    }
}

/// Least-squares slope of ln y against ln x over the points with both positive and finite;
/// `None` with fewer than three such points. For Monte Carlo error against time (or samples) it
/// is −1/2; randomized quasi-Monte Carlo can do better on smooth integrands.
pub fn log_log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn slope_of_a_power_law_is_its_exponent() {
        let pts: Vec<(f64, f64)> = (1..8)
            .map(|k| (k as f64, 3.0 * (k as f64).powf(-0.5)))
            .collect();
        assert!((log_log_slope(&pts).unwrap() + 0.5).abs() < 1e-12);
        assert!(log_log_slope(&pts[..2]).is_none());
        assert!(log_log_slope(&[(1.0, 0.0), (2.0, 0.0), (3.0, 1.0)]).is_none());
    }

    #[test]
    fn measures_against_an_exact_reference() {
        let mut acc = Accumulation::new(0, 0, 2, 1);
        // Pixel 0: samples 1 and 3 (mean 2, exact). Pixel 1: 2 and 4 (mean 3, error 1).
        for (i, vals) in [[1.0f32, 3.0], [2.0, 4.0]].iter().enumerate() {
            for v in vals {
                acc.pixels[i].add_sample(Vec3::splat(*v));
            }
        }
        let reference = Reference {
            luminance: vec![2.0, 2.0],
            variance: vec![0.0, 0.0],
            exact: true,
            spp: 0,
            render_seconds: 0.0,
            cached: false,
            width: 2,
            height: 1,
        };
        let m = measure(&acc, &reference);
        assert!((m.mse - 0.5).abs() < 1e-9, "{m:?}");
        assert!((m.rel_rmse - 0.5f64.sqrt() / 2.0).abs() < 1e-9);
        assert!((m.mean - 2.5).abs() < 1e-9);
        // Each pixel: sample variance 2, variance of the mean 1; SE of the image mean √2 / 2.
        assert!((m.mean_se - 2f64.sqrt() / 2.0).abs() < 1e-6, "{m:?}");
        assert!((m.mean_z - 0.5 / (2f64.sqrt() / 2.0)).abs() < 1e-5);
        // A noisy reference: its noise is taken out of the MSE.
        let noisy = Reference {
            variance: vec![0.1, 0.1],
            exact: false,
            ..reference
        };
        assert!((measure(&acc, &noisy).mse - 0.4).abs() < 1e-9);
    }
}
