//! Statistical tests of the layers on the glTF material: KHR_materials_clearcoat's GGX coat and
//! KHR_materials_sheen's "Charlie" sheen. `sample()` draws directions with exactly the density
//! `pdf()` claims (Pearson chi-square over direction bins, at several roughnesses and angles, with a
//! coat normal that differs from the shading normal too), every sample's weight is `eval / pdf`, the
//! white furnace never creates energy and gives what the layering formulas predict, and the tests
//! reject a slightly wrong pdf.
//!
//! Run with `--nocapture` to see the p-values and furnace values.

mod common;

use common::bins::{Binning, HemiGrid};
use common::bsdf_chi2::{check_view_angles, p_right_and_wrong, run_chi2, wo_at, MIN_P, WORLD};
use common::Pcg32;
use glam::{DVec3, Vec2, Vec3};
use pathfarm_tracer::bsdf::{Bsdf, PbrParams};
use pathfarm_tracer::stats::SphereBins;
const TINT: Vec3 = Vec3::new(0.9, 0.6, 0.3);

/// A Lambertian of albedo `base` under a clear coat.
fn coated(base: Vec3, clearcoat: f32, roughness: f32) -> PbrParams {
    PbrParams {
        clearcoat,
        clearcoat_roughness: roughness,
        ..PbrParams::diffuse(base)
    }
}

/// A Lambertian of albedo `base` under a sheen.
fn sheened(base: Vec3, color: Vec3, roughness: f32) -> PbrParams {
    PbrParams {
        sheen_color: color,
        sheen_roughness: roughness,
        ..PbrParams::diffuse(base)
    }
}

/// A BSDF on the z = 0 plane; the clear coat's normal is `coat_normal` (on the front side).
fn bsdf_with(p: PbrParams, coat_normal: Vec3) -> Bsdf {
    Bsdf::with_coat_normal(p, Vec3::Z, Vec3::Z, Some(Vec3::X), coat_normal)
}

/// Bins zoomed on the mirror direction about `normal` (flipped to wo's side) for a lobe of
/// `roughness`, or uniform bins for broad lobes.
fn bins(wo: Vec3, normal: Vec3, roughness: f32, wide: bool) -> Binning {
    if wide {
        return Binning::Sphere(SphereBins {
            n_theta: 40,
            n_phi: 40,
        });
    }
    let n = if wo.z > 0.0 {
        normal
    } else {
        // The coat normal flips with the side, as the shading normal does.
        -normal
    };
    let w = wo.as_dvec3();
    let n = n.as_dvec3();
    let refl = 2.0 * w.dot(n) * n - w;
    let spread = 2.0 * (roughness as f64).powi(2).max(1e-4);
    let (up, down) = if wo.z > 0.0 {
        (refl, -refl)
    } else {
        (-refl, refl)
    };
    Binning::Zoom(Box::new((
        HemiGrid::new(true, up, spread, 32, 32),
        HemiGrid::new(false, down, spread, 8, 8),
    )))
}

/// Runs every wo of a configuration and asserts p > 1e-4 and the per-sample consistency. The bins
/// zoom on the coat's lobe, or with `zoom` on the mirror lobe of that normal and roughness.
fn check_config(
    name: &str,
    p: PbrParams,
    coat_normal: Vec3,
    wide: bool,
    sides: &[bool],
    seed: u64,
) {
    check_config_zoomed(
        name,
        p,
        coat_normal,
        (coat_normal, p.clearcoat_roughness),
        wide,
        sides,
        seed,
    )
}

fn check_config_zoomed(
    name: &str,
    p: PbrParams,
    coat_normal: Vec3,
    zoom: (Vec3, f32),
    wide: bool,
    sides: &[bool],
    seed: u64,
) {
    let b = bsdf_with(p, coat_normal);
    check_view_angles(name, sides, seed, |wo, seed| {
        let bins = bins(wo, zoom.0, zoom.1, wide);
        run_chi2(&b, wo, &bins, &WORLD, 1_000_000, seed, &|s, pdf| {
            assert!(!s.transmitted, "an opaque layered material transmitted");
            assert_eq!(pdf, s.pdf, "the sample's pdf is not pdf(wo, wi)");
        })
    });
}

/// A coat normal tilted 25° from the shading normal.
fn tilted_coat_normal() -> Vec3 {
    Vec3::new(0.35, 0.25, 0.9).normalize()
}

#[test]
fn clearcoat_sampling_matches_pdf() {
    check_config(
        "coat r=0.05 on diffuse",
        coated(TINT, 1.0, 0.05),
        Vec3::Z,
        false,
        &[true, false],
        1,
    );
    check_config(
        "coat 0.7 r=0.3 on diffuse",
        coated(TINT, 0.7, 0.3),
        Vec3::Z,
        false,
        &[true],
        2,
    );
    check_config(
        "coat r=1 on diffuse",
        coated(TINT, 1.0, 1.0),
        Vec3::Z,
        true,
        &[true],
        3,
    );
    // A rough metal under a mirror coat: the coat is a delta, the metal is what is binned.
    check_config(
        "mirror coat on metal r=0.4",
        PbrParams {
            metallic: 1.0,
            roughness: 0.4,
            ..coated(TINT, 1.0, 0.0)
        },
        Vec3::Z,
        true,
        &[true],
        4,
    );
}

#[test]
fn clearcoat_with_its_own_normal_sampling_matches_pdf() {
    let n = tilted_coat_normal();
    check_config(
        "tilted coat r=0.2 on diffuse",
        coated(TINT, 1.0, 0.2),
        n,
        false,
        &[true, false],
        5,
    );
    // The plastic's lobe is the narrow one: the bins zoom on it.
    check_config_zoomed(
        "tilted coat r=0.6 on plastic r=0.3",
        PbrParams {
            specular: 1.0,
            roughness: 0.3,
            ..coated(TINT, 1.0, 0.6)
        },
        n,
        (Vec3::Z, 0.3),
        false,
        &[true],
        6,
    );
}

/// (A sheen colour below 1 leaves the base some weight: where a white sheen's albedo reaches 1 the
/// base gets none, and the sheen's cosine samples that miss its narrow lobe evaluate to black and
/// are rejected, as every lobe's black samples are, which a histogram of directions cannot show.)
#[test]
fn sheen_sampling_matches_pdf() {
    for (k, r) in [0.0f32, 0.3, 0.7, 1.0].into_iter().enumerate() {
        check_config(
            &format!("sheen r={r} on diffuse"),
            sheened(TINT, Vec3::new(0.6, 0.8, 0.4), r),
            Vec3::Z,
            true,
            if k == 1 { &[true, false] } else { &[true] },
            10 + k as u64,
        );
    }
    // Sheen on a black base: the sheen lobe alone.
    check_config(
        "sheen r=0.5 on black",
        sheened(Vec3::ZERO, Vec3::ONE, 0.5),
        Vec3::Z,
        true,
        &[true],
        15,
    );
}

#[test]
fn every_lobe_together_sampling_matches_pdf() {
    let p = PbrParams {
        base_color: TINT,
        metallic: 0.3,
        roughness: 0.5,
        specular: 0.7,
        specular_color: Vec3::new(1.0, 0.8, 1.2),
        ior: 1.4,
        transmission: 0.0,
        thin_walled: false,
        clearcoat: 0.8,
        clearcoat_roughness: 0.15,
        sheen_color: Vec3::new(0.3, 0.5, 0.9),
        sheen_roughness: 0.4,
    };
    check_config(
        "everything, tilted coat",
        p,
        tilted_coat_normal(),
        false,
        &[true, false],
        20,
    );
}

/// The chi-square test can fail: samples are rejected against the pdf of a coat of roughness 0.33
/// instead of 0.3, of a coat of weight 0.8 instead of 1 (wrong lobe probabilities), and of a sheen
/// of another colour over a glossy plastic (wrong probabilities of the sheen against the plastic's
/// GGX lobe; over a Lambertian alone both lobes are sampled by cosine and the pdf cannot tell).
#[test]
fn chi_square_rejects_a_slightly_wrong_layer_pdf() {
    for (name, drawn, claimed, wide) in [
        (
            "coat r 0.30 vs 0.33",
            coated(TINT, 1.0, 0.3),
            coated(TINT, 1.0, 0.33),
            false,
        ),
        (
            "coat 1.0 vs 0.8",
            coated(TINT, 1.0, 0.3),
            coated(TINT, 0.8, 0.3),
            false,
        ),
        (
            "sheen white vs grey on plastic",
            PbrParams {
                specular: 1.0,
                roughness: 0.3,
                ..sheened(Vec3::splat(0.2), Vec3::ONE, 0.3)
            },
            PbrParams {
                specular: 1.0,
                roughness: 0.3,
                ..sheened(Vec3::splat(0.2), Vec3::splat(0.5), 0.3)
            },
            true,
        ),
    ] {
        let (b, wrong) = (bsdf_with(drawn, Vec3::Z), bsdf_with(claimed, Vec3::Z));
        let wo = wo_at(0.6, true);
        let r = if wide {
            drawn.roughness
        } else {
            drawn.clearcoat_roughness
        };
        let bins = bins(wo, Vec3::Z, r, false);
        let (right, bad) = p_right_and_wrong(&b, &wrong, wo, &bins, 1_000_000);
        println!("{name}: p(right) = {right:.4}, p(wrong) = {bad:.3e}");
        assert!(right > MIN_P, "{name}: p(right) = {right}");
        assert!(
            bad < 1e-6,
            "{name}: the wrong pdf was not rejected (p = {bad})"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Energy

/// Mean and standard error of the BSDF weights (rejected samples count as 0), per channel.
fn furnace(b: &Bsdf, wo: Vec3, n: usize, seed: u64) -> (DVec3, DVec3) {
    let mut rng = Pcg32::new(seed, 11);
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    for _ in 0..n {
        let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) else {
            continue;
        };
        let w = s.weight.as_dvec3();
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(DVec3::ZERO);
    (mean, (var / n as f64).map(f64::sqrt))
}

/// ∫ eval dwi by quadrature over the hemisphere of wo (midpoint rule in (cos² θ, φ), denser towards
/// the horizon), independent of the sampling: the white furnace measured without `sample`.
fn integrate_eval(b: &Bsdf, wo: Vec3, n: usize) -> DVec3 {
    let up = wo.z > 0.0;
    let mut acc = DVec3::ZERO;
    for a in 0..n {
        let t = (a as f64 + 0.5) / n as f64;
        let z = t * t;
        let s = (1.0 - z * z).max(0.0).sqrt();
        for c in 0..2 * n {
            let phi = std::f64::consts::PI * (c as f64 + 0.5) / n as f64;
            let wi = DVec3::new(s * phi.cos(), s * phi.sin(), if up { z } else { -z }).as_vec3();
            acc += b.eval(wo, wi).as_dvec3() * 2.0 * t;
        }
    }
    acc * std::f64::consts::PI / (n * n) as f64
}

/// Schlick's Fresnel of the clear coat (f0 = 0.04), independently.
fn coat_fresnel(cos: f64) -> f64 {
    0.04 + 0.96 * (1.0 - cos.abs()).powi(5)
}

const FURNACE_COS: [f32; 7] = [1.0, 0.9, 0.7, 0.5, 0.3, 0.1, 0.03];

/// A white base under a clear coat reflects 1 − clearcoat · F(μ) · (1 − E(μ)), E the coat's GGX
/// directional albedo (measured as the furnace of a white rough metal, whose Fresnel is 1): never
/// more than 1, and exactly what the extension's layering predicts; by sampling and by quadrature.
#[test]
fn clearcoat_white_furnace_is_the_layering_formula() {
    let mut failures = Vec::new();
    for (k, r) in [0.0f32, 0.05, 0.3, 0.6, 1.0].into_iter().enumerate() {
        for c in [1.0f32, 0.5] {
            let b = bsdf_with(coated(Vec3::ONE, c, r), Vec3::Z);
            let metal = bsdf_with(
                PbrParams {
                    metallic: 1.0,
                    specular: 1.0,
                    roughness: r,
                    ..PbrParams::diffuse(Vec3::ONE)
                },
                Vec3::Z,
            );
            let mut line = format!("coat {c} r={r:<4}:");
            for (ci, &mu) in FURNACE_COS.iter().enumerate() {
                for front in [true, false] {
                    let wo = wo_at(mu, front);
                    let seed = (k * 100 + ci * 2 + front as usize) as u64;
                    let (mean, se) = furnace(&b, wo, 200_000, seed);
                    let (e_ggx, se_ggx) = furnace(&metal, wo, 200_000, seed + 7);
                    let f = c as f64 * coat_fresnel(mu as f64);
                    let expected = 1.0 - f * (1.0 - e_ggx.x);
                    let tol = 4.0 * (se.x + f * se_ggx.x) + 1e-4;
                    if front {
                        line += &format!(" {:.4}/{expected:.4}", mean.x);
                    }
                    if mean.max_element() > 1.0 + 1e-4 + 4.0 * se.max_element() {
                        failures.push(format!(
                            "coat {c} r={r} cos={mu} front={front}: creates energy {mean}"
                        ));
                    }
                    if (mean.x - expected).abs() > tol {
                        failures.push(format!(
                            "coat {c} r={r} cos={mu} front={front}: {} ± {} vs the formula's {expected}",
                            mean.x, se.x
                        ));
                    }
                    // (The quadrature resolves coats of roughness ≥ 0.3; the mirror coat is a delta.)
                    if r >= 0.3 && front && ci % 2 == 0 {
                        let q = integrate_eval(&b, wo, 400).x;
                        if q > 1.0 + 1e-3 || (q - expected).abs() > 5e-3 + tol {
                            failures.push(format!(
                                "coat {c} r={r} cos={mu}: ∫ eval = {q}, formula {expected}"
                            ));
                        }
                    }
                }
            }
            println!("{line}");
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A white sheen on a white Lambertian: the sheen reflects E(μ) and the base 1 − E(μ), so the total
/// is 1 up to the margin of the conservative albedo table (and never above it); by sampling and by
/// quadrature of eval. The sheen alone (black base) reflects its own albedo, which the table bounds.
#[test]
fn sheen_white_furnace_conserves_energy() {
    let mut failures = Vec::new();
    for (k, r) in [0.0f32, 0.07, 0.2, 0.5, 0.8, 1.0].into_iter().enumerate() {
        let white = bsdf_with(sheened(Vec3::ONE, Vec3::ONE, r), Vec3::Z);
        let alone = bsdf_with(sheened(Vec3::ZERO, Vec3::ONE, r), Vec3::Z);
        let mut line = format!("sheen r={r:<4}:");
        for (ci, &mu) in FURNACE_COS.iter().enumerate() {
            let wo = wo_at(mu, true);
            let (mean, se) = furnace(&white, wo, 200_000, (k * 100 + ci) as u64);
            let q = integrate_eval(&white, wo, 400);
            let q_alone = integrate_eval(&alone, wo, 400).x;
            line += &format!(" {:.4}/{:.4} (sheen {q_alone:.4})", mean.x, q.x);
            if mean.max_element() > 1.0 + 1e-4 + 4.0 * se.max_element()
                || q.max_element() > 1.0 + 1e-3
            {
                failures.push(format!(
                    "sheen r={r} cos={mu}: creates energy: {mean} / {q}"
                ));
            }
            // The table's conservative margin costs up to 2.5 % where E changes fastest (r ≤ 0.1,
            // cos θo ≈ 0.1), a few 10⁻³ elsewhere.
            if mean.x < 0.97 - 4.0 * se.x || q.x < 0.97 {
                failures.push(format!("sheen r={r} cos={mu}: loses energy: {mean} / {q}"));
            }
        }
        println!("{line}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Every layer over every base, white: never more than 1 (flux-weighted for the refracting volume,
/// from outside only, where no scaling applies to the reflection), by sampling.
#[test]
fn layered_white_furnace_never_creates_energy() {
    let white = Vec3::ONE;
    let bases = [
        ("diffuse", PbrParams::diffuse(white)),
        (
            "plastic r=0.3",
            PbrParams {
                specular: 1.0,
                roughness: 0.3,
                ..PbrParams::diffuse(white)
            },
        ),
        (
            "plastic r=0",
            PbrParams {
                specular: 1.0,
                roughness: 0.0,
                ..PbrParams::diffuse(white)
            },
        ),
        (
            "metal r=0.5",
            PbrParams {
                metallic: 1.0,
                specular: 1.0,
                roughness: 0.5,
                ..PbrParams::diffuse(white)
            },
        ),
        (
            "thin glass r=0.3",
            PbrParams {
                specular: 1.0,
                roughness: 0.3,
                transmission: 1.0,
                thin_walled: true,
                ..PbrParams::diffuse(white)
            },
        ),
    ];
    let mut failures = Vec::new();
    for (k, (name, base)) in bases.iter().enumerate() {
        for (coat, cr, sheen, sr) in [
            (1.0f32, 0.0f32, 0.0f32, 0.0f32),
            (1.0, 0.2, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.3),
            (1.0, 0.1, 1.0, 0.6),
        ] {
            let p = PbrParams {
                clearcoat: coat,
                clearcoat_roughness: cr,
                sheen_color: Vec3::splat(sheen),
                sheen_roughness: sr,
                ..*base
            };
            for coat_normal in [Vec3::Z, tilted_coat_normal()] {
                let b = bsdf_with(p, coat_normal);
                let mut line = format!(
                    "{name:<16} coat {coat} r={cr:<3} sheen {sheen} r={sr:<3} {}:",
                    if coat_normal == Vec3::Z {
                        "     "
                    } else {
                        "tilt "
                    }
                );
                for (ci, &mu) in FURNACE_COS.iter().enumerate() {
                    let wo = wo_at(mu, true);
                    let (mean, se) = furnace(&b, wo, 200_000, (k * 1000 + ci) as u64);
                    line += &format!(" {:.4}", mean.max_element());
                    if mean.max_element() > 1.0 + 1e-3 + 4.0 * se.max_element() {
                        failures.push(format!("{line}: {mean} ± {se} at cos {mu}"));
                    }
                }
                println!("{line}");
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Light never leaks through the geometric surface, whatever the coat normal and the shading
/// normal say, and the samples' pdfs and weights are the queries' own.
#[test]
fn layered_light_never_leaks_through_the_geometric_surface() {
    let ng = Vec3::Z;
    let ns = Vec3::new(0.64, 0.0, 0.77).normalize();
    let nc = Vec3::new(-0.3, 0.5, 0.81).normalize();
    let mut rng = Pcg32::new(23, 5);
    let p = PbrParams {
        specular: 1.0,
        roughness: 0.4,
        clearcoat: 1.0,
        clearcoat_roughness: 0.2,
        sheen_color: TINT,
        sheen_roughness: 0.5,
        ..PbrParams::diffuse(TINT)
    };
    for coat_r in [0.2f32, 0.0] {
        let b = Bsdf::with_coat_normal(
            PbrParams {
                clearcoat_roughness: coat_r,
                ..p
            },
            ns,
            ng,
            None,
            nc,
        );
        let mut worst: f32 = 0.0;
        for _ in 0..200_000 {
            let rand_dir = |rng: &mut Pcg32| {
                let z = 1.0 - 2.0 * rng.f32();
                let phi = 2.0 * std::f32::consts::PI * rng.f32();
                let r = (1.0 - z * z).max(0.0).sqrt();
                Vec3::new(r * phi.cos(), r * phi.sin(), z)
            };
            let wo = rand_dir(&mut rng);
            let wi = rand_dir(&mut rng);
            if (wo.dot(ng) > 0.0) != (wi.dot(ng) > 0.0) {
                assert_eq!(b.eval(wo, wi), Vec3::ZERO, "the layered surface leaks");
                assert_eq!(b.pdf(wo, wi), 0.0);
            }
            if let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) {
                assert!(!s.transmitted);
                assert_eq!((wo.dot(ng) > 0.0), (s.wi.dot(ng) > 0.0), "a sample leaked");
                if !s.delta {
                    let (e, pdf) = b.eval_pdf(wo, s.wi);
                    let rel = ((pdf - s.pdf) / s.pdf).abs().max(
                        (e / pdf - s.weight).abs().max_element() / s.weight.max_element().max(1e-6),
                    );
                    worst = worst.max(rel);
                }
            }
        }
        println!("layered leak guard, coat r={coat_r}: worst weight/pdf mismatch {worst:.1e}");
        assert!(worst < 1e-3);
    }
}

/// Layers that are off change nothing: a zero clear coat or a black sheen gives the BSDF of the
/// material without them, to the bit, whatever the other layer parameters and the coat normal.
#[test]
fn layers_that_are_off_change_no_bit() {
    let n = Vec3::new(0.1, -0.2, 0.97).normalize();
    for base in [
        PbrParams::diffuse(TINT),
        PbrParams {
            specular: 1.0,
            roughness: 0.3,
            metallic: 0.4,
            ..PbrParams::diffuse(TINT)
        },
    ] {
        let plain = Bsdf::new(base, n, n, None);
        let off = Bsdf::with_coat_normal(
            PbrParams {
                clearcoat: 0.0,
                clearcoat_roughness: 0.7,
                sheen_color: Vec3::ZERO,
                sheen_roughness: 0.4,
                ..base
            },
            n,
            n,
            None,
            tilted_coat_normal(),
        );
        assert_eq!(plain.single_lobe(), off.single_lobe());
        let mut rng = Pcg32::new(5, 5);
        for _ in 0..20_000 {
            let wo = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32()).normalize();
            let wi = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.2).normalize();
            assert_eq!(
                format!("{:?}", plain.eval_pdf(wo, wi)),
                format!("{:?}", off.eval_pdf(wo, wi))
            );
            let (ul, u) = (rng.f32(), Vec2::new(rng.f32(), rng.f32()));
            assert_eq!(
                format!("{:?}", plain.sample(wo, ul, u)),
                format!("{:?}", off.sample(wo, ul, u))
            );
        }
    }
}
