//! Sampling of the layers matches their pdf: chi-square at several roughnesses and angles.

use super::*;

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
