//! [`Bsdf::eval`] and [`Bsdf::pdf`] of every material but the pure Lambertian: the lobes' values
//! and densities in the local frame, the layers' (coat, sheen) added on top.

use super::clearcoat::to_coat;
use super::dielectric::refraction_half_vector;
use super::{conductor, lambert, Bsdf, LayerTerms, WoTerms};
use glam::Vec3;

impl Bsdf {
    /// The public queries of every material but the pure Lambertian, out of line: the
    /// Lambertian's short paths (`lambert.rs`) are inlined into the integrator, this is not.
    /// Materials with layers take a copy of their own (`LAYERED`), so that the others run the code
    /// they ran before the layers existed.
    #[inline(never)]
    pub(super) fn general_eval_pdf<const EVAL: bool, const PDF: bool>(
        &self,
        wo: Vec3,
        wi: Vec3,
    ) -> (Vec3, f32) {
        if self.layered {
            return self.layered_eval_pdf::<EVAL, PDF>(wo, wi);
        }
        self.general_eval_pdf_in::<EVAL, PDF, false>(wo, wi, |co| self.row.lookup(co))
    }

    /// [`Bsdf::general_eval_pdf`] of a material with layers.
    #[inline(never)]
    pub(super) fn layered_eval_pdf<const EVAL: bool, const PDF: bool>(
        &self,
        wo: Vec3,
        wi: Vec3,
    ) -> (Vec3, f32) {
        self.general_eval_pdf_in::<EVAL, PDF, true>(wo, wi, |co| self.row.lookup(co))
    }

    /// `albedo_terms`: the GGX albedo table's (A, B) at cos θo (`AlbedoRow::lookup`, or the same
    /// values looked up before, as the wavefront's lanes do).
    #[inline(always)]
    pub(super) fn general_eval_pdf_in<const EVAL: bool, const PDF: bool, const LAYERED: bool>(
        &self,
        wo: Vec3,
        wi: Vec3,
        albedo_terms: impl FnOnce(f32) -> (f32, f32),
    ) -> (Vec3, f32) {
        let Some((o, i, entering)) = self.local_pair(wo, wi) else {
            return (Vec3::ZERO, 0.0);
        };
        let eta = self.interface.eta(entering);
        let s = if entering { 1.0 } else { -1.0 };
        let t = self.wo_terms::<LAYERED>(o, s, eta, albedo_terms);
        self.eval_pdf_local::<EVAL, PDF, LAYERED>(o, i, eta, &t)
    }

    /// f·|cos θi| and/or the pdf of the non-delta lobes, in the local frame with `o.z > 0`.
    #[inline(always)]
    pub(super) fn eval_pdf_local<const EVAL: bool, const PDF: bool, const LAYERED: bool>(
        &self,
        o: Vec3,
        i: Vec3,
        eta: f32,
        t: &WoTerms,
    ) -> (Vec3, f32) {
        let (f, pdf) = self.base_eval_pdf_local::<EVAL, PDF>(o, i, eta, t);
        if !LAYERED {
            return (f, pdf);
        }
        self.layer_eval_pdf::<EVAL, PDF>(o, i, &t.layers, f, pdf)
    }

    /// Adds the clear coat's and the sheen's lobes to the base's `f` (scaled here by the layers'
    /// base weight) and `pdf`.
    #[inline(never)]
    pub(super) fn layer_eval_pdf<const EVAL: bool, const PDF: bool>(
        &self,
        o: Vec3,
        i: Vec3,
        t: &LayerTerms,
        f: Vec3,
        pdf: f32,
    ) -> (Vec3, f32) {
        let (mut f, mut pdf) = (f * t.base, pdf);
        if i.z <= 0.0 {
            return (f, pdf);
        }
        if self.coat_on && !self.coat.smooth && t.oc.z > 0.0 {
            let (oc, ic) = (t.oc, to_coat(&t.coat_frame, i));
            let h = (oc + ic).normalize_or_zero();
            let g = &self.coat.ggx;
            if EVAL && ic.z > 0.0 {
                f += Vec3::splat(t.coat_f * g.d(h) * g.vis(oc, ic) * ic.z);
            }
            if PDF {
                pdf += t.p_coat * g.reflection_pdf(oc, h);
            }
        }
        if self.sheen_on {
            if EVAL {
                let e = self.sheen.eval(o, i, t.sheen_lambda_o);
                f += (t.sheen_w * e) * self.sheen.color;
            }
            if PDF {
                pdf += t.p_sheen * lambert::pdf(i.z);
            }
        }
        (f, pdf)
    }

    /// [`Bsdf::eval_pdf_local`] of the material under the layers (all of it, without layers).
    #[inline(always)]
    pub(super) fn base_eval_pdf_local<const EVAL: bool, const PDF: bool>(
        &self,
        o: Vec3,
        i: Vec3,
        eta: f32,
        t: &WoTerms,
    ) -> (Vec3, f32) {
        let base = self.params.base_color;
        let mut f = Vec3::ZERO;
        let mut pdf = 0.0;
        let trans_rough = self.trans_on && !self.trans_smooth;
        if i.z > 0.0 {
            if EVAL {
                f += (t.kd * lambert::eval(i.z)) * base;
            }
            if PDF {
                pdf += t.p[0] * lambert::pdf(i.z);
            }
            if !self.spec_smooth && (self.spec_on || trans_rough) {
                let h = (o + i).normalize();
                let oh = o.dot(h).max(0.0);
                let d = self.ggx.d(h);
                let split = if trans_rough {
                    Some(self.interface.split(oh, eta, base))
                } else {
                    None
                };
                if EVAL {
                    let mut c = self.w_metal * conductor::fresnel(base, oh)
                        + (self.w_base * self.layer.weight) * self.layer.fresnel(oh);
                    if let Some(sp) = split {
                        c += self.w_trans * sp.r;
                    }
                    f += c * (d * self.ggx.vis(o, i) * i.z);
                }
                if PDF {
                    let rp = self.ggx.reflection_pdf(o, h);
                    pdf += t.p[1] * rp;
                    if let Some(sp) = split {
                        pdf += t.p[2] * rp * sp.p_r;
                    }
                }
            }
        } else if trans_rough {
            if self.interface.thin {
                // The reflection lobe mirrored through the surface.
                let ir = Vec3::new(i.x, i.y, -i.z);
                let h = (o + ir).normalize();
                let d = self.ggx.d(h);
                let sp = self.interface.split(o.dot(h).max(0.0), eta, base);
                if EVAL {
                    f = (self.w_trans * d * self.ggx.vis(o, ir) * ir.z) * sp.t;
                }
                if PDF {
                    pdf = t.p[2] * (1.0 - sp.p_r) * self.ggx.reflection_pdf(o, h);
                }
            } else if let Some((m, om, im)) = refraction_half_vector(o, i, eta) {
                let sp = self.interface.split(om, eta, base);
                let d = self.ggx.d(m);
                let den = om + eta * im;
                let den2 = den * den;
                if EVAL {
                    // f_t |cos θi| = T D G2 |i·m| (o·m) / (cos θo (o·m + η i·m)²); the η² of the
                    // Jacobian cancels against the 1/η² of radiance transport.
                    f = (self.w_trans * d * self.ggx.g2(o, i) * -im * om / (o.z * den2)) * sp.t;
                }
                if PDF {
                    pdf = t.p[2]
                        * (1.0 - sp.p_r)
                        * self.ggx.visible_normal_pdf(o, m)
                        * eta
                        * eta
                        * -im
                        / den2;
                }
            }
        }
        (f, pdf)
    }
}
