//! Statistical tests of the layers on the glTF material: KHR_materials_clearcoat's GGX coat and
//! KHR_materials_sheen's "Charlie" sheen. `sample()` draws directions with exactly the density
//! `pdf()` claims (Pearson chi-square over direction bins, at several roughnesses and angles, with a
//! coat normal that differs from the shading normal too), every sample's weight is `eval / pdf`, the
//! white furnace never creates energy and gives what the layering formulas predict, and the tests
//! reject a slightly wrong pdf.
//!
//! Run with `--nocapture` to see the p-values and furnace values.

#[path = "../common/mod.rs"]
mod common;

use common::bins::{Binning, HemiGrid};
use common::bsdf_chi2::{check_view_angles, p_right_and_wrong, run_chi2, wo_at, MIN_P, WORLD};
use common::Pcg32;
use glam::{DVec3, Vec2, Vec3};
use pathfarm_tracer::bsdf::{Bsdf, PbrParams};
use pathfarm_tracer::stats::SphereBins;

mod energy;
mod sampling;

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
