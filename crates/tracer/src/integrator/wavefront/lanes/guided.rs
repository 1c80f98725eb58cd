//! The caustic guide in the lanes (`crate::guide`), lane by lane, as `trace_path` draws it: each
//! lane whose vertex has non-delta lobes and lies in one of the guide's cells is *guided*. Its
//! light sample's MIS weight takes the mixture's density (`guide::mix_densities` of the guide's
//! density of the light's direction, found here, and the BSDF's, which the vector steps evaluate
//! as for every lane), and its continuation is drawn from the mixture: where the mixture draws the
//! BSDF's branch of a Lambertian, `scatter` keeps its own sample of the BSDF reweighed (the same
//! direction: a Lambertian ignores the lobe's value), and otherwise `scatter_lane_by_lane`
//! (`general.rs`) draws it. A scene without a guide runs none of this.

use super::{Lanes, B, F, LANES, V3};
use crate::bsdf::Bsdf;
use crate::guide::MIX;
use crate::integrator::direct::LightGeometry;
use crate::math::is_black;
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};

impl Lanes<'_> {
    /// Each lane's guide cell and whether it is guided, and the guide's density of its light
    /// sample's direction (the environment's, or the area light point's), after the light
    /// sample was chosen and before `scatter`, `light_environment` and `absorb_light_samples`
    /// weigh it.
    #[inline(never)]
    pub(super) fn find_guide_cells(&mut self) {
        let Some(guide) = self.guide else {
            return;
        };
        for i in 0..LANES {
            let p = self.p.get(i);
            // As `trace_path`: only a vertex with non-delta lobes draws from the mixture.
            let cell = match self.go[i] && self.diffuse_on[i] {
                true => guide.cell(p),
                false => None,
            };
            self.guided[i] = cell.is_some();
            self.guide_pdf[i] = match cell {
                Some(cell) => {
                    let wi = match self.env_light[i] {
                        true => self.env_wi.get(i),
                        false => {
                            LightGeometry::new(p, self.light_point.get(i), self.light_normal.get(i))
                                .wi
                        }
                    };
                    cell.pdf(wi)
                }
                None => 0.0,
            };
            self.cells[i] = cell;
        }
    }

    /// Lane `i`'s BSDF where it is guided and its material is neither general nor specular
    /// (those have theirs in `scatter_lane_by_lane`): its material's template, or its texel's,
    /// moved to the hit as `Scene::bsdf_at` moves it.
    pub(super) fn guided_bsdf(&self, i: usize) -> Option<Bsdf> {
        if !self.guided[i] {
            return None;
        }
        let template = match &self.texel_bsdf[i] {
            Some(texel) if self.materials[self.material[i] as usize].textured => texel,
            _ => self.scene.bsdf_template(self.material[i])?,
        };
        Some(template.at(self.ns.get(i), self.ng.get(i), self.frame_tangent(i)))
    }

    /// In `scatter`, after its BSDF samples (`wi`, `weight`, `pdf`, `ok`): each guided
    /// Lambertian lane whose mixture draws the BSDF's branch takes its sample reweighed as
    /// `GuideCell::sample_mixture` weighs it (a Lambertian ignores the lobe's value, so its sample
    /// is the one the branch would draw), tested as `trace_path` tests it. `glossy`: in a scene
    /// with glossy lanes, which lanes are glossy and the lobe values `scatter` drew for them
    /// all. Returns the guided lanes left to `scatter_lane_by_lane` (`scatter` leaves them in
    /// `guided` for it).
    #[inline(always)]
    pub(super) fn mix_lambert_samples(
        &self,
        glossy: Option<(B, &F)>,
        wi: &V3,
        weight: &mut V3,
        pdf: &mut F,
        ok: &mut B,
    ) -> B {
        let mut lane_by_lane = self.guided;
        for i in 0..LANES {
            let glossy_lane = glossy.is_some_and(|(on, _)| on[i]);
            let Some(cell) = self.cells[i] else {
                continue;
            };
            if !self.guided[i] || glossy_lane || self.general[i].is_some() {
                continue;
            }
            // The lobe's value chooses between the guide and the BSDF (drawn here, for the
            // guided lanes alone, where `scatter` did not draw it for every lane).
            let u_mix = match glossy {
                Some((_, u_lobe)) => u_lobe[i],
                None => {
                    let group = bounce_dim(self.depth[i], dims::BSDF_DIR);
                    let offset = [dims::BSDF_LOBE - dims::BSDF_DIR];
                    owen_sobol_group_lanewise(self.key[i], self.index_rev[i], group, offset)[0]
                }
            };
            if u_mix < MIX {
                continue;
            }
            lane_by_lane[i] = false;
            let (w, p) = (wi.get(i), pdf[i]);
            let mixed = cell.mix_pdf(p, w);
            let reweighed = weight.get(i) * (p / mixed);
            ok[i] &= !(mixed.is_nan() || mixed <= 0.0 || is_black(reweighed));
            weight.set(i, reweighed);
            pdf[i] = mixed;
        }
        lane_by_lane
    }
}
