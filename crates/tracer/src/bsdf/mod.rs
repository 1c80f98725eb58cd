//! Scattering at surfaces: the glTF 2.0 metallic-roughness BSDF (core spec Appendix B, with
//! KHR_materials_specular, _ior, _transmission, _clearcoat and _sheen).
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
//! Two layers go on top of f, in the order the extensions define (clear coat over sheen over the
//! material):
//!
//!   f_layered = c F_c(|wo·nc|) · coat + (1 − c F_c(|wo·nc|)) · [sheen_color · sheen
//!               + (1 − max(sheen_color) · E_sheen(cos θo)) · f],
//!
//! - coat (`clearcoat.rs`): KHR_materials_clearcoat's GGX layer of ior 1.5 (f0 = 0.04) with its
//!   own roughness and normal (nc: its normal map, else the interpolated normal); the extension's
//!   `fresnel_coat` weighs coat and base by the same Fresnel at the view direction, which conserves
//!   energy as written, so it is used unchanged;
//! - sheen (`sheen.rs`): KHR_materials_sheen's "Charlie" lobe (Estevez & Kulla 2017) with the
//!   extension's albedo scaling of everything under it, in its wo-only form, E_sheen from a
//!   conservative table (energy conserving as long as the table never underestimates the albedo);
//!   where E_sheen exceeds 1 (grazing views, low roughness) the lobe is divided by it and E_sheen
//!   in the base's weight is taken as 1.
//!
//! Sampling chooses one of three lobes — diffuse (cosine), GGX reflection (metal + specular layer,
//! visible normals) and the interface (visible normals, then reflect or refract by the Fresnel split)
//! — plus, where the layers are on, the coat (GGX visible normals about nc, or its mirror) and the
//! sheen (cosine), with probabilities proportional to their directional albedos at wo (exact, or
//! from the albedo tables when rough), so no lobe that contributes is ever given probability zero.
//! The layers' lobes take the top of the lobe choice's range, and everything about them sits behind
//! one flag, so a material without them samples and evaluates to the same bits as before they
//! existed. The pure Lambertian material (metallic = specular = transmission = clearcoat = 0 and a
//! black sheen) takes a short path everywhere (`lambert.rs`); every other material's queries are
//! in `eval.rs` ([`Bsdf::eval`], [`Bsdf::pdf`]) and `sample.rs` ([`Bsdf::sample`]).

mod albedo;
mod clearcoat;
mod conductor;
mod dielectric;
mod eval;
mod fresnel;
mod glossy;
mod lambert;
pub mod microfacet;
mod params;
mod sample;
mod sheen;
mod specular_layer;

pub use params::PbrParams;

pub(crate) use glossy::GlossyLobes;

pub(crate) use lambert::at as lambert_at;

use crate::math::Frame;
use albedo::AlbedoRow;
use clearcoat::{to_coat, Coat};
use dielectric::{Interface, INDEX_MATCHED};
use glam::{Vec2, Vec3};
use microfacet::Ggx;
use sheen::Sheen;
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
    /// KHR_materials_clearcoat (`clearcoat.rs`).
    coat: Coat,
    /// KHR_materials_sheen (`sheen.rs`).
    sheen: Sheen,
    coat_on: bool,
    sheen_on: bool,
    /// A clear coat or a sheen: the base is weighted per wo and the layers' lobes are added.
    layered: bool,
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
    /// The layers' terms (neutral without layers).
    layers: LayerTerms,
}

/// The quantities of the clear coat and the sheen that depend on wo only.
#[derive(Clone, Copy, Debug)]
struct LayerTerms {
    /// Weight of everything under the layers:
    /// (1 − clearcoat · F(wo · nc)) · (1 − max(sheenColor) · E_sheen(cos θo)).
    base: f32,
    /// Weight of the sheen lobe: 1 − clearcoat · F(wo · nc), divided by E_sheen(cos θo) where that
    /// exceeds 1.
    sheen_w: f32,
    /// clearcoat · F(wo · nc), the coat lobe's weight.
    coat_f: f32,
    /// Probabilities of choosing the coat and the sheen lobes.
    p_coat: f32,
    p_sheen: f32,
    /// Λ(cos θo) of the sheen's visibility.
    sheen_lambda_o: f32,
    /// The coat's frame (inside the shading frame) when its normal is not the shading normal, and
    /// wo in it.
    coat_frame: Option<Frame>,
    oc: Vec3,
}

impl LayerTerms {
    const NONE: LayerTerms = LayerTerms {
        base: 1.0,
        sheen_w: 1.0,
        coat_f: 0.0,
        p_coat: 0.0,
        p_sheen: 0.0,
        sheen_lambda_o: 0.0,
        coat_frame: None,
        oc: Vec3::Z,
    };
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
    /// Parameters are sanitised: factors clamped to [0, 1], base and sheen colours to ≥ 0, a
    /// non-finite ior becomes 1.5 and an ior below 1 becomes 1. [`Bsdf::params`] returns the
    /// sanitised values. The clear coat's normal is `ns` (see [`Bsdf::with_coat_normal`]).
    pub fn new(params: PbrParams, ns: Vec3, ng: Vec3, tangent: Option<Vec3>) -> Self {
        Self::with_coat_normal(params, ns, ng, tangent, ns)
    }

    /// [`Bsdf::new`] with the clear coat's own unit normal `coat_normal` (front side): the
    /// interpolated normal, or the one its clearcoatNormalTexture gives, while `ns` may carry the
    /// base's normal map. Without a clear coat it plays no part.
    pub fn with_coat_normal(
        params: PbrParams,
        ns: Vec3,
        ng: Vec3,
        tangent: Option<Vec3>,
        coat_normal: Vec3,
    ) -> Self {
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
            clearcoat: clamp01(params.clearcoat),
            clearcoat_roughness: clamp01(params.clearcoat_roughness),
            sheen_color: params.sheen_color.max(Vec3::ZERO),
            sheen_roughness: clamp01(params.sheen_roughness),
        };
        let base_max = p.base_color.max_element();
        let coat_on = p.clearcoat > 0.0;
        let sheen_on = p.sheen_color.max_element() > 0.0;
        if p.metallic == 0.0 && p.specular == 0.0 && p.transmission == 0.0 && !coat_on && !sheen_on
        {
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
                coat: Coat::NONE,
                sheen: Sheen::NONE,
                coat_on: false,
                sheen_on: false,
                layered: false,
            };
        }
        let w_metal = p.metallic;
        let w_base = (1.0 - p.metallic) * (1.0 - p.transmission);
        let w_trans = (1.0 - p.metallic) * p.transmission;
        let layer = SpecularLayer::new(p.ior, p.specular, p.specular_color);
        let interface = Interface::new(p.ior, p.thin_walled, p.specular, p.specular_color);
        let spec_smooth = p.roughness == 0.0;
        let coat = if coat_on {
            // The coat normal in the shading frame, where it differs from the shading normal.
            let n = if coat_normal == ns {
                None
            } else {
                let n = frame.to_local(coat_normal).normalize_or_zero();
                (n != Vec3::ZERO && n.is_finite() && n != Vec3::Z).then_some(n)
            };
            Coat::new(p.clearcoat, p.clearcoat_roughness, n)
        } else {
            Coat::NONE
        };
        let sheen = if sheen_on {
            Sheen::new(p.sheen_color, p.sheen_roughness)
        } else {
            Sheen::NONE
        };
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
            coat,
            sheen,
            coat_on,
            sheen_on,
            layered: coat_on || sheen_on,
        }
    }

    /// The same BSDF at another surface point: exactly `Bsdf::new(params, ns, ng, tangent)` for the
    /// `params` this one was made from, without redoing the work that depends on them alone. A
    /// material whose parameters are not textured makes its BSDF once and moves it to each hit.
    /// (A clear coat's own normal, kept relative to the shading frame, is not moved: only a BSDF
    /// made by [`Bsdf::new`], whose coat normal is the shading normal, may be moved.)
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
            || (self.coat_on && !self.coat.smooth)
            || self.sheen_on
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

    /// Samples wi. `u_lobe` chooses the lobe (and, remapped, reflection against refraction); `u`
    /// samples the direction within it.
    #[inline(always)]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.lambert {
            return self.lambert_sample(wo, u);
        }
        self.general_sample(wo, u_lobe, u)
    }

    /// True when the geometric normal agrees with the shading frame on whether (wo, wi) is a
    /// reflection or a transmission.
    #[inline(always)]
    fn guard(&self, wo: Vec3, wi: Vec3, lo_z: f32, li_z: f32) -> bool {
        guard(self.ng, wo, wi, lo_z, li_z)
    }

    /// Local directions with wo mirrored into the upper hemisphere (the lobes are isotropic, so the
    /// mirror through the tangent plane changes nothing), and whether wo is on the front side.
    #[inline(always)]
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

    /// Diffuse weight and lobe probabilities for the local (mirrored) wo `o` (`o.z` > 0) on the
    /// side `s` (±1) of the shading surface; `albedo_terms(o.z)` gives the rough lobe's albedo
    /// terms (`AlbedoRow::lookup`).
    #[inline(always)]
    fn wo_terms<const LAYERED: bool>(
        &self,
        o: Vec3,
        s: f32,
        eta: f32,
        albedo_terms: impl FnOnce(f32) -> (f32, f32),
    ) -> WoTerms {
        let co = o.z;
        let mut layers = LayerTerms::NONE;
        let (mut est_c, mut est_sh) = (0.0, 0.0);
        if LAYERED {
            (layers, est_c, est_sh) = self.layer_terms(o, s);
        }
        let base = self.params.base_color;
        let (kd, est_s) = if self.spec_smooth {
            let fl = self.layer.fresnel(co);
            let kd = self.w_base * self.layer.diffuse_factor_smooth(fl);
            let m =
                self.w_metal * conductor::mirror(base, co) + (self.w_base * self.layer.weight) * fl;
            (kd, mean(m))
        } else {
            let ab = albedo_terms(co);
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
        let (est_d, est_s, est_t, sum) = if LAYERED {
            let b = layers.base;
            let (d, s, t) = (est_d * b, est_s * b, est_t * b);
            (d, s, t, d + s + t + est_c + est_sh)
        } else {
            (est_d, est_s, est_t, est_d + est_s + est_t)
        };
        let p = if sum > 0.0 {
            // Without the interface, p_t is 0 (as 0 / sum): written so that a BSDF whose
            // `trans_on` is a constant (`GlossyLobes::at`) drops the interface's branches.
            let p_t = if self.trans_on { est_t / sum } else { 0.0 };
            [est_d / sum, est_s / sum, p_t]
        } else {
            [0.0; 3]
        };
        if sum > 0.0 && LAYERED {
            layers.p_coat = est_c / sum;
            layers.p_sheen = est_sh / sum;
        }
        WoTerms { kd, p, layers }
    }

    /// The layers' wo terms, and the estimated albedos of the coat and the sheen lobes.
    #[inline]
    fn layer_terms(&self, o: Vec3, s: f32) -> (LayerTerms, f32, f32) {
        let mut t = LayerTerms::NONE;
        let (mut est_c, mut est_sh) = (0.0, 0.0);
        if self.coat_on {
            t.coat_frame = self.coat.frame(s);
            t.oc = to_coat(&t.coat_frame, o);
            t.coat_f = self.coat.weight_at(t.oc.z);
            t.sheen_w = 1.0 - t.coat_f;
            t.base = t.sheen_w;
            if t.oc.z > 0.0 {
                est_c = t.coat_f * self.coat.lobe_albedo(t.oc.z);
            }
        }
        if self.sheen_on {
            // Above an albedo of 1 (grazing views at low roughness, see `sheen.rs`) the lobe is
            // scaled down to reflect at most its colour, and the base gets nothing.
            let e = self.sheen.albedo(o.z);
            let e1 = e.min(1.0);
            est_sh = t.sheen_w * self.sheen.mean() * e1;
            t.base *= 1.0 - self.sheen.max() * e1;
            if e > 1.0 {
                t.sheen_w /= e;
            }
            t.sheen_lambda_o = self.sheen.lambda(o.z);
        }
        (t, est_c, est_sh)
    }
}
