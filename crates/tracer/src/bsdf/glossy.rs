//! The glossy materials' lobes as plain values, for the wavefront integrator's vector code.
//!
//! A *glossy* material is the glTF metallic-roughness BSDF without its interface, layers or
//! mirrors: a rough metal, or a Lambertian base under a rough specular layer, or a mix of the two
//! (`metallic` between 0 and 1): what a Principled BSDF exported by Blender is unless it is glass,
//! clear-coated, sheened or perfectly smooth. [`GlossyLobes`] holds the few numbers of such a
//! material that its BSDF reads (all of them plain `f32`s, so the lanes keep them one array per
//! field), [`GlossyLobes::at`] makes the material's [`Bsdf`] at a hit again from them, with every
//! flag of the lobes it lacks a constant, and [`Bsdf::glossy_eval_pdf`] and
//! [`Bsdf::glossy_sample`] run the general queries' own code with the albedo table's values
//! looked up before (a table lookup per lane is a gather, kept out of the vector loops). The
//! same code as [`Bsdf::eval_pdf`] and [`Bsdf::sample`] on the same values: the same bits
//! (tested below).

use super::albedo::AlbedoRow;
use super::dielectric::Interface;
use super::microfacet::Ggx;
use super::specular_layer::SpecularLayer;
use super::{clearcoat::Coat, sheen::Sheen};
use super::{shading_frame, Bsdf, BsdfSample, PbrParams};
use glam::{Vec2, Vec3};

/// What a glossy material's [`Bsdf`] reads, as plain values (see the module's doc).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct GlossyLobes {
    pub base_color: Vec3,
    pub alpha: f32,
    /// The specular layer: its weight, tinted f0, and that f0's largest and mean channel.
    pub weight: f32,
    pub f0: Vec3,
    pub f0_max: f32,
    pub f0_mean: f32,
    pub w_metal: f32,
    pub w_base: f32,
    pub mean_base: f32,
    pub diffuse_on: bool,
    pub spec_on: bool,
    /// The albedo table's row (`AlbedoRow`): its index and fraction.
    pub row_k: u16,
    pub row_fy: f32,
}

impl Bsdf {
    /// The lobes of a glossy material (see the module's doc), or None for any other: a pure
    /// Lambertian, a material with a transmission lobe, a clear coat or a sheen, or a smooth one.
    pub(crate) fn glossy_lobes(&self) -> Option<GlossyLobes> {
        let glossy = !self.lambert
            && !self.layered
            && !self.trans_on
            && !self.spec_smooth
            && self.has_non_delta();
        glossy.then(|| {
            let (f0_max, f0_mean) = self.layer.f0_summary();
            let (row_k, row_fy) = self.row.parts();
            GlossyLobes {
                base_color: self.params.base_color,
                alpha: self.ggx.alpha,
                weight: self.layer.weight,
                f0: self.layer.f0,
                f0_max,
                f0_mean,
                w_metal: self.w_metal,
                w_base: self.w_base,
                mean_base: self.mean_base,
                diffuse_on: self.diffuse_on,
                spec_on: self.spec_on,
                row_k,
                row_fy,
            }
        })
    }

    /// [`Bsdf::eval_pdf`] of a glossy material's BSDF (made by [`GlossyLobes::at`]), with the
    /// albedo table's values at cos θo = |wo · ns| given ([`GlossyLobes::albedo_terms`]).
    #[inline(always)]
    pub(crate) fn glossy_eval_pdf(&self, wo: Vec3, wi: Vec3, terms: (f32, f32)) -> (Vec3, f32) {
        self.general_eval_pdf_in::<true, true, false>(wo, wi, |_| terms)
    }

    /// [`Bsdf::sample`] of a glossy material's BSDF, the albedo table's values given as in
    /// [`Bsdf::glossy_eval_pdf`].
    #[inline(always)]
    pub(crate) fn glossy_sample(
        &self,
        wo: Vec3,
        u_lobe: f32,
        u: Vec2,
        terms: (f32, f32),
    ) -> Option<BsdfSample> {
        self.general_sample_in::<false>(wo, u_lobe, u, |_| terms)
    }
}

impl GlossyLobes {
    /// The material's BSDF at a hit: what `Bsdf::at(ns, ng, tangent)` makes of the material's
    /// own, with the lobes it does not have switched off by constants, so that their code folds
    /// away.
    #[inline(always)]
    pub(crate) fn at(&self, ns: Vec3, ng: Vec3, tangent: Option<Vec3>) -> Bsdf {
        Bsdf {
            frame: shading_frame(ns, tangent),
            ng,
            params: PbrParams {
                base_color: self.base_color,
                ..PbrParams::diffuse(Vec3::ZERO)
            },
            ggx: Ggx { alpha: self.alpha },
            row: AlbedoRow::from_parts(self.row_k, self.row_fy),
            layer: SpecularLayer::from_parts(self.weight, self.f0, self.f0_max, self.f0_mean),
            interface: Interface::NONE,
            w_metal: self.w_metal,
            w_base: self.w_base,
            w_trans: 0.0,
            mean_base: self.mean_base,
            lambert: false,
            spec_smooth: false,
            trans_smooth: true,
            diffuse_on: self.diffuse_on,
            spec_on: self.spec_on,
            trans_on: false,
            coat: Coat::NONE,
            sheen: Sheen::NONE,
            coat_on: false,
            sheen_on: false,
            layered: false,
        }
    }

    /// The albedo table's (A, B) at cos θo = `cos_o` (≥ 0), as the BSDF looks them up.
    #[inline(always)]
    pub(crate) fn albedo_terms(&self, cos_o: f32) -> (f32, f32) {
        AlbedoRow::from_parts(self.row_k, self.row_fy).lookup(cos_o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform values in [0, 1) from a counter (SplitMix64).
    struct Values(u64);

    impl Values {
        fn next(&mut self) -> f32 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        }

        fn unit(&mut self) -> Vec3 {
            let v = Vec3::new(self.next(), self.next(), self.next()) * 2.0 - 1.0;
            v.try_normalize().unwrap_or(Vec3::Z)
        }
    }

    fn bits(v: Vec3) -> [u32; 3] {
        v.to_array().map(f32::to_bits)
    }

    /// Glossy materials of every kind: metal, the specular layer over a base, mixes, tinted
    /// specular, rough to nearly smooth, black bases.
    fn materials(v: &mut Values) -> Vec<PbrParams> {
        let mut out = Vec::new();
        for k in 0..200 {
            let base = match k % 5 {
                0 => Vec3::ZERO,
                _ => Vec3::new(v.next(), v.next(), v.next()),
            };
            out.push(PbrParams {
                base_color: base,
                metallic: [0.0, 1.0, v.next()][k % 3],
                roughness: [0.02, 0.5, 1.0, v.next().max(0.01)][k % 4],
                specular: [1.0, v.next()][k % 2],
                specular_color: [Vec3::ONE, Vec3::new(v.next(), v.next(), 1.0)][(k / 2) % 2],
                ior: [1.5, 1.0 + 2.0 * v.next()][(k / 3) % 2],
                ..PbrParams::diffuse(base)
            });
        }
        out
    }

    #[test]
    fn the_lobes_remade_at_a_hit_answer_as_the_material_bsdf_does() {
        let mut v = Values(7);
        let mut compared = 0;
        for params in materials(&mut v) {
            let template = Bsdf::new(params, Vec3::Z, Vec3::Z, None);
            let lobes = template
                .glossy_lobes()
                .unwrap_or_else(|| panic!("{params:?} is glossy"));
            for _ in 0..200 {
                let ns = v.unit();
                // The geometric normal near the shading one, on its side or a little past it.
                let ng = (ns + 0.3 * v.unit()).try_normalize().unwrap_or(ns);
                let (wo, wi) = (v.unit(), v.unit());
                let bsdf = template.at(ns, ng, None);
                let lanes = lobes.at(ns, ng, None);
                let terms = lobes.albedo_terms(wo.dot(ns).abs());
                let (f, pdf) = bsdf.eval_pdf(wo, wi);
                let (lf, lpdf) = lanes.glossy_eval_pdf(wo, wi, terms);
                assert_eq!((bits(f), pdf.to_bits()), (bits(lf), lpdf.to_bits()));
                assert_eq!(bits(bsdf.eval(wo, wi)), bits(lanes.eval(wo, wi)));
                let (u_lobe, u) = (v.next(), Vec2::new(v.next(), v.next()));
                let a = bsdf.sample(wo, u_lobe, u);
                let b = lanes.glossy_sample(wo, u_lobe, u, terms);
                assert_eq!(
                    a.is_some(),
                    b.is_some(),
                    "{params:?} wo {wo} u {u_lobe} {u}"
                );
                if let (Some(a), Some(b)) = (a, b) {
                    assert_eq!(bits(a.wi), bits(b.wi));
                    assert_eq!(bits(a.weight), bits(b.weight));
                    assert_eq!(a.pdf.to_bits(), b.pdf.to_bits());
                    assert_eq!((a.delta, a.transmitted), (b.delta, b.transmitted));
                    compared += 1;
                }
            }
        }
        assert!(compared > 10_000, "only {compared} samples compared");
    }

    #[test]
    fn only_glossy_materials_have_glossy_lobes() {
        let glossy = |p: PbrParams| {
            Bsdf::new(p, Vec3::Z, Vec3::Z, None)
                .glossy_lobes()
                .is_some()
        };
        let plastic = PbrParams {
            specular: 1.0,
            roughness: 0.5,
            ..PbrParams::diffuse(Vec3::splat(0.5))
        };
        assert!(glossy(plastic));
        assert!(glossy(PbrParams {
            metallic: 1.0,
            ..plastic
        }));
        assert!(!glossy(PbrParams::diffuse(Vec3::splat(0.5))));
        assert!(!glossy(PbrParams {
            roughness: 0.0,
            ..plastic
        }));
        assert!(!glossy(PbrParams {
            transmission: 1.0,
            ..plastic
        }));
        assert!(!glossy(PbrParams {
            clearcoat: 1.0,
            ..plastic
        }));
        assert!(!glossy(PbrParams {
            sheen_color: Vec3::ONE,
            ..plastic
        }));
    }
}
