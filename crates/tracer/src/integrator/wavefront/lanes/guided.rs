//! The caustic guide in the lanes (`crate::guide`), lane by lane, as `trace_path` draws it: each
//! lane whose vertex has non-delta lobes and lies in one of the guide's cells is *guided*. Its
//! light sample's MIS weight takes the mixture's density (`guide::mix_densities` of the guide's
//! density of the light's direction, found here, and the BSDF's, which the vector steps evaluate
//! as for every lane), and its continuation is drawn from the mixture by `scatter_lane_by_lane`
//! (`general.rs`), which `scatter` leaves the guided lanes to. A scene without a guide runs none
//! of this.

use super::{Lanes, LANES};
use crate::bsdf::Bsdf;
use crate::integrator::direct::LightGeometry;

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
}
