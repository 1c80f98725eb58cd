//! Scattering at surfaces: the glTF 2.0 metallic-roughness BSDF (core spec Appendix B, with
//! KHR_materials_specular, _ior and _transmission).
//!
//! Contract of [`Bsdf`] (every implementation detail below serves it):
//! - Directions are world-space unit vectors pointing *away* from the surface (`wo` towards the
//!   viewer, `wi` towards the light). `ns` and `ng` are given on the surface's front side; `wo` may be
//!   on either side.
//! - [`Bsdf::eval`] returns f(wo, wi) · |cos θi| (cosine against the shading normal) for the
//!   non-delta lobes only; delta lobes (roughness 0 mirror and refraction) evaluate to zero.
//! - [`Bsdf::pdf`] returns the solid-angle density with which [`Bsdf::sample`] produces `wi` through its
//!   non-delta lobes (including the probability of choosing those lobes).
//! - [`Bsdf::sample`] returns a direction and weight = f·|cos|/pdf. For non-delta samples `pdf` is
//!   exactly `Bsdf::pdf(wo, wi)` and `weight` exactly `eval / pdf` (the full mixture, not the sampled
//!   lobe alone, so MIS is consistent); for delta samples `pdf` is the discrete probability of the
//!   chosen delta lobe and `weight` its throughput divided by it.
//! - Light never leaks: reflection requires wo and wi on the same side of the *geometric* normal,
//!   transmission on opposite sides; otherwise eval is zero (and such directions are never sampled).
//!   The lobes themselves are evaluated in the shading frame, with the sides of wo and wi taken from
//!   the shading normal; a pair whose shading and geometric sides disagree is dropped.
//! - Energy: ∫ eval dwi ≤ 1 per channel for every wo with a white base colour (white furnace), except
//!   for the radiance scaling of refraction below: transmitted radiance is scaled by 1/η², so for a
//!   volume the flux-weighted furnace ∫ eval · (n_i/n_o)² dwi (n_o, n_i the indices on the sides of
//!   wo and wi) is the one bounded by 1; seen from inside, the raw integral may reach ior².
//! - Radiance transport: refraction into a denser medium (along the path) scales radiance by 1/η²,
//!   η = n_t / n_i, as pbrt-v4's `DielectricBxDF` in radiance mode.
//!
//! The model, per glTF: with α = roughness² (roughness 0 ⇒ delta lobes; α ≥ 10⁻⁴ otherwise),
//!
//!   f = metallic · metal + (1 − metallic) · [(1 − transmission) · fresnel_mix(diffuse, specular)
//!       + transmission · dielectric_interface],
//!
//! - metal (`conductor.rs`): F_schlick(base_color, v·h) · D · V, GGX with height-correlated Smith
//!   ([`microfacet`], `albedo.rs` for its directional albedo);
//! - fresnel_mix (`specular_layer.rs`): KHR_materials_specular's layer, with the diffuse weighted by
//!   1 − specular · max E(cos θo), the layer's directional albedo, instead of glTF's
//!   1 − specular · max F(v·h), which is not energy conserving at grazing angles (see that module);
//! - dielectric_interface (`dielectric.rs`, `fresnel.rs`): exact Fresnel with total internal
//!   reflection, smooth or rough (Walter et al. 2007) refraction through a volume, or thin-walled
//!   transmission.
//!
//! Sampling chooses one of three lobes — diffuse (cosine), GGX reflection (metal + specular layer,
//! visible normals) and the interface (visible normals, then reflect or refract by the Fresnel split)
//! — with probabilities proportional to their directional albedos at wo (exact, or from the albedo
//! tables when rough), so no lobe that contributes is ever given probability zero. The pure
//! Lambertian material (metallic = specular = transmission = 0) takes a short path everywhere.

mod albedo;
mod conductor;
mod dielectric;
mod fresnel;
mod lambert;
pub mod microfacet;
mod params;
mod specular_layer;

pub use params::PbrParams;

pub(crate) use lambert::at as lambert_at;

use crate::math::Frame;
use albedo::AlbedoRow;
use dielectric::{refraction_half_vector, Interface, INDEX_MATCHED};
use glam::{Vec2, Vec3};
use microfacet::Ggx;
use specular_layer::SpecularLayer;

/// One sampled scattering direction.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    /// f · |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle pdf (non-delta) or discrete lobe probability (delta).
    pub pdf: f32,
    /// Sampled from a delta lobe (perfect mirror or refraction).
    pub delta: bool,
    /// `wi` is on the other side of the surface from `wo`.
    pub transmitted: bool,
}

/// The BSDF at one surface point. Everything that does not depend on the directions is precomputed
/// by [`Bsdf::new`].
#[derive(Clone, Copy, Debug)]
pub struct Bsdf {
    frame: Frame,
    ng: Vec3,
    params: PbrParams,
    ggx: Ggx,
    row: AlbedoRow,
    layer: SpecularLayer,
    interface: Interface,
    /// Lobe weights: metallic, (1 − metallic)(1 − transmission), (1 − metallic) transmission.
    w_metal: f32,
    w_base: f32,
    w_trans: f32,
    mean_base: f32,
    /// Pure Lambertian: metallic = specular = transmission = 0.
    lambert: bool,
    /// Roughness 0: the metal and the specular layer are mirrors.
    spec_smooth: bool,
    /// The interface is a delta (roughness 0, or an index-matched volume).
    trans_smooth: bool,
    diffuse_on: bool,
    spec_on: bool,
    trans_on: bool,
}

/// True when the geometric normal `ng` agrees with the shading frame (wo and wi at heights `lo_z`
/// and `li_z` in it) on whether (wo, wi) is a reflection or a transmission: the light-leak guard.
#[inline(always)]
pub(crate) fn guard(ng: Vec3, wo: Vec3, wi: Vec3, lo_z: f32, li_z: f32) -> bool {
    let (go, gi) = (wo.dot(ng), wi.dot(ng));
    go != 0.0 && gi != 0.0 && ((go > 0.0) == (gi > 0.0)) == ((lo_z > 0.0) == (li_z > 0.0))
}

/// The quantities that depend on wo only.
#[derive(Clone, Copy, Debug)]
struct WoTerms {
    /// Weight of the diffuse lobe: (1 − metallic)(1 − transmission) · (1 − specular · max E(wo)).
    kd: f32,
    /// Probabilities of choosing the diffuse, GGX-reflection and interface lobes.
    p: [f32; 3],
}

/// The local frame of the lobes: the shading normal, oriented by the tangent where there is one.
#[inline]
fn shading_frame(ns: Vec3, tangent: Option<Vec3>) -> Frame {
    match tangent {
        Some(t) => Frame::from_zx(ns, t),
        None => Frame::from_z(ns),
    }
}

#[inline]
fn mean(v: Vec3) -> f32 {
    v.element_sum() * (1.0 / 3.0)
}

#[inline]
fn mirror(o: Vec3) -> Vec3 {
    Vec3::new(-o.x, -o.y, o.z)
}

impl Bsdf {
    /// `ns`: unit shading normal; `ng`: unit geometric normal, both on the front side;
    /// `tangent`: optional shading tangent (the model is isotropic: it only orients the frame).
    ///
    /// Parameters are sanitised: factors clamped to [0, 1], base colour to ≥ 0, a non-finite ior
    /// becomes 1.5 and an ior below 1 becomes 1. [`Bsdf::params`] returns the sanitised values.
    pub fn new(params: PbrParams, ns: Vec3, ng: Vec3, tangent: Option<Vec3>) -> Self {
        let frame = shading_frame(ns, tangent);
        let clamp01 = |x: f32| if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
        let p = PbrParams {
            base_color: params.base_color.max(Vec3::ZERO),
            metallic: clamp01(params.metallic),
            roughness: clamp01(params.roughness),
            specular: clamp01(params.specular),
            specular_color: params.specular_color.max(Vec3::ZERO),
            ior: if params.ior.is_finite() {
                params.ior.max(1.0)
            } else {
                1.5
            },
            transmission: clamp01(params.transmission),
            thin_walled: params.thin_walled,
        };
        let base_max = p.base_color.max_element();
        if p.metallic == 0.0 && p.specular == 0.0 && p.transmission == 0.0 {
            // The pure Lambertian (the Cornell box): nothing else to precompute.
            return Bsdf {
                frame,
                ng,
                params: p,
                ggx: Ggx { alpha: 1.0 },
                row: AlbedoRow::NONE,
                layer: SpecularLayer::NONE,
                interface: Interface::NONE,
                w_metal: 0.0,
                w_base: 1.0,
                w_trans: 0.0,
                mean_base: mean(p.base_color),
                lambert: true,
                spec_smooth: false,
                trans_smooth: true,
                diffuse_on: base_max > 0.0,
                spec_on: false,
                trans_on: false,
            };
        }
        let w_metal = p.metallic;
        let w_base = (1.0 - p.metallic) * (1.0 - p.transmission);
        let w_trans = (1.0 - p.metallic) * p.transmission;
        let layer = SpecularLayer::new(p.ior, p.specular, p.specular_color);
        let interface = Interface::new(p.ior, p.thin_walled, p.specular, p.specular_color);
        let spec_smooth = p.roughness == 0.0;
        Bsdf {
            frame,
            ng,
            params: p,
            ggx: Ggx::from_roughness(p.roughness),
            row: AlbedoRow::new(p.roughness),
            layer,
            interface,
            w_metal,
            w_base,
            w_trans,
            mean_base: mean(p.base_color),
            lambert: false,
            spec_smooth,
            trans_smooth: spec_smooth || (!p.thin_walled && p.ior - 1.0 < INDEX_MATCHED),
            diffuse_on: w_base > 0.0 && base_max > 0.0,
            spec_on: w_metal > 0.0 || (w_base > 0.0 && p.specular > 0.0),
            trans_on: w_trans > 0.0
                && (base_max > 0.0 || p.specular * interface.tint.max_element() > 0.0),
        }
    }

    /// The same BSDF at another surface point: exactly `Bsdf::new(params, ns, ng, tangent)` for the
    /// `params` this one was made from, without redoing the work that depends on them alone. A
    /// material whose parameters are not textured makes its BSDF once and moves it to each hit.
    #[inline]
    pub fn at(&self, ns: Vec3, ng: Vec3, tangent: Option<Vec3>) -> Self {
        Bsdf {
            frame: shading_frame(ns, tangent),
            ng,
            ..*self
        }
    }

    pub fn params(&self) -> &PbrParams {
        &self.params
    }

    /// True if [`Bsdf::sample`] ignores its lobe choice (`u_lobe`): the pure Lambertian.
    pub fn single_lobe(&self) -> bool {
        self.lambert
    }

    /// True if some lobe is not a delta (light sampling can contribute).
    pub fn has_non_delta(&self) -> bool {
        self.diffuse_on
            || (self.spec_on && !self.spec_smooth)
            || (self.trans_on && !self.trans_smooth)
    }

    /// True if a non-delta lobe transmits (direct lighting must consider both hemispheres).
    pub fn has_non_delta_transmission(&self) -> bool {
        self.trans_on && !self.trans_smooth && self.mean_base > 0.0
    }

    /// f(wo, wi) · |cos θi| of the non-delta lobes.
    #[inline(always)]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if self.lambert {
            return self.lambert_eval_pdf(wo, wi).0;
        }
        self.general_eval_pdf::<true, false>(wo, wi).0
    }

    /// Solid-angle density of [`Bsdf::sample`] producing `wi` through a non-delta lobe.
    #[inline(always)]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.lambert {
            return self.lambert_eval_pdf(wo, wi).1;
        }
        self.general_eval_pdf::<false, true>(wo, wi).1
    }

    /// [`Bsdf::eval`] and [`Bsdf::pdf`] together, sharing their work (for light sampling with MIS).
    #[inline(always)]
    pub fn eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        if self.lambert {
            return self.lambert_eval_pdf(wo, wi);
        }
        self.general_eval_pdf::<true, true>(wo, wi)
    }

    /// The public queries of every material but the pure Lambertian, out of line: the
    /// Lambertian's short paths (`lambert.rs`) are inlined into the integrator, this is not.
    #[inline(never)]
    fn general_eval_pdf<const EVAL: bool, const PDF: bool>(
        &self,
        wo: Vec3,
        wi: Vec3,
    ) -> (Vec3, f32) {
        let Some((o, i, entering)) = self.local_pair(wo, wi) else {
            return (Vec3::ZERO, 0.0);
        };
        let eta = self.interface.eta(entering);
        let t = self.wo_terms(o.z, eta);
        self.eval_pdf_local::<EVAL, PDF>(o, i, eta, &t)
    }

    /// Samples wi. `u_lobe` chooses the lobe (and, remapped, reflection against refraction); `u`
    /// samples the direction within it.
    #[inline(always)]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.lambert {
            return self.lambert_sample(wo, u);
        }
        self.general_sample(wo, u_lobe, u)
    }

    /// [`Bsdf::sample`] for every material but the pure Lambertian, out of line.
    #[inline(never)]
    fn general_sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let lo = self.frame.to_local(wo);
        if lo.z == 0.0 || lo.z.is_nan() {
            return None;
        }
        let s = if lo.z > 0.0 { 1.0 } else { -1.0 };
        let o = Vec3::new(lo.x, lo.y, lo.z.abs());
        let eta = self.interface.eta(lo.z > 0.0);
        let t = self.wo_terms(o.z, eta);
        let [p_d, p_s, p_t] = t.p;
        if p_d + p_s + p_t <= 0.0 {
            return None;
        }
        let unflip = |i: Vec3| Vec3::new(i.x, i.y, i.z * s);
        let (i, transmit) = if u_lobe < p_d {
            (lambert::sample(u), false)
        } else if u_lobe < p_d + p_s || p_t == 0.0 {
            if self.spec_smooth {
                let m = self.w_metal * conductor::mirror(self.params.base_color, o.z)
                    + (self.w_base * self.layer.weight) * self.layer.fresnel(o.z);
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
                let sp = self.interface.split(o.z, eta, base);
                if u2 < sp.p_r {
                    let pdf = p_t * sp.p_r;
                    return self.finish(
                        wo,
                        lo.z,
                        unflip(mirror(o)),
                        self.w_trans * sp.r / pdf,
                        pdf,
                        true,
                    );
                }
                let pdf = p_t * (1.0 - sp.p_r);
                if self.interface.thin {
                    return self.finish(wo, lo.z, -lo, self.w_trans * sp.t / pdf, pdf, true);
                }
                let i = fresnel::refract(o, Vec3::Z, eta)?;
                return self.finish(
                    wo,
                    lo.z,
                    unflip(i),
                    self.w_trans * sp.t / (eta * eta * pdf),
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
        let (f, pdf) = self.eval_pdf_local::<true, true>(o, i, eta, &t);
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
    #[inline]
    fn finish(
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

    /// True when the geometric normal agrees with the shading frame on whether (wo, wi) is a
    /// reflection or a transmission.
    #[inline]
    fn guard(&self, wo: Vec3, wi: Vec3, lo_z: f32, li_z: f32) -> bool {
        guard(self.ng, wo, wi, lo_z, li_z)
    }

    /// Local directions with wo mirrored into the upper hemisphere (the lobes are isotropic, so the
    /// mirror through the tangent plane changes nothing), and whether wo is on the front side.
    #[inline]
    fn local_pair(&self, wo: Vec3, wi: Vec3) -> Option<(Vec3, Vec3, bool)> {
        let lo = self.frame.to_local(wo);
        let li = self.frame.to_local(wi);
        if lo.z == 0.0
            || li.z == 0.0
            || lo.z.is_nan()
            || li.z.is_nan()
            || !self.guard(wo, wi, lo.z, li.z)
        {
            return None;
        }
        let s = if lo.z > 0.0 { 1.0 } else { -1.0 };
        Some((
            Vec3::new(lo.x, lo.y, lo.z * s),
            Vec3::new(li.x, li.y, li.z * s),
            lo.z > 0.0,
        ))
    }

    /// Diffuse weight and lobe probabilities for cos θo = `co` (> 0).
    #[inline]
    fn wo_terms(&self, co: f32, eta: f32) -> WoTerms {
        let base = self.params.base_color;
        let (kd, est_s) = if self.spec_smooth {
            let fl = self.layer.fresnel(co);
            let kd = self.w_base * self.layer.diffuse_factor_smooth(fl);
            let m =
                self.w_metal * conductor::mirror(base, co) + (self.w_base * self.layer.weight) * fl;
            (kd, mean(m))
        } else {
            let ab = self.row.lookup(co);
            let kd = self.w_base * self.layer.diffuse_factor(ab);
            let est = self.w_metal * conductor::mean_albedo(self.mean_base, ab)
                + self.w_base * self.layer.mean_albedo(ab);
            (kd, est)
        };
        let est_d = if self.diffuse_on {
            kd * self.mean_base
        } else {
            0.0
        };
        let est_t = if self.trans_on {
            let sp = self.interface.split(co, eta, base);
            let e = self.w_trans * (mean(sp.r) + mean(sp.t));
            if self.trans_smooth {
                e
            } else {
                // The split at the macro normal only estimates the rough lobe: never let it vanish.
                e.max(1e-3 * self.w_trans)
            }
        } else {
            0.0
        };
        let sum = est_d + est_s + est_t;
        let p = if sum > 0.0 {
            [est_d / sum, est_s / sum, est_t / sum]
        } else {
            [0.0; 3]
        };
        WoTerms { kd, p }
    }

    /// f·|cos θi| and/or the pdf of the non-delta lobes, in the local frame with `o.z > 0`.
    #[inline]
    fn eval_pdf_local<const EVAL: bool, const PDF: bool>(
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
