//! The guide's directions and its mixture with the BSDF: bins of equal solid angle that the
//! sampling inverts, a density that integrates to one and matches the samples, and a mixture
//! whose weights estimate the BSDF's integral without bias.

use super::*;
use crate::bsdf::{Bsdf, PbrParams};
use crate::sampling::sample_uniform_sphere;
use crate::testing::uniform_stream;

/// A cell's bins from (bin, weight) pairs, as `photons::fill` makes them (by bin).
fn cell_bins(weights: &[(u16, f32)]) -> Vec<(u16, f32)> {
    let mut weights = weights.to_vec();
    weights.sort_by_key(|w| w.0);
    let total: f32 = weights.iter().map(|w| w.1).sum();
    let mut running = 0.0;
    let mut out: Vec<(u16, f32)> = weights
        .iter()
        .map(|&(b, w)| {
            running += w;
            (b, running / total)
        })
        .collect();
    out.last_mut().expect("bins").1 = 1.0;
    out
}

#[test]
fn a_direction_drawn_in_a_bin_falls_in_that_bin() {
    let mut rng = uniform_stream(3);
    for bin in 0..BINS {
        for _ in 0..8 {
            // Away from the bin's edges, where rounding may go either way.
            let u = Vec2::new(0.02 + 0.96 * rng(), 0.02 + 0.96 * rng());
            let w = direction_in(bin, u);
            assert!((w.length() - 1.0).abs() < 1e-5, "{w}");
            assert_eq!(bin_of(w), bin, "{w} from {u}");
        }
    }
}

#[test]
fn the_bins_have_equal_solid_angles() {
    // Uniform directions fall in every bin equally often: counts within 5σ of n / BINS.
    let mut rng = uniform_stream(5);
    let n = 400 * BINS;
    let mut counts = vec![0u32; BINS];
    for _ in 0..n {
        counts[bin_of(sample_uniform_sphere(Vec2::new(rng(), rng())))] += 1;
    }
    let expected = (n / BINS) as f64;
    for (bin, &c) in counts.iter().enumerate() {
        assert!(
            (f64::from(c) - expected).abs() < 5.0 * expected.sqrt(),
            "bin {bin}: {c} against {expected}"
        );
    }
}

#[test]
fn a_cell_density_integrates_to_one_and_matches_its_samples() {
    let bins = cell_bins(&[(7, 1.0), (200, 3.0), (201, 0.5), (400, 2.0)]);
    let occupied = Occupancy::of(&bins);
    let cell = GuideCell {
        bins: &bins,
        occupied: &occupied,
    };
    let mut rng = uniform_stream(9);
    // ∫ pdf dω by uniform directions.
    let n = 400_000;
    let mut sum = 0.0f64;
    for _ in 0..n {
        let w = sample_uniform_sphere(Vec2::new(rng(), rng()));
        sum += f64::from(cell.pdf(w)) * 4.0 * std::f64::consts::PI;
    }
    let integral = sum / f64::from(n);
    assert!((integral - 1.0).abs() < 0.02, "∫ pdf = {integral}");
    // Samples fall in the bins in proportion to their probabilities.
    // (A direction drawn within a float's rounding of its bin's edge may be binned next door,
    // as in any warp whose inverse is computed apart: a handful in a million.)
    let draws = 200_000;
    let mut counts = std::collections::BTreeMap::new();
    let mut outside = 0;
    for _ in 0..draws {
        let w = cell.sample(rng(), Vec2::new(rng(), rng()));
        outside += u32::from(cell.pdf(w) == 0.0);
        *counts.entry(bin_of(w) as u16).or_insert(0u32) += 1;
    }
    assert!(
        outside < 20,
        "{outside} of {draws} drawn outside the cell's bins"
    );
    let mut below = 0.0;
    for &(bin, cdf) in &bins {
        let p = f64::from(cdf - below);
        below = cdf;
        let expected = p * f64::from(draws);
        let got = f64::from(counts.get(&bin).copied().unwrap_or(0));
        let sigma = (expected * (1.0 - p)).sqrt();
        assert!(
            (got - expected).abs() < 5.0 * sigma,
            "bin {bin}: {got} against {expected}"
        );
    }
    let stray: u32 = counts
        .iter()
        .filter(|(b, _)| !bins.iter().any(|(c, _)| c == *b))
        .map(|(_, n)| n)
        .sum();
    assert!(stray < 20, "{stray} drawn in bins the cell does not have");
}

/// The mean of the mixture's weights against the BSDF's own: both estimate ∫ f |cos| dω, which
/// for a Lambertian of albedo a is a.
#[test]
fn the_mixture_estimates_the_bsdf_integral_without_bias() {
    let albedo = Vec3::new(0.8, 0.5, 0.2);
    let n_up = Vec3::new(0.3, -0.2, 1.0).normalize();
    let bsdf = Bsdf::new(PbrParams::diffuse(albedo), n_up, n_up, None);
    let wo = Vec3::new(-0.4, 0.1, 0.9).normalize();
    // Bins above and below the surface (a guide may point where the BSDF sends nothing).
    let bins = cell_bins(&[
        (bin_of(Vec3::Z) as u16, 2.0),
        (bin_of(Vec3::new(0.6, 0.0, 0.8)) as u16, 1.0),
        (bin_of(-Vec3::Z) as u16, 1.0),
    ]);
    let occupied = Occupancy::of(&bins);
    let cell = GuideCell {
        bins: &bins,
        occupied: &occupied,
    };
    let mut rng = uniform_stream(13);
    let n = 400_000;
    let (mut sum, mut sum2, mut guided) = (0.0f64, 0.0f64, 0u32);
    for _ in 0..n {
        let u_mix = rng();
        guided += u32::from(u_mix < MIX);
        let w = match cell.sample_mixture(&bsdf, wo, n_up, u_mix, Vec2::new(rng(), rng())) {
            Some(bs) => {
                assert!(!bs.delta && bs.pdf > 0.0);
                // The sample's density and weight against the BSDF evaluated there: equal but
                // for rounding, which near grazing angles (cos θ ~ 1e-3, where sampling and
                // evaluation compute the cosine differently) reaches 1e-5 of the value.
                let (f, pdf) = bsdf.eval_pdf(wo, bs.wi);
                let mix = cell.mix_pdf(pdf, bs.wi);
                assert!(
                    (mix - bs.pdf).abs() <= 1e-3 * bs.pdf,
                    "{bs:?}: mixture {mix}"
                );
                let want = f / bs.pdf;
                let off = (bs.weight - want).abs().max_element();
                assert!(off <= 1e-3 * want.max_element(), "{bs:?}: weight {want}");
                f64::from(bs.weight.x)
            }
            None => 0.0,
        };
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / f64::from(n);
    let stderr = ((sum2 / f64::from(n) - mean * mean) / f64::from(n)).sqrt();
    assert!(
        (mean - f64::from(albedo.x)).abs() < 4.0 * stderr + 1e-4,
        "mean weight {mean} ± {stderr} against the albedo {}",
        albedo.x
    );
    let share = f64::from(guided) / f64::from(n);
    assert!(
        (share - f64::from(MIX)).abs() < 0.01,
        "guided share {share}"
    );
}

/// A delta lobe drawn through the mixture keeps its direction; its weight and probability carry
/// the BSDF's share of the mixture.
#[test]
fn a_delta_lobe_keeps_its_direction_and_carries_the_bsdf_share() {
    let mirror = Bsdf::new(
        PbrParams {
            metallic: 1.0,
            roughness: 0.0,
            ..PbrParams::diffuse(Vec3::splat(0.9))
        },
        Vec3::Z,
        Vec3::Z,
        None,
    );
    let bins = cell_bins(&[(bin_of(Vec3::Z) as u16, 1.0)]);
    let occupied = Occupancy::of(&bins);
    let cell = GuideCell {
        bins: &bins,
        occupied: &occupied,
    };
    let wo = Vec3::new(0.6, 0.0, 0.8);
    let plain = mirror
        .sample(wo, 0.5, Vec2::new(0.3, 0.7))
        .expect("a mirror reflects");
    assert!(plain.delta);
    // Past the guide's share: the BSDF's branch.
    let mixed = cell
        .sample_mixture(&mirror, wo, Vec3::Z, 0.5 + 0.5 * MIX, Vec2::new(0.3, 0.7))
        .expect("a mirror reflects");
    assert!(mixed.delta);
    assert_eq!(mixed.wi, plain.wi);
    assert!(
        (mixed.weight - plain.weight / (1.0 - MIX))
            .abs()
            .max_element()
            < 1e-6
    );
    // The guide's branch finds nothing a mirror reflects: f = 0 there.
    let guided = cell.sample_mixture(&mirror, wo, Vec3::Z, 0.25 * MIX, Vec2::new(0.3, 0.7));
    assert!(guided.is_none_or(|bs| crate::math::is_black(bs.weight)));
}
