//! Chi-square tests of every sampling routine in `pathfarm_tracer::sampling` against the density it
//! claims, each with ~1M samples and the requirement p > 1e-4. Each family also checks that a
//! deliberately wrong law is *rejected* by the same test, so that the tests are known to be able to
//! fail.
//!
//! Run with `--nocapture` to see the p-values.

mod common;

use common::Pcg32;
use glam::{Vec2, Vec3};
use pathfarm_tracer::sampling::{
    barycentrics_along, cosine_hemisphere_pdf, cubic_falloff_pdf, sample_concentric_disk,
    sample_cosine_hemisphere, sample_cubic_falloff, sample_uniform_disk, sample_uniform_hemisphere,
    sample_uniform_sphere, sample_uniform_triangle, uniform_hemisphere_pdf, uniform_sphere_pdf,
    Distribution1D, SphericalTriangle,
};
use pathfarm_tracer::stats::{chi_square_test, ChiSquare, SphereBins};
use std::f32::consts::PI;

const N: usize = 1_000_000;
const MIN_P: f64 = 1e-4;
/// A wrong law must be rejected at least this strongly.
const REJECT_P: f64 = 1e-6;

fn report(name: &str, chi: ChiSquare) -> f64 {
    println!(
        "{name:<44} p = {:.4e} (χ² = {:.1}, dof {})",
        chi.p_value, chi.statistic, chi.dof
    );
    chi.p_value
}

// ---------------------------------------------------------------------------------------------
// Disk

/// Polar grid on the unit disk with bins of equal area: n_r rings uniform in r², n_phi sectors.
/// The density is 1/π, so every bin expects N / (n_r n_phi) samples.
fn disk_chi2(sample: impl Fn(Vec2) -> Vec2, seed: u64) -> ChiSquare {
    let (n_r, n_phi) = (25usize, 32usize);
    let mut observed = vec![0.0f64; n_r * n_phi];
    let mut rng = Pcg32::seeded(seed);
    for _ in 0..N {
        let p = sample(rng.vec2());
        let r2 = p.length_squared() as f64;
        assert!(r2 <= 1.0 + 1e-6, "point outside the disk: {p}");
        let mut phi = (p.y as f64).atan2(p.x as f64);
        if phi < 0.0 {
            phi += 2.0 * std::f64::consts::PI;
        }
        let i = ((r2 * n_r as f64) as usize).min(n_r - 1);
        let j = ((phi / (2.0 * std::f64::consts::PI) * n_phi as f64) as usize).min(n_phi - 1);
        observed[i * n_phi + j] += 1.0;
    }
    let expected = vec![N as f64 / (n_r * n_phi) as f64; n_r * n_phi];
    chi_square_test(&observed, &expected, 5.0)
}

#[test]
fn uniform_disk_is_uniform() {
    assert!(
        report(
            "sample_uniform_disk (r = √ξ)",
            disk_chi2(sample_uniform_disk, 1)
        ) > MIN_P
    );
}

#[test]
fn concentric_disk_is_uniform() {
    assert!(
        report(
            "sample_concentric_disk",
            disk_chi2(sample_concentric_disk, 2)
        ) > MIN_P
    );
}

#[test]
fn disk_with_linear_radius_is_rejected() {
    let wrong = |u: Vec2| {
        let r = u.x; // should be √ξ
        let (s, c) = (2.0 * PI * u.y).sin_cos();
        Vec2::new(r * c, r * s)
    };
    let p = report("wrong disk (r = ξ) must fail", disk_chi2(wrong, 3));
    assert!(p < REJECT_P, "a disk with r = ξ passed (p = {p})");
}

// ---------------------------------------------------------------------------------------------
// Sphere and hemisphere

fn sphere_chi2(sample: impl Fn(Vec2) -> Vec3, pdf: impl Fn(Vec3) -> f64, seed: u64) -> ChiSquare {
    let bins = SphereBins {
        n_theta: 40,
        n_phi: 40,
    };
    let mut observed = vec![0.0f64; bins.len()];
    let mut rng = Pcg32::seeded(seed);
    for _ in 0..N {
        let w = sample(rng.vec2());
        assert!((w.length() - 1.0).abs() < 1e-5, "not a unit vector: {w}");
        observed[bins.bin(w)] += 1.0;
    }
    let expected: Vec<f64> = bins
        .integrate(pdf, 8)
        .iter()
        .map(|e| e * N as f64)
        .collect();
    chi_square_test(&observed, &expected, 5.0)
}

#[test]
fn uniform_hemisphere_matches_its_pdf() {
    let pdf = |w: Vec3| {
        if w.z >= 0.0 {
            uniform_hemisphere_pdf() as f64
        } else {
            0.0
        }
    };
    assert!((uniform_hemisphere_pdf() as f64 - 0.5 / std::f64::consts::PI).abs() < 1e-8);
    assert!(
        report(
            "sample_uniform_hemisphere (1/2π)",
            sphere_chi2(sample_uniform_hemisphere, pdf, 4)
        ) > MIN_P
    );
}

#[test]
fn uniform_sphere_matches_its_pdf() {
    assert!((uniform_sphere_pdf() as f64 - 0.25 / std::f64::consts::PI).abs() < 1e-8);
    let p = report(
        "sample_uniform_sphere (1/4π)",
        sphere_chi2(sample_uniform_sphere, |_| uniform_sphere_pdf() as f64, 5),
    );
    assert!(p > MIN_P);
}

#[test]
fn cosine_hemisphere_matches_its_pdf() {
    let pdf = |w: Vec3| cosine_hemisphere_pdf(w.z) as f64;
    assert!(
        report(
            "sample_cosine_hemisphere (cos θ / π)",
            sphere_chi2(sample_cosine_hemisphere, pdf, 6)
        ) > MIN_P
    );
}

#[test]
fn cosine_samples_are_rejected_against_the_uniform_pdf() {
    let pdf = |w: Vec3| {
        if w.z >= 0.0 {
            uniform_hemisphere_pdf() as f64
        } else {
            0.0
        }
    };
    let p = report(
        "cosine samples vs 1/2π must fail",
        sphere_chi2(sample_cosine_hemisphere, pdf, 7),
    );
    assert!(p < REJECT_P);
}

// ---------------------------------------------------------------------------------------------
// Triangle

/// The index of sub-triangle (i, j, upper) of the barycentric triangle cut into n² (see
/// [`triangle_chi2`]), and whether it lies inside the triangle.
fn sub_triangle(n: usize, i: usize, j: usize, upper: bool) -> (usize, bool) {
    (
        (i * n + j) * 2 + upper as usize,
        i + j + (upper as usize) < n,
    )
}

/// Counts, for each of the n² congruent sub-triangles of the barycentric triangle (an n × n grid in
/// (b1, b2), each cell split by its anti-diagonal), the points among N that `sample` puts in it;
/// every barycentric must be at least `min_bary` and their sum 1.
fn bin_barycentrics(n: usize, sample: impl Fn(Vec2) -> Vec3, seed: u64, min_bary: f32) -> Vec<f64> {
    let mut observed = vec![0.0f64; 2 * n * n];
    let mut rng = Pcg32::seeded(seed);
    for _ in 0..N {
        let b = sample(rng.vec2());
        assert!(
            b.min_element() >= min_bary && (b.element_sum() - 1.0).abs() < 1e-5,
            "bad barycentrics {b}"
        );
        let (x, y) = (b.y as f64 * n as f64, b.z as f64 * n as f64);
        let (i, j) = ((x as usize).min(n - 1), (y as usize).min(n - 1));
        let mut upper = (x - i as f64) + (y - j as f64) >= 1.0;
        if !sub_triangle(n, i, j, upper).1 {
            // Only rounding can put a point past the hypotenuse.
            upper = false;
        }
        observed[sub_triangle(n, i, j, upper).0] += 1.0;
    }
    observed
}

/// Bins the barycentric triangle {b1, b2 ≥ 0, b1 + b2 ≤ 1} into n² congruent sub-triangles (an n × n
/// grid in (b1, b2), each cell split by its anti-diagonal; cells beyond the hypotenuse hold nothing).
/// Every sub-triangle has area 1/n² of the whole, so a uniform sampler expects N / n² in each.
fn triangle_chi2(sample: impl Fn(Vec2) -> Vec3, seed: u64) -> ChiSquare {
    let n = 30usize;
    let observed = bin_barycentrics(n, sample, seed, -1e-6);
    let mut expected = vec![0.0f64; 2 * n * n];
    for i in 0..n {
        for j in 0..n {
            for upper in [false, true] {
                let (index, valid) = sub_triangle(n, i, j, upper);
                if valid {
                    expected[index] = N as f64 / (n * n) as f64;
                }
            }
        }
    }
    chi_square_test(&observed, &expected, 5.0)
}

#[test]
fn triangle_sampling_is_uniform() {
    assert!(
        report(
            "sample_uniform_triangle",
            triangle_chi2(sample_uniform_triangle, 8)
        ) > MIN_P
    );
    // Uniform barycentrics give uniform points on any triangle (the map is affine), and the mean of
    // the barycentrics is the centroid.
    let mut rng = Pcg32::seeded(9);
    let mut mean = Vec3::ZERO.as_dvec3();
    for _ in 0..N {
        mean += sample_uniform_triangle(rng.vec2()).as_dvec3();
    }
    mean /= N as f64;
    println!("mean barycentrics {mean}");
    assert!((mean - glam::DVec3::splat(1.0 / 3.0)).abs().max_element() < 2e-3);
}

#[test]
fn triangle_without_square_root_is_rejected() {
    let wrong = |u: Vec2| {
        let b0 = 1.0 - u.x; // should be 1 − √ξ₁
        let b1 = u.y * u.x;
        Vec3::new(b0, b1, 1.0 - b0 - b1)
    };
    let p = report("wrong triangle (no √) must fail", triangle_chi2(wrong, 10));
    assert!(p < REJECT_P);
}

// ---------------------------------------------------------------------------------------------
// Spherical triangle

/// The solid angle of the triangle `c` seen from `p`, in double precision (Van Oosterom and
/// Strackee), independent of the code under test.
fn solid_angle_f64(c: [glam::DVec3; 3], p: glam::DVec3) -> f64 {
    let [a, b, c] = c.map(|v| (v - p).normalize());
    2.0 * a
        .dot(b.cross(c))
        .abs()
        .atan2(1.0 + a.dot(b) + b.dot(c) + c.dot(a))
}

/// Bins the points that `sample` (barycentrics, from uniform numbers) puts on the triangle
/// `corners` into its n² congruent sub-triangles (as [`triangle_chi2`]) and tests the counts against
/// a density uniform in the solid angle seen from `p`: each sub-triangle expects N times its solid
/// angle over the whole's.
fn spherical_chi2(
    corners: [Vec3; 3],
    p: Vec3,
    sample: impl Fn(Vec2) -> Vec3,
    seed: u64,
) -> ChiSquare {
    let n = 16usize;
    let observed = bin_barycentrics(n, sample, seed, 0.0);
    let c = corners.map(|v| v.as_dvec3());
    let at = |b1: f64, b2: f64| c[0] * (1.0 - b1 - b2) + c[1] * b1 + c[2] * b2;
    let pd = p.as_dvec3();
    let whole = solid_angle_f64(c, pd);
    let mut expected = vec![0.0f64; 2 * n * n];
    let h = 1.0 / n as f64;
    for i in 0..n {
        for j in 0..n {
            let (b1, b2) = (i as f64 * h, j as f64 * h);
            let lower = [at(b1, b2), at(b1 + h, b2), at(b1, b2 + h)];
            let upper = [at(b1 + h, b2), at(b1 + h, b2 + h), at(b1, b2 + h)];
            for (half, is_upper) in [(lower, false), (upper, true)] {
                let (index, valid) = sub_triangle(n, i, j, is_upper);
                if valid {
                    expected[index] = N as f64 * solid_angle_f64(half, pd) / whole;
                }
            }
        }
    }
    chi_square_test(&observed, &expected, 5.0)
}

/// The triangle of the spherical-triangle tests and the points it is seen from: close above its
/// middle (a solid angle near 2π), close above a corner, beside it near its plane, far off, and
/// behind it (the sampler does not care which side it is seen from).
fn spherical_cases() -> ([Vec3; 3], [Vec3; 5]) {
    let corners = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.2, 0.9, 0.0),
    ];
    let points = [
        Vec3::new(0.4, 0.3, 0.01),
        Vec3::new(0.95, 0.02, 0.05),
        Vec3::new(1.4, 0.6, 0.1),
        Vec3::new(-2.0, 3.0, 4.0),
        Vec3::new(0.3, 0.2, -0.3),
    ];
    (corners, points)
}

#[test]
fn spherical_triangle_sampling_is_uniform_in_solid_angle() {
    let (corners, points) = spherical_cases();
    let mut worst = 1.0f64;
    for (k, p) in points.into_iter().enumerate() {
        let s = SphericalTriangle::new(corners, p).expect("a triangle seen from off its corners");
        let exact = solid_angle_f64(corners.map(|v| v.as_dvec3()), p.as_dvec3());
        assert!(
            (s.solid_angle() as f64 / exact - 1.0).abs() < 1e-4,
            "solid angle {} against {exact}",
            s.solid_angle()
        );
        let sample = |u: Vec2| {
            let w = s.sample(u);
            assert!((w.length() - 1.0).abs() < 1e-4, "not a unit direction: {w}");
            barycentrics_along(corners, p, w).expect("the direction meets the plane")
        };
        let name = format!("spherical triangle from {p} (Ω = {exact:.4})");
        worst = worst.min(report(
            &name,
            spherical_chi2(corners, p, sample, 20 + k as u64),
        ));
    }
    assert!(worst > MIN_P, "some case failed (p = {worst:e})");
}

#[test]
fn area_sampling_is_rejected_against_the_solid_angle_density() {
    let (corners, points) = spherical_cases();
    let p = report(
        "area sampling seen close by must fail",
        spherical_chi2(corners, points[0], sample_uniform_triangle, 30),
    );
    assert!(p < REJECT_P);
}

// ---------------------------------------------------------------------------------------------
// Inverse CDF

/// 100 bins on [0, 1]; expected counts are differences of the CDF P(x) = 1 − (1 − x)³.
fn cubic_chi2(sample: impl Fn(f32) -> f32, seed: u64) -> ChiSquare {
    let n_bins = 100usize;
    let mut observed = vec![0.0f64; n_bins];
    let mut rng = Pcg32::seeded(seed);
    for _ in 0..N {
        let x = sample(rng.f32());
        assert!((0.0..=1.0).contains(&x), "{x} outside [0, 1]");
        observed[((x as f64 * n_bins as f64) as usize).min(n_bins - 1)] += 1.0;
    }
    let cdf = |x: f64| 1.0 - (1.0 - x).powi(3);
    let expected: Vec<f64> = (0..n_bins)
        .map(|k| N as f64 * (cdf((k + 1) as f64 / n_bins as f64) - cdf(k as f64 / n_bins as f64)))
        .collect();
    chi_square_test(&observed, &expected, 5.0)
}

#[test]
fn cubic_falloff_follows_its_density() {
    assert!(
        report(
            "sample_cubic_falloff (3(1 − x)²)",
            cubic_chi2(sample_cubic_falloff, 11)
        ) > MIN_P
    );
    // The pdf function is the one sampled and integrates to 1.
    let m = 100_000;
    let integral: f64 = (0..m)
        .map(|k| cubic_falloff_pdf((k as f32 + 0.5) / m as f32) as f64)
        .sum::<f64>()
        / m as f64;
    assert!((integral - 1.0).abs() < 1e-4);
    assert_eq!(cubic_falloff_pdf(-0.1), 0.0);
    assert_eq!(cubic_falloff_pdf(1.1), 0.0);
}

#[test]
fn uniform_samples_are_rejected_against_the_cubic_falloff() {
    let p = report("x = ξ vs 3(1 − x)² must fail", cubic_chi2(|u| u, 12));
    assert!(p < REJECT_P);
}

// ---------------------------------------------------------------------------------------------
// Discrete distributions

/// Draws N outcomes; returns (counts per outcome, histogram of the remapped u in 50 bins) and checks
/// that the returned probability is the pmf.
fn draw(d: &Distribution1D, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut counts = vec![0.0f64; d.len()];
    let mut remap = vec![0.0f64; 50];
    let mut rng = Pcg32::seeded(seed);
    for _ in 0..N {
        let (i, p, r) = d.sample(rng.f32());
        assert_eq!(p, d.pmf(i));
        assert!((0.0..1.0).contains(&r), "remapped u {r} outside [0, 1)");
        counts[i] += 1.0;
        remap[((r * 50.0) as usize).min(49)] += 1.0;
    }
    (counts, remap)
}

fn discrete_chi2(d: &Distribution1D, counts: &[f64]) -> ChiSquare {
    let expected: Vec<f64> = (0..d.len()).map(|i| d.pmf(i) as f64 * N as f64).collect();
    chi_square_test(counts, &expected, 5.0)
}

#[test]
fn distribution_1d_samples_its_pmf() {
    let weights = [0.0f32, 1.0, 0.0, 3.0, 0.5, 0.0, 0.0, 2.5, 0.01, 0.0];
    let d = Distribution1D::new(&weights);
    let total: f32 = weights.iter().sum();
    assert!((d.total() - total as f64).abs() < 1e-6);
    for (i, &w) in weights.iter().enumerate() {
        assert!((d.pmf(i) - w / total).abs() < 1e-7);
    }
    let (counts, remap) = draw(&d, 13);
    for (i, &w) in weights.iter().enumerate() {
        if w == 0.0 {
            assert_eq!(counts[i], 0.0, "zero-weight outcome {i} was drawn");
        }
    }
    assert!(report("Distribution1D counts vs pmf", discrete_chi2(&d, &counts)) > MIN_P);
    let uniform = vec![N as f64 / 50.0; 50];
    assert!(
        report(
            "Distribution1D remapped u is uniform",
            chi_square_test(&remap, &uniform, 5.0)
        ) > MIN_P
    );

    // The extreme inputs still land on positive-weight outcomes.
    assert_eq!(d.sample(0.0).0, 1);
    assert_eq!(d.sample(1.0 - f32::EPSILON / 2.0).0, 8);
    for u in [1.0f32 / 7.01, 4.0 / 7.01, 4.5 / 7.01, 7.0 / 7.01] {
        let (i, _, _) = d.sample(u);
        assert!(weights[i] > 0.0, "u = {u} drew zero-weight outcome {i}");
    }

    // Degenerate cases: all zero (or invalid) is empty; a single outcome always wins.
    assert!(Distribution1D::new(&[0.0, -1.0, f32::NAN]).is_empty());
    let one = Distribution1D::new(&[0.0, 2.0, 0.0]);
    for u in [0.0f32, 0.3, 0.999_999_9] {
        let (i, p, r) = one.sample(u);
        assert_eq!((i, p), (1, 1.0));
        assert!((r - u).abs() < 1e-6);
    }
}

#[test]
fn light_selection_is_proportional_to_power() {
    let power = [1.0f32, 0.0, 5.0, 0.25, 100.0];
    let d = Distribution1D::new(&power);
    let (counts, _) = draw(&d, 14);
    assert_eq!(counts[1], 0.0, "a light without power was chosen");
    assert!(
        report(
            "light selection ∝ power [1, 0, 5, 0.25, 100]",
            discrete_chi2(&d, &counts)
        ) > MIN_P
    );
    // A selection that ignores power (uniform over the four lights that emit) is rejected by the same
    // test, on the statistic alone (no impossible outcome is drawn).
    let mut rng = Pcg32::seeded(15);
    let mut uniform_counts = vec![0.0f64; power.len()];
    for _ in 0..N {
        uniform_counts[[0, 2, 3, 4][((rng.f32() * 4.0) as usize).min(3)]] += 1.0;
    }
    let chi = discrete_chi2(&d, &uniform_counts);
    assert!(report("uniform light selection must fail", chi) < REJECT_P);
}
