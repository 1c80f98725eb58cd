//! Sampling matches the pdf: chi-square of each material's samples, and its power to reject.

use super::*;

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
