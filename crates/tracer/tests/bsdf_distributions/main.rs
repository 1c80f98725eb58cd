//! Statistical tests of the BSDF: `sample()` draws directions with exactly the density `pdf()` claims
//! (Pearson chi-square over direction bins), every sample's weight is `eval / pdf`, the white furnace
//! never creates energy, the smooth dielectric reflects its exact Fresnel fraction, and GGX
//! visible-normal sampling follows D_wo(m).
//!
//! Run with `--nocapture` to see the p-values and furnace values.

#[path = "../common/mod.rs"]
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

mod energy;
mod sampling;
mod vndf;

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
