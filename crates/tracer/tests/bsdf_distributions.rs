//! Statistical tests of the BSDF: `sample()` draws directions with exactly the density `pdf()` claims
//! (Pearson chi-square over direction bins), every sample's weight is `eval / pdf`, the white furnace
//! never creates energy, the smooth dielectric reflects its exact Fresnel fraction, and GGX
//! visible-normal sampling follows D_wo(m).
//!
//! Run with `--nocapture` to see the p-values and furnace values.

mod common;

use common::bins::{Binning, HemiGrid};
use common::bsdf_chi2::{
    check_view_angles, p_right_and_wrong, run_chi2, wo_at, Frame, RunStats, MIN_P,
};
use common::Pcg32;
use glam::{DVec3, Vec2, Vec3};
use pathfarm_tracer::bsdf::microfacet::Ggx;
use pathfarm_tracer::bsdf::{Bsdf, PbrParams};
use pathfarm_tracer::stats::{chi_square_test, SphereBins};
use std::f64::consts::PI;

// ---------------------------------------------------------------------------------------------
// Configurations

fn ggx_alpha(roughness: f32) -> f64 {
    (roughness as f64 * roughness as f64).max(1e-4)
}

fn plastic(base: Vec3, roughness: f32) -> PbrParams {
    PbrParams {
        specular: 1.0,
        roughness,
        ..PbrParams::diffuse(base)
    }
}

fn metal(base: Vec3, roughness: f32) -> PbrParams {
    PbrParams {
        metallic: 1.0,
        specular: 1.0,
        roughness,
        ..PbrParams::diffuse(base)
    }
}

fn glass(base: Vec3, roughness: f32, thin: bool) -> PbrParams {
    PbrParams {
        specular: 1.0,
        roughness,
        transmission: 1.0,
        thin_walled: thin,
        ..PbrParams::diffuse(base)
    }
}

fn bsdf(p: PbrParams) -> Bsdf {
    Bsdf::new(p, Vec3::Z, Vec3::Z, Some(Vec3::X))
}

/// An orthonormal frame around `n` (independent of the library's), to run tests on a tilted surface.
#[derive(Clone, Copy)]
struct TestFrame {
    t: Vec3,
    b: Vec3,
    n: Vec3,
}

impl TestFrame {
    fn new(n: Vec3) -> Self {
        let n = n.normalize();
        let (t, b) = n.any_orthonormal_pair();
        TestFrame { t, b, n }
    }
    fn to_world(self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
    fn to_local(self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
}

/// A slanted surface normal for the tests that must not rely on the local frame being the world's.
const TILTED: Vec3 = Vec3::new(0.2, -0.3, 0.93);

/// The lobe axes for a histogram: the mirror direction, and the refraction (or thin-walled
/// straight-through) direction when the material transmits.
fn binning_for(p: &PbrParams, wo: Vec3, wide: bool) -> Binning {
    if wide {
        return Binning::Sphere(SphereBins {
            n_theta: 40,
            n_phi: 40,
        });
    }
    let wo = wo.as_dvec3();
    let front = wo.z > 0.0;
    let spread = 2.0 * ggx_alpha(p.roughness);
    let refl = DVec3::new(-wo.x, -wo.y, wo.z);
    let trans = if p.transmission > 0.0 {
        if p.thin_walled {
            DVec3::new(-wo.x, -wo.y, -wo.z)
        } else {
            let eta = if front {
                p.ior as f64
            } else {
                1.0 / p.ior as f64
            };
            let sin_t = (1.0 - wo.z * wo.z).sqrt() / eta;
            if sin_t >= 1.0 {
                DVec3::new(-1.0, 0.0, 0.0)
            } else {
                let cos_t = (1.0 - sin_t * sin_t).sqrt();
                DVec3::new(-sin_t, 0.0, if front { -cos_t } else { cos_t })
            }
        }
    } else {
        DVec3::new(refl.x, refl.y, -refl.z)
    };
    let (up, down) = if front { (refl, trans) } else { (trans, refl) };
    Binning::Zoom(Box::new((
        HemiGrid::new(true, up, spread, 32, 32),
        HemiGrid::new(false, down, spread, 32, 32),
    )))
}

/// The chi-square run of `p` on a surface of normal `normal`, at `wo_local` in its frame.
fn run_chi2_tilted(
    p: PbrParams,
    normal: Vec3,
    wo_local: Vec3,
    wide: bool,
    n: usize,
    seed: u64,
) -> RunStats {
    let frame = TestFrame::new(normal);
    let b = Bsdf::new(p, frame.n, frame.n, None);
    let wo = frame.to_world(wo_local);
    let bins = binning_for(&p, wo_local, wide);
    let (to_local, to_world) = (|v| frame.to_local(v), |v| frame.to_world(v));
    let frames = Frame {
        to_local: &to_local,
        to_world: &to_world,
    };
    run_chi2(&b, wo, &bins, &frames, n, seed, &|s, _| {
        if !s.delta {
            assert_eq!(
                s.transmitted,
                (s.wi.dot(frame.n) > 0.0) != (wo.dot(frame.n) > 0.0)
            );
        }
    })
}

/// Runs every wo of a configuration and asserts p > 1e-4 and the per-sample consistency.
fn check_config(name: &str, p: PbrParams, normal: Vec3, wide: bool, sides: &[bool], seed: u64) {
    check_view_angles(name, sides, seed, |wo, seed| {
        run_chi2_tilted(p, normal, wo, wide, 1_000_000, seed)
    });
}

const TINT: Vec3 = Vec3::new(0.9, 0.6, 0.3);

#[test]
fn diffuse_sampling_matches_pdf() {
    check_config(
        "diffuse",
        PbrParams::diffuse(TINT),
        Vec3::Z,
        true,
        &[true, false],
        1,
    );
}

#[test]
fn metal_sampling_matches_pdf() {
    check_config(
        "metal r=0.05 (tilted)",
        metal(TINT, 0.05),
        TILTED,
        false,
        &[true],
        2,
    );
    check_config("metal r=0.3", metal(TINT, 0.3), Vec3::Z, false, &[true], 3);
    check_config(
        "metal r=1",
        metal(TINT, 1.0),
        Vec3::Z,
        true,
        &[true, false],
        4,
    );
}

#[test]
fn plastic_sampling_matches_pdf() {
    check_config(
        "plastic r=0.05",
        plastic(TINT, 0.05),
        Vec3::Z,
        false,
        &[true],
        5,
    );
    check_config(
        "plastic r=0.3",
        plastic(TINT, 0.3),
        Vec3::Z,
        false,
        &[true],
        6,
    );
    check_config(
        "plastic r=1",
        plastic(TINT, 1.0),
        Vec3::Z,
        true,
        &[true, false],
        7,
    );
    // Smooth plastic: only the diffuse lobe is non-delta.
    check_config(
        "plastic r=0 (diffuse part)",
        plastic(TINT, 0.0),
        Vec3::Z,
        true,
        &[true],
        8,
    );
}

#[test]
fn rough_transmission_sampling_matches_pdf() {
    check_config(
        "glass r=0.3 (tilted)",
        glass(TINT, 0.3, false),
        TILTED,
        false,
        &[true, false],
        9,
    );
    check_config(
        "glass r=1",
        glass(TINT, 1.0, false),
        Vec3::Z,
        true,
        &[true, false],
        10,
    );
}

#[test]
fn thin_rough_transmission_sampling_matches_pdf() {
    check_config(
        "thin glass r=0.3",
        glass(TINT, 0.3, true),
        Vec3::Z,
        false,
        &[true, false],
        11,
    );
    check_config(
        "thin glass r=1",
        glass(TINT, 1.0, true),
        Vec3::Z,
        true,
        &[true],
        12,
    );
}

#[test]
fn mixed_material_sampling_matches_pdf() {
    let p = PbrParams {
        base_color: TINT,
        metallic: 0.3,
        roughness: 0.5,
        specular: 0.7,
        specular_color: Vec3::new(1.0, 0.8, 1.2),
        ior: 1.4,
        transmission: 0.5,
        thin_walled: false,
        ..PbrParams::diffuse(Vec3::ZERO)
    };
    check_config("mixed r=0.5 (tilted)", p, TILTED, false, &[true, false], 13);
}

/// The tests can fail: samples of a metal of roughness 0.3 are rejected against the pdf of roughness
/// 0.33, and samples of the mixed material against a pdf whose lobe probabilities are off (the pdf of
/// the same material with metallic 0.35 instead of 0.3).
#[test]
fn chi_square_rejects_a_slightly_wrong_pdf() {
    for (name, drawn, claimed, wo) in [
        (
            "metal r 0.30 vs 0.33",
            metal(TINT, 0.3),
            metal(TINT, 0.33),
            wo_at(0.6, true),
        ),
        (
            "mixed metallic 0.30 vs 0.35",
            PbrParams {
                metallic: 0.3,
                transmission: 0.5,
                roughness: 0.5,
                ..plastic(TINT, 0.5)
            },
            PbrParams {
                metallic: 0.35,
                transmission: 0.5,
                roughness: 0.5,
                ..plastic(TINT, 0.5)
            },
            wo_at(0.6, true),
        ),
    ] {
        let (b, wrong) = (bsdf(drawn), bsdf(claimed));
        let bins = binning_for(&drawn, wo, false);
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
// GGX visible normals

/// Independent f64 reference: D_o(m) = G1(o) max(0, o·m) D(m) / o.z.
fn reference_vndf(alpha: f64, o: DVec3, m: DVec3) -> f64 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let cos2 = m.z * m.z;
    let tan2 = (m.x * m.x + m.y * m.y) / cos2;
    let d = 1.0 / (PI * a2 * cos2 * cos2 * (1.0 + tan2 / a2).powi(2));
    let tan2_o = (1.0 - o.z * o.z) / (o.z * o.z);
    let lambda = 0.5 * ((1.0 + a2 * tan2_o).sqrt() - 1.0);
    let g1 = 1.0 / (1.0 + lambda);
    g1 * o.dot(m).max(0.0) * d / o.z
}

#[test]
fn ggx_visible_normal_sampling_matches_d_wo() {
    let mut failures = Vec::new();
    for (ai, &alpha) in [0.0025f32, 0.09, 0.5, 1.0].iter().enumerate() {
        for (ci, &cos) in [0.95f32, 0.5, 0.1, 0.02].iter().enumerate() {
            let g = Ggx { alpha };
            let o = wo_at(cos, true);
            let s = alpha as f64;
            let bins = Binning::Zoom(Box::new((
                HemiGrid::new(true, DVec3::Z, s, 32, 32),
                HemiGrid::new(false, -DVec3::Z, s, 4, 4),
            )));
            let mut observed = vec![0.0f64; bins.len()];
            let mut rng = Pcg32::new((ai * 10 + ci) as u64, 3);
            let n = 1_000_000;
            for _ in 0..n {
                let m = g.sample_visible_normal(o, Vec2::new(rng.f32(), rng.f32()));
                assert!((m.length() - 1.0).abs() < 1e-4 && m.z >= 0.0);
                observed[bins.bin(m).unwrap()] += 1.0;
            }
            let expected: Vec<f64> = bins
                .integrate(
                    |m| reference_vndf(alpha as f64, o.as_dvec3(), m.as_dvec3().normalize()),
                    &observed,
                )
                .iter()
                .map(|e| e * n as f64)
                .collect();
            let total: f64 = expected.iter().sum::<f64>() / n as f64;
            let chi = chi_square_test(&observed, &expected, 5.0);
            println!(
                "VNDF α {alpha:<6} cos {cos:<4}: p = {:.4} (dof {}), ∫ D_wo = {total:.5}",
                chi.p_value, chi.dof
            );
            // The library's own pdf agrees with the reference.
            for k in 0..100 {
                let m = g.sample_visible_normal(o, Vec2::new(k as f32 / 100.0 + 0.003, 0.37));
                let r = reference_vndf(alpha as f64, o.as_dvec3(), m.as_dvec3());
                assert!(((g.visible_normal_pdf(o, m) as f64 - r) / r).abs() < 1e-3);
            }
            if chi.p_value <= MIN_P || (total - 1.0).abs() > 5e-3 {
                failures.push((alpha, cos, chi.p_value, total));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

// ---------------------------------------------------------------------------------------------
// Energy

/// Mean and standard error of the BSDF weights (rejected samples count as 0), per channel. With
/// `flux`, a refracted weight is multiplied by (n_i / n_o)², undoing the radiance scaling.
fn furnace(p: PbrParams, wo: Vec3, n: usize, seed: u64, flux: bool) -> (Vec3, Vec3) {
    let b = bsdf(p);
    let mut rng = Pcg32::new(seed, 11);
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    let ratio2 = if wo.z > 0.0 {
        p.ior * p.ior
    } else {
        1.0 / (p.ior * p.ior)
    };
    for _ in 0..n {
        let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) else {
            continue;
        };
        let mut w = s.weight.as_dvec3();
        if flux && s.transmitted && !p.thin_walled {
            w *= ratio2 as f64;
        }
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(DVec3::ZERO);
    (mean.as_vec3(), (var / n as f64).as_vec3().map(f32::sqrt))
}

#[test]
fn white_furnace_never_creates_energy() {
    let white = Vec3::ONE;
    let mixed = PbrParams {
        base_color: white,
        metallic: 0.3,
        roughness: 0.5,
        specular: 0.7,
        specular_color: Vec3::ONE,
        ior: 1.4,
        transmission: 0.5,
        thin_walled: false,
        ..PbrParams::diffuse(Vec3::ZERO)
    };
    let mut configs: Vec<(String, PbrParams, bool)> =
        vec![("diffuse".into(), PbrParams::diffuse(white), true)];
    for r in [0.0f32, 0.05, 0.3, 0.6, 1.0] {
        configs.push((format!("metal r={r}"), metal(white, r), true));
        configs.push((format!("plastic r={r}"), plastic(white, r), true));
    }
    for r in [0.0f32, 0.05, 0.3, 1.0] {
        configs.push((format!("glass r={r}"), glass(white, r, false), false));
        configs.push((format!("thin glass r={r}"), glass(white, r, true), false));
    }
    configs.push(("mixed r=0.5".into(), mixed, false));
    let mut failures = Vec::new();
    for (k, (name, p, front_only)) in configs.iter().enumerate() {
        let sides: &[bool] = if *front_only { &[true] } else { &[true, false] };
        for &front in sides {
            let mut line = format!("{name:<18} {}:", if front { "front" } else { "back " });
            for (ci, &c) in [1.0f32, 0.9, 0.7, 0.5, 0.3, 0.15, 0.05, 0.02]
                .iter()
                .enumerate()
            {
                let wo = wo_at(c, front);
                let seed = (k * 100 + ci * 2 + front as usize) as u64;
                let (mean, se) = furnace(*p, wo, 400_000, seed, true);
                let m = mean.max_element();
                let bound = 1.0 + 1e-3 + 4.0 * se.max_element();
                line += &format!(" {m:.4}");
                if m > bound {
                    failures.push(format!("{name} front={front} cos={c}: {mean} ± {se}"));
                }
                // The opaque dielectric hands the diffuse exactly what the specular layer leaves, up to
                // the conservative margin of the albedo tables.
                if name.starts_with("plastic") && m < 0.97 - 4.0 * se.max_element() {
                    failures.push(format!("{name} cos={c}: loses energy: {mean}"));
                }
            }
            println!("{line}");
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn radiance_scaling_of_refraction_is_one_over_eta_squared() {
    // From inside, the raw furnace exceeds 1 (radiance gains ior² leaving the glass along the path's
    // reverse); flux-weighted it is 1 for the smooth dielectric, whose interface loses nothing.
    let p = glass(Vec3::ONE, 0.0, false);
    for front in [true, false] {
        for c in [1.0f32, 0.8, 0.5] {
            let wo = wo_at(c, front);
            let (raw, _) = furnace(p, wo, 100_000, 5, false);
            let (flux, _) = furnace(p, wo, 100_000, 5, true);
            let f = fresnel_ref(c as f64, if front { 1.5 } else { 1.0 / 1.5 });
            let eta2 = if front { 2.25 } else { 1.0 / 2.25 };
            println!(
                "smooth glass front={front} cos {c}: raw {:.4} (expected ≈ {:.4}), flux {:.4}",
                raw.x,
                f + (1.0 - f) / eta2,
                flux.x
            );
            assert!((flux.x as f64 - 1.0).abs() < 1e-5);
            assert!((raw.x as f64 - (f + (1.0 - f) / eta2)).abs() < 0.01);
        }
    }
}

/// Independent f64 reference of the exact unpolarised Fresnel reflectance (eta = n_t / n_i).
fn fresnel_ref(cos_i: f64, eta: f64) -> f64 {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

#[test]
fn smooth_dielectric_reflects_the_exact_fresnel_fraction() {
    let p = glass(Vec3::ONE, 0.0, false);
    let b = bsdf(p);
    let n = 200_000;
    // Critical angle from inside: cos θc = √(1 − 1/1.5²) ≈ 0.745.
    for (front, c) in [
        (true, 1.0f32),
        (true, 0.8),
        (true, 0.5),
        (true, 0.2),
        (true, 0.05),
        (false, 1.0),
        (false, 0.9),
        (false, 0.8),
        (false, 0.76),
        (false, 0.73),
        (false, 0.5),
        (false, 0.1),
    ] {
        let wo = wo_at(c, front);
        let eta = if front { 1.5 } else { 1.0 / 1.5 };
        let f = fresnel_ref(c as f64, eta);
        let mut rng = Pcg32::new(c.to_bits() as u64, front as u64);
        let mut reflected = 0usize;
        for _ in 0..n {
            let s = b
                .sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32()))
                .expect("smooth glass always scatters");
            assert!(s.delta);
            if s.transmitted {
                // Snell's law and the 1/η² radiance scaling.
                let sin_o = (1.0 - c * c).sqrt();
                let sin_i = (1.0 - s.wi.z * s.wi.z).max(0.0).sqrt();
                assert!(
                    (sin_o - eta as f32 * sin_i).abs() < 1e-4,
                    "Snell: {sin_o} vs {eta} · {sin_i}"
                );
                assert!((s.weight.x - (1.0 / (eta * eta)) as f32).abs() < 1e-4 * s.weight.x);
            } else {
                reflected += 1;
                assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-5);
                assert!((s.weight.x - 1.0).abs() < 1e-4);
            }
        }
        let frac = reflected as f64 / n as f64;
        let sigma = (f * (1.0 - f) / n as f64).sqrt();
        println!("smooth dielectric front={front} cos {c:<4}: reflected {frac:.5}, Fresnel {f:.5} (σ {sigma:.1e})");
        if f == 1.0 {
            assert_eq!(reflected, n, "total internal reflection");
        } else {
            assert!(
                (frac - f).abs() <= 5.0 * sigma + 1e-6,
                "front={front} cos={c}: {frac} vs {f}"
            );
        }
    }
    // Thin walls: the transmitted ray goes straight through with weight 1 − F.
    let thin = bsdf(glass(Vec3::ONE, 0.0, true));
    let wo = wo_at(0.5, true);
    let f = fresnel_ref(0.5, 1.5);
    let mut rng = Pcg32::new(3, 3);
    let (mut t, mut total) = (0usize, 0.0f64);
    for _ in 0..n {
        let s = thin
            .sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32()))
            .unwrap();
        if s.transmitted {
            t += 1;
            assert!((s.wi + wo).length() < 1e-6);
        }
        total += s.weight.x as f64;
    }
    let frac = t as f64 / n as f64;
    println!(
        "thin smooth glass cos 0.5: transmitted {frac:.5}, 1 − F = {:.5}, furnace {:.6}",
        1.0 - f,
        total / n as f64
    );
    assert!((frac - (1.0 - f)).abs() < 5.0 * (f * (1.0 - f) / n as f64).sqrt());
    assert!((total / n as f64 - 1.0).abs() < 1e-5);
}

#[test]
fn lambertian_furnace_is_exactly_the_albedo() {
    for albedo in [Vec3::ONE, Vec3::new(0.8, 0.5, 0.1), Vec3::ZERO] {
        let b = bsdf(PbrParams::diffuse(albedo));
        assert!(b.has_non_delta() == (albedo != Vec3::ZERO) || albedo == Vec3::ZERO);
        for front in [true, false] {
            let wo = wo_at(0.3, front);
            let mut rng = Pcg32::new(17, front as u64);
            let (mut sum, mut count) = (DVec3::ZERO, 0usize);
            let n = 200_000;
            for _ in 0..n {
                let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) else {
                    continue;
                };
                assert_eq!(
                    s.weight, albedo,
                    "every Lambertian sample weighs exactly the albedo"
                );
                assert!(!s.transmitted && !s.delta);
                assert!((b.eval(wo, s.wi) / s.pdf - albedo).abs().max_element() < 1e-6);
                sum += s.weight.as_dvec3();
                count += 1;
            }
            // cos θi = 0 exactly is the only rejection; at 24-bit inputs it essentially never happens.
            assert!(count as f64 > 0.9999 * n as f64);
            let mean = sum / count as f64;
            println!("Lambertian albedo {albedo}: furnace {mean}");
            assert!((mean - albedo.as_dvec3()).abs().max_element() < 1e-12);
        }
    }
    // The same surface through the general path (specular 0 but a metal-free, transmission-free
    // material that is not flagged Lambertian cannot exist): check eval directly instead.
    let b = bsdf(PbrParams {
        roughness: 0.3,
        ..PbrParams::diffuse(Vec3::new(0.5, 0.25, 1.0))
    });
    let wo = wo_at(0.4, true);
    let wi = Vec3::new(-0.3, 0.2, (1.0f32 - 0.13).sqrt());
    let e = b.eval(wo, wi);
    assert!(
        (e - Vec3::new(0.5, 0.25, 1.0) * wi.z / std::f32::consts::PI)
            .abs()
            .max_element()
            < 1e-7
    );
}

#[test]
fn light_never_leaks_through_the_geometric_surface() {
    // Shading normal tilted 40° from the geometric one: directions above the geometric surface can be
    // below the shading one.
    let ng = Vec3::Z;
    let ns = Vec3::new(0.64, 0.0, 0.77).normalize();
    let mut rng = Pcg32::new(23, 5);
    let materials = [
        plastic(TINT, 0.4),
        metal(TINT, 0.2),
        glass(TINT, 0.4, false),
        glass(TINT, 0.4, true),
        glass(TINT, 0.0, false),
        PbrParams::diffuse(TINT),
    ];
    for p in materials {
        let b = Bsdf::new(p, ns, ng, None);
        let transmits = p.transmission > 0.0;
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
            let same_side = (wo.dot(ng) > 0.0) == (wi.dot(ng) > 0.0);
            let e = b.eval(wo, wi);
            if !transmits && !same_side {
                assert_eq!(e, Vec3::ZERO, "{p:?}: opaque surface leaks");
                assert_eq!(b.pdf(wo, wi), 0.0);
            }
            if let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) {
                let geo_transmitted = (wo.dot(ng) > 0.0) != (s.wi.dot(ng) > 0.0);
                assert_eq!(
                    s.transmitted, geo_transmitted,
                    "{p:?}: sampled side disagrees with the geometry"
                );
                assert!(transmits || !geo_transmitted, "{p:?}: opaque sample leaked");
                if !s.delta {
                    let (e, pdf) = b.eval_pdf(wo, s.wi);
                    let rel = ((pdf - s.pdf) / s.pdf).abs().max(
                        ((e / pdf - s.weight).abs().max_element())
                            / s.weight.max_element().max(1e-6),
                    );
                    worst = worst.max(rel);
                }
            }
        }
        println!("leak guard {:?} metallic {} transmission {} thin {}: worst weight/pdf mismatch {worst:.1e}", p.roughness, p.metallic, p.transmission, p.thin_walled);
        assert!(worst < 1e-3);
    }
}
