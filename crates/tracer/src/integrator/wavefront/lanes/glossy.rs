//! The glossy materials in the lanes (`bsdf::GlossyLobes`: a rough metal, a Lambertian base under
//! a rough specular layer, or a mix): each lane's lobes loaded one array per value, with the
//! albedo table's values at its cos θo, so that the vector steps make the lane's BSDF again
//! (`GlossyLobes::at`) and run its queries beside the Lambertian's, keeping the glossy lanes'
//! results. The lanes of a general material (`general.rs`) ride along: their BSDF's values,
//! computed lane by lane, replace the vector code's.

use super::{Lanes, B, F, LANES, V3};
use crate::bsdf::{Bsdf, GlossyLobes};
use crate::math::is_black;
use glam::{Vec2, Vec3};

/// Every lane's glossy lobes (zero where the lane's material is not glossy: `on` false).
pub(super) struct GlossyLanes<'a> {
    /// The lane's material is glossy.
    pub on: B,
    /// The lane's BSDF values are this struct's (`eval_pdf`, `eval`): a glossy or a general
    /// material's.
    pub shaded: B,
    /// Each lane's BSDF, where its material is general (`Lanes::general`).
    general: Option<&'a [Option<Bsdf>; LANES]>,
    base_color: V3,
    alpha: F,
    weight: F,
    f0: V3,
    f0_max: F,
    f0_mean: F,
    w_metal: F,
    w_base: F,
    mean_base: F,
    diffuse_on: B,
    spec_on: B,
    /// The albedo table's (A, B) at the lane's cos θo.
    terms_a: F,
    terms_b: F,
    /// The lanes' tangents, where some mesh has them (`Lanes::tangent`).
    tangent: Option<V3>,
}

impl<'a> GlossyLanes<'a> {
    /// No lane glossy.
    #[inline(always)]
    pub(super) fn none() -> Self {
        GlossyLanes {
            on: [false; LANES],
            shaded: [false; LANES],
            general: None,
            base_color: V3::ZERO,
            alpha: [0.0; LANES],
            weight: [0.0; LANES],
            f0: V3::ZERO,
            f0_max: [0.0; LANES],
            f0_mean: [0.0; LANES],
            w_metal: [0.0; LANES],
            w_base: [0.0; LANES],
            mean_base: [0.0; LANES],
            diffuse_on: [false; LANES],
            spec_on: [false; LANES],
            terms_a: [0.0; LANES],
            terms_b: [0.0; LANES],
            tangent: None,
        }
    }

    /// Loads each lane's lobes from its material, and the albedo table's values at cos θo =
    /// |wo · ns| (wo = −d), which the BSDF looks up with the same value (`to_local`'s z). Scalar
    /// loads and gathers, kept out of the vector loops.
    #[inline(always)]
    pub(super) fn load(
        lobes: impl Fn(usize) -> Option<GlossyLobes>,
        ns: &V3,
        d: &V3,
        tangent: Option<V3>,
        general: Option<&'a [Option<Bsdf>; LANES]>,
    ) -> Self {
        let mut g = Self::none();
        g.tangent = tangent;
        g.general = general;
        if let Some(general) = general {
            g.shaded = std::array::from_fn(|i| general[i].is_some());
        }
        for i in 0..LANES {
            let Some(l) = lobes(i) else {
                continue;
            };
            g.on[i] = true;
            g.shaded[i] = true;
            g.base_color.set(i, l.base_color);
            g.alpha[i] = l.alpha;
            g.weight[i] = l.weight;
            g.f0.set(i, l.f0);
            g.f0_max[i] = l.f0_max;
            g.f0_mean[i] = l.f0_mean;
            g.w_metal[i] = l.w_metal;
            g.w_base[i] = l.w_base;
            g.mean_base[i] = l.mean_base;
            g.diffuse_on[i] = l.diffuse_on;
            g.spec_on[i] = l.spec_on;
            let wo = -d.get(i);
            (g.terms_a[i], g.terms_b[i]) = l.albedo_terms(wo.dot(ns.get(i)).abs());
        }
        g
    }

    /// Lane `i`'s BSDF at its hit (normals `ns`, `ng`; its frame `ORIENTED` by the lane's
    /// tangent, which `tangent` then holds), and the albedo table's values for its queries
    /// ([`Bsdf::glossy_eval_pdf`], [`Bsdf::glossy_sample`]). The orientation is a constant of
    /// each loop: a choice per lane inside them cost scenes without tangents 5 % (A/B).
    #[inline(always)]
    fn bsdf<const ORIENTED: bool>(&self, i: usize, ns: Vec3, ng: Vec3) -> (Bsdf, (f32, f32)) {
        let lobes = GlossyLobes {
            base_color: self.base_color.get(i),
            alpha: self.alpha[i],
            weight: self.weight[i],
            f0: self.f0.get(i),
            f0_max: self.f0_max[i],
            f0_mean: self.f0_mean[i],
            w_metal: self.w_metal[i],
            w_base: self.w_base[i],
            mean_base: self.mean_base[i],
            diffuse_on: self.diffuse_on[i],
            spec_on: self.spec_on[i],
            // The table's values are given: the row is not read.
            row_k: 0,
            row_fy: 0.0,
        };
        let tangent = match (ORIENTED, &self.tangent) {
            (true, Some(t)) => Some(t.get(i)),
            _ => None,
        };
        (
            lobes.at(ns, ng, tangent),
            (self.terms_a[i], self.terms_b[i]),
        )
    }

    /// `Bsdf::eval_pdf(wo, wi)` of every lane's glossy BSDF (wo = −d), in a loop of its own
    /// with nothing but the BSDF in it (measured faster than inside the light sample's loop:
    /// docs/benchmarks.md, December 6). Lanes that are not glossy compute values never read.
    /// The general lanes' values are their BSDFs' (`Bsdf::eval_pdf`).
    #[inline(always)]
    pub(super) fn eval_pdf(&self, ns: &V3, ng: &V3, d: &V3, wi: &V3) -> (V3, F) {
        let (mut f, mut pdf) = match self.tangent.is_some() {
            // SAFETY: the lanes run only where an `Isa` was detected, and both have AVX2.
            true => unsafe { self.eval_pdf_oriented(ns, ng, d, wi) },
            false => self.eval_pdf_in::<false>(ns, ng, d, wi),
        };
        if let Some(general) = self.general {
            general_eval_pdf(general, d, wi, &mut f, &mut pdf);
        }
        (f, pdf)
    }

    /// [`GlossyLanes::eval_pdf`]'s values of f alone, as `Bsdf::eval` gives them (the lamps'
    /// sample, `direct_punctual`'s): the glossy lanes' from the same code, the general lanes'
    /// from `Bsdf::eval`.
    #[inline(always)]
    pub(super) fn eval(&self, ns: &V3, ng: &V3, d: &V3, wi: &V3) -> V3 {
        let mut f = match self.tangent.is_some() {
            // SAFETY: as in `eval_pdf`.
            true => unsafe { self.eval_pdf_oriented(ns, ng, d, wi) }.0,
            false => self.eval_pdf_in::<false>(ns, ng, d, wi).0,
        };
        if let Some(general) = self.general {
            general_eval(general, d, wi, &mut f);
        }
        f
    }

    /// [`GlossyLanes::eval_pdf`] in frames oriented by the tangents: out of line, so that the
    /// scenes without tangents keep their steps as they were (inlined, it cost them 2 %), and
    /// compiled for AVX2 (the steps' builds' common set, `builds.rs`; out of line and for the
    /// baseline, it cost the scenes with tangents a fifth).
    #[cfg_attr(
        target_arch = "x86_64",
        target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")
    )]
    unsafe fn eval_pdf_oriented(&self, ns: &V3, ng: &V3, d: &V3, wi: &V3) -> (V3, F) {
        self.eval_pdf_in::<true>(ns, ng, d, wi)
    }

    #[inline(always)]
    fn eval_pdf_in<const ORIENTED: bool>(&self, ns: &V3, ng: &V3, d: &V3, wi: &V3) -> (V3, F) {
        let (mut f, mut pdf) = (V3::ZERO, [0.0; LANES]);
        for (i, pdf) in pdf.iter_mut().enumerate() {
            let (bsdf, terms) = self.bsdf::<ORIENTED>(i, ns.get(i), ng.get(i));
            let fi;
            (fi, *pdf) = bsdf.glossy_eval_pdf(-d.get(i), wi.get(i), terms);
            f.set(i, fi);
        }
        (f, pdf)
    }

    /// `Bsdf::sample(wo, u_lobe, u)` of every lane's glossy BSDF, as [`GlossyLanes::eval_pdf`]:
    /// the direction, weight and density where `ok`, the sample being kept only with a weight
    /// that is not black (`trace_path`'s filter).
    #[inline(always)]
    pub(super) fn sample(&self, ns: &V3, ng: &V3, d: &V3, u: [&F; 3]) -> Sample {
        match self.tangent.is_some() {
            // SAFETY: as in `eval_pdf`.
            true => unsafe { self.sample_oriented(ns, ng, d, u) },
            false => self.sample_in::<false>(ns, ng, d, u),
        }
    }

    /// [`GlossyLanes::sample`] in oriented frames, built as [`GlossyLanes::eval_pdf_oriented`].
    #[cfg_attr(
        target_arch = "x86_64",
        target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")
    )]
    unsafe fn sample_oriented(&self, ns: &V3, ng: &V3, d: &V3, u: [&F; 3]) -> Sample {
        self.sample_in::<true>(ns, ng, d, u)
    }

    #[inline(always)]
    fn sample_in<const ORIENTED: bool>(&self, ns: &V3, ng: &V3, d: &V3, u: [&F; 3]) -> Sample {
        let mut s = Sample {
            wi: V3::ZERO,
            weight: V3::ZERO,
            pdf: [0.0; LANES],
            ok: [false; LANES],
        };
        let [u_lobe, u0, u1] = u;
        for i in 0..LANES {
            let (bsdf, terms) = self.bsdf::<ORIENTED>(i, ns.get(i), ng.get(i));
            let bs = bsdf.glossy_sample(-d.get(i), u_lobe[i], Vec2::new(u0[i], u1[i]), terms);
            let bs = bs.filter(|bs| !is_black(bs.weight));
            s.ok[i] = bs.is_some();
            let (wi, weight, pdf) =
                bs.map_or((Vec3::Z, Vec3::ZERO, 0.0), |bs| (bs.wi, bs.weight, bs.pdf));
            s.wi.set(i, wi);
            s.weight.set(i, weight);
            s.pdf[i] = pdf;
        }
        s
    }
}

/// The general lanes' `Bsdf::eval_pdf(wo, wi)` (wo = −d) in place of the vector code's: out of
/// line, a scalar loop over the few lanes that have one.
#[inline(never)]
fn general_eval_pdf(general: &[Option<Bsdf>; LANES], d: &V3, wi: &V3, f: &mut V3, pdf: &mut F) {
    for (i, bsdf) in general.iter().enumerate() {
        if let Some(bsdf) = bsdf {
            let fi;
            (fi, pdf[i]) = bsdf.eval_pdf(-d.get(i), wi.get(i));
            f.set(i, fi);
        }
    }
}

/// The general lanes' `Bsdf::eval(wo, wi)`, as [`general_eval_pdf`].
#[inline(never)]
fn general_eval(general: &[Option<Bsdf>; LANES], d: &V3, wi: &V3, f: &mut V3) {
    for (i, bsdf) in general.iter().enumerate() {
        if let Some(bsdf) = bsdf {
            f.set(i, bsdf.eval(-d.get(i), wi.get(i)));
        }
    }
}

/// Each lane's BSDF sample (`GlossyLanes::sample`).
pub(super) struct Sample {
    pub wi: V3,
    pub weight: V3,
    pub pdf: F,
    pub ok: B,
}

impl Lanes<'_> {
    /// The lanes' glossy lobes at their hits (`shade_hit` has set `ns`; `d` is still the ray
    /// that found the hit).
    /// The general lanes' BSDFs ride along (`GlossyLanes::shaded`).
    #[inline(always)]
    pub(super) fn glossy_lanes(&self) -> GlossyLanes<'_> {
        let tangent = self.tangents.then_some(self.tangent);
        let general = self.any_general.then_some(&*self.general);
        GlossyLanes::load(|i| self.lobes(i), &self.ns, &self.d, tangent, general)
    }

    /// Lane `i`'s tangent for its BSDF's frame (`Bsdf::at`), where some mesh has tangents.
    #[inline(always)]
    pub(super) fn frame_tangent(&self, i: usize) -> Option<Vec3> {
        self.tangents.then(|| self.tangent.get(i))
    }

    /// Lane `i`'s glossy lobes: its material's, or, for a textured material, those of its hit's
    /// texel (loaded by `trace_closest`).
    #[inline(always)]
    pub(super) fn lobes(&self, i: usize) -> Option<GlossyLobes> {
        let m = &self.materials[self.material[i] as usize];
        match m.textured {
            false => m.glossy,
            true => self.texel_lobes[i],
        }
    }
}
