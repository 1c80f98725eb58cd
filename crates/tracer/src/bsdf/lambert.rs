//! The Lambertian (diffuse) lobe: f = albedo / π, sampled by cosine-weighted directions.

use super::{Bsdf, BsdfSample};
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

/// The pure Lambertian at one surface point, as free functions of what it reads (the shading frame,
/// the geometric normal and the albedo): the [`Bsdf`] methods below call them, and so does the
/// wavefront integrator, which keeps these quantities in lanes rather than in a `Bsdf`. One body of
/// code for both is what makes the two integrators' bits the same.
pub(crate) mod at {
    use super::{pdf, sample, BsdfSample};
    use crate::bsdf::guard;
    use crate::math::Frame;
    use glam::{Vec2, Vec3};

    /// What the general local pair gives the Lambertian lobe: cos θi on wo's side of the shading
    /// surface (normal `n`), when it is positive and the pair passes the same tests. The lobe needs
    /// only the two z components, so the other four dot products are not computed (the values are
    /// the same bits: `to_local`'s z is the same dot product).
    #[inline(always)]
    pub(crate) fn cos_i(n: Vec3, ng: Vec3, wo: Vec3, wi: Vec3) -> Option<f32> {
        let (lo_z, li_z) = (wo.dot(n), wi.dot(n));
        if lo_z == 0.0
            || li_z == 0.0
            || lo_z.is_nan()
            || li_z.is_nan()
            || !guard(ng, wo, wi, lo_z, li_z)
        {
            return None;
        }
        let cos_i = if lo_z > 0.0 { li_z } else { -li_z };
        (cos_i > 0.0).then_some(cos_i)
    }

    /// f · cos θi and the pdf of [`sample`] for the pair (wo, wi).
    #[inline(always)]
    pub(crate) fn eval_pdf(n: Vec3, ng: Vec3, albedo: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        match cos_i(n, ng, wo, wi) {
            Some(c) => (albedo * super::eval(c), pdf(c)),
            None => (Vec3::ZERO, 0.0),
        }
    }

    /// A cosine-weighted direction about the shading normal on wo's side.
    #[inline(always)]
    pub(crate) fn sample_wi(
        frame: &Frame,
        ng: Vec3,
        albedo: Vec3,
        wo: Vec3,
        u: Vec2,
    ) -> Option<BsdfSample> {
        // Only cos θo (its sign) matters to the Lambertian lobe: one dot product, not three.
        let lo_z = wo.dot(frame.z);
        if lo_z == 0.0 || lo_z.is_nan() {
            return None;
        }
        let s = if lo_z > 0.0 { 1.0 } else { -1.0 };
        let i = sample(u);
        if i.z <= 0.0 {
            return None;
        }
        let li = i * Vec3::new(1.0, 1.0, s);
        // What `Bsdf::finish` does for a non-delta sample.
        let pdf = pdf(i.z);
        if li.z == 0.0 || pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        let wi = frame.to_world(li);
        if !guard(ng, wo, wi, lo_z, li.z) {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight: albedo,
            pdf,
            delta: false,
            transmitted: (li.z > 0.0) != (lo_z > 0.0),
        })
    }
}

/// The pure Lambertian's short paths of the [`Bsdf`] queries, inlined into the integrator.
impl Bsdf {
    #[inline(always)]
    #[cfg(test)]
    pub(super) fn lambert_cos_i(&self, wo: Vec3, wi: Vec3) -> Option<f32> {
        at::cos_i(self.frame.z, self.ng, wo, wi)
    }

    /// [`Bsdf::eval_pdf`] of the pure Lambertian.
    #[inline(always)]
    pub(super) fn lambert_eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        at::eval_pdf(self.frame.z, self.ng, self.params.base_color, wo, wi)
    }

    /// [`Bsdf::sample`] of the pure Lambertian.
    #[inline(always)]
    pub(super) fn lambert_sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        at::sample_wi(&self.frame, self.ng, self.params.base_color, wo, u)
    }
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
