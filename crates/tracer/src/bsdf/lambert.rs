//! The Lambertian (diffuse) lobe: f = albedo / π, sampled by cosine-weighted directions.

use crate::sampling::sample_cosine_hemisphere;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// f · cos θi of a white Lambertian lobe (`cos_i` against the shading normal, ≥ 0).
#[inline]
pub(super) fn eval(cos_i: f32) -> f32 {
    cos_i * FRAC_1_PI
}

/// Density of [`sample`] (equal to [`eval`]: the lobe is sampled exactly).
#[inline]
pub(super) fn pdf(cos_i: f32) -> f32 {
    cos_i * FRAC_1_PI
}

/// Cosine-weighted direction in the upper hemisphere of the local frame.
#[inline]
pub(super) fn sample(u: Vec2) -> Vec3 {
    sample_cosine_hemisphere(u)
}

#[cfg(test)]
mod tests {
    use crate::bsdf::{Bsdf, PbrParams};
    use crate::sampling::sample_uniform_sphere;
    use glam::{Vec2, Vec3};

    /// The Lambertian shortcut (two dot products) gives exactly the cos θi of the general
    /// local-frame path, with the same rejections (shading and geometric normals disagreeing,
    /// grazing and opposite-side pairs), and eval/pdf/sample built on it agree with each other.
    #[test]
    fn the_lambertian_shortcut_is_the_general_local_pair() {
        let mut u = crate::testing::uniform_stream(0x2545_f491_4f6c_dd1du64);
        let albedo = Vec3::new(0.8, 0.5, 0.2);
        let mut agreed = 0;
        for case in 0..100_000 {
            let ns = sample_uniform_sphere(Vec2::new(u(), u()));
            // A geometric normal up to ~60° off the shading normal, so the guard rejects some pairs.
            let ng = (ns + sample_uniform_sphere(Vec2::new(u(), u())) * 0.9).normalize_or(ns);
            let bsdf = Bsdf::new(PbrParams::diffuse(albedo), ns, ng, None);
            assert!(bsdf.single_lobe());
            let wo = sample_uniform_sphere(Vec2::new(u(), u()));
            let wi = if case % 7 == 0 {
                // Exactly in the shading plane.
                (wo - ns * wo.dot(ns)).normalize_or(Vec3::X)
            } else {
                sample_uniform_sphere(Vec2::new(u(), u()))
            };
            let general = bsdf
                .local_pair(wo, wi)
                .map(|(_, i, _)| i.z)
                .filter(|&z| z > 0.0);
            let short = bsdf.lambert_cos_i(wo, wi);
            assert_eq!(
                short.map(f32::to_bits),
                general.map(f32::to_bits),
                "ns {ns:?} ng {ng:?} wo {wo:?} wi {wi:?}"
            );
            let (f, pdf) = bsdf.eval_pdf(wo, wi);
            assert_eq!(f, bsdf.eval(wo, wi));
            assert_eq!(pdf, bsdf.pdf(wo, wi));
            match short {
                Some(c) => {
                    agreed += 1;
                    assert_eq!(pdf, super::pdf(c));
                    assert_eq!(f, albedo * super::eval(c));
                }
                None => assert_eq!((f, pdf), (Vec3::ZERO, 0.0)),
            }
            // A sampled direction is one the shortcut accepts, with the same pdf (up to the
            // rounding of the round trip from the local frame to the world and back).
            if let Some(bs) = bsdf.sample(wo, 0.0, Vec2::new(u(), u())) {
                let back = bsdf.pdf(wo, bs.wi);
                assert!(
                    (bs.pdf - back).abs() <= 1e-5 * bs.pdf.max(1e-3),
                    "wo {wo:?} wi {:?}: {} against {back}",
                    bs.wi,
                    bs.pdf
                );
            }
        }
        assert!(
            agreed > 20_000 && agreed < 80_000,
            "{agreed} pairs accepted"
        );
    }
}
