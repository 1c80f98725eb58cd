//! Energy of the layers: white furnaces against the layering formulas, no leaks, layers off.

use super::*;

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
