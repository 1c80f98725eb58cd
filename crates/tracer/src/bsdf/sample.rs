//! [`Bsdf::sample`] of every material but the pure Lambertian: the lobe's choice by its albedo,
//! the direction within it, and the sample's weight and density from the whole mixture.

use super::clearcoat::from_coat;
use super::{conductor, dielectric, fresnel, lambert, mirror, Bsdf, BsdfSample};
use glam::{Vec2, Vec3};

impl Bsdf {
    /// [`Bsdf::sample`] for every material but the pure Lambertian, out of line (materials with
    /// layers in a copy of their own).
    #[inline(never)]
    pub(super) fn general_sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.layered {
            return self.layered_sample(wo, u_lobe, u);
        }
        self.general_sample_in::<false>(wo, u_lobe, u, |co| self.row.lookup(co))
    }

    /// [`Bsdf::general_sample`] of a material with layers.
    #[inline(never)]
    pub(super) fn layered_sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        self.general_sample_in::<true>(wo, u_lobe, u, |co| self.row.lookup(co))
    }

    /// `albedo_terms` as in [`Bsdf::general_eval_pdf_in`].
    #[inline(always)]
    pub(super) fn general_sample_in<const LAYERED: bool>(
        &self,
        wo: Vec3,
        u_lobe: f32,
        u: Vec2,
        albedo_terms: impl FnOnce(f32) -> (f32, f32),
    ) -> Option<BsdfSample> {
        let lo = self.frame.to_local(wo);
        if lo.z == 0.0 || lo.z.is_nan() {
            return None;
        }
        let s = if lo.z > 0.0 { 1.0 } else { -1.0 };
        let o = Vec3::new(lo.x, lo.y, lo.z.abs());
        let eta = self.interface.eta(lo.z > 0.0);
        let t = self.wo_terms::<LAYERED>(o, s, eta, albedo_terms);
        let [p_d, p_s, p_t] = t.p;
        let lt = &t.layers;
        let p_base = p_d + p_s + p_t;
        let p_layers = lt.p_coat + lt.p_sheen;
        if p_base + p_layers <= 0.0 {
            return None;
        }
        let unflip = |i: Vec3| Vec3::new(i.x, i.y, i.z * s);
        let (i, transmit) = if LAYERED && p_layers > 0.0 && u_lobe >= p_base {
            // The layers' lobes take the top of u_lobe's range, so that a material without them
            // chooses among the others exactly as before.
            if u_lobe < p_base + lt.p_coat || lt.p_sheen == 0.0 {
                if self.coat.smooth {
                    let i = from_coat(&lt.coat_frame, mirror(lt.oc));
                    if i.z <= 0.0 {
                        // Mirrored below the shading surface by a tilted coat normal: lost.
                        return None;
                    }
                    let w = Vec3::splat(lt.coat_f / lt.p_coat);
                    return self.finish(wo, lo.z, unflip(i), w, lt.p_coat, true);
                }
                let m = self.coat.ggx.sample_visible_normal(lt.oc, u);
                (
                    from_coat(&lt.coat_frame, dielectric::reflect(lt.oc, m)),
                    false,
                )
            } else {
                (lambert::sample(u), false)
            }
        } else if u_lobe < p_d {
            (lambert::sample(u), false)
        } else if u_lobe < p_d + p_s || p_t == 0.0 {
            if self.spec_smooth {
                let m = self.w_metal * conductor::mirror(self.params.base_color, o.z)
                    + (self.w_base * self.layer.weight) * self.layer.fresnel(o.z);
                let m = if LAYERED { m * lt.base } else { m };
                return self.finish(wo, lo.z, unflip(mirror(o)), m / p_s, p_s, true);
            }
            (
                dielectric::reflect(o, self.ggx.sample_visible_normal(o, u)),
                false,
            )
        } else {
            let u2 = ((u_lobe - p_d - p_s) / p_t).clamp(0.0, 1.0);
            let base = self.params.base_color;
            if self.trans_smooth {
                // Under the layers.
                let w_trans = if LAYERED {
                    self.w_trans * lt.base
                } else {
                    self.w_trans
                };
                let sp = self.interface.split(o.z, eta, base);
                if u2 < sp.p_r {
                    let pdf = p_t * sp.p_r;
                    return self.finish(
                        wo,
                        lo.z,
                        unflip(mirror(o)),
                        w_trans * sp.r / pdf,
                        pdf,
                        true,
                    );
                }
                let pdf = p_t * (1.0 - sp.p_r);
                if self.interface.thin {
                    return self.finish(wo, lo.z, -lo, w_trans * sp.t / pdf, pdf, true);
                }
                let i = fresnel::refract(o, Vec3::Z, eta)?;
                return self.finish(
                    wo,
                    lo.z,
                    unflip(i),
                    w_trans * sp.t / (eta * eta * pdf),
                    pdf,
                    true,
                );
            }
            let m = self.ggx.sample_visible_normal(o, u);
            let sp = self.interface.split(o.dot(m), eta, base);
            let r = dielectric::reflect(o, m);
            if u2 < sp.p_r {
                (r, false)
            } else if self.interface.thin {
                (Vec3::new(r.x, r.y, -r.z), true)
            } else {
                (fresnel::refract(o, m, eta)?, true)
            }
        };
        // A direction sampled on the wrong side (a reflection below the horizon, a refraction that
        // grazes back up) is lost: `pdf` accounts for it.
        if i.z == 0.0 || (i.z < 0.0) != transmit {
            return None;
        }
        // Evaluate at the world-space wi that is returned, exactly as `eval_pdf(wo, wi)` does (same
        // inputs, same code), so that weight = eval / pdf holds to the last bit even where rounding
        // in the change of frame matters (near the horizon).
        let wi = self.frame.to_world(unflip(i));
        let li = self.frame.to_local(wi);
        if li.z == 0.0 || li.z.is_nan() || !self.guard(wo, wi, lo.z, li.z) {
            return None;
        }
        let i = Vec3::new(li.x, li.y, li.z * s);
        let (f, pdf) = self.eval_pdf_local::<true, true, LAYERED>(o, i, eta, &t);
        if pdf.is_nan() || pdf <= 0.0 || crate::math::is_black(f) {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight: f / pdf,
            pdf,
            delta: false,
            transmitted: (li.z > 0.0) != (lo.z > 0.0),
        })
    }

    /// Maps a local sample back to world space, applies the light-leak guard and packs it.
    #[inline(always)]
    pub(super) fn finish(
        &self,
        wo: Vec3,
        lo_z: f32,
        li: Vec3,
        weight: Vec3,
        pdf: f32,
        delta: bool,
    ) -> Option<BsdfSample> {
        if li.z == 0.0 || pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        let wi = self.frame.to_world(li);
        if !self.guard(wo, wi, lo_z, li.z) {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight,
            pdf,
            delta,
            transmitted: (li.z > 0.0) != (lo_z > 0.0),
        })
    }
}
