//! The lanes whose BSDF is not one the vector steps model, lane by lane through the BSDF's own
//! code: a specular material (delta lobes only: a perfect mirror, smooth glass), whose
//! continuation alone is its own, and a general one (`DiffuseMaterial::general`: a clear coat, a
//! sheen, rough transmission, textures that change its kind), whose BSDF is made at each hit
//! (`shade_general`), evaluated where the vector steps evaluate the others' (`GlossyLanes`
//! takes its values) and sampled here; and the lanes the caustic guide guides (`guided.rs`),
//! whose continuation is drawn from its mixture with their BSDF, as `trace_path` draws it.

use super::{Lanes, LANES};
use crate::integrator::path::survival;
use crate::math::{is_black, offset_unit_normal, spawn_clearance};
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use glam::Vec2;

impl Lanes<'_> {
    /// Each general material's BSDF at its lane's hit (`Scene::bsdf_at`'s: its template moved
    /// there, or its texels read), after `shade_hit` has made the shading normal and
    /// `shade_texels` the tangent: the lane's `general` BSDF, and whether it samples lights
    /// (`Bsdf::has_non_delta`, which its texels may change).
    #[inline(never)]
    pub(super) fn shade_general(&mut self) {
        let scene = self.scene;
        for i in 0..LANES {
            self.general[i] = None;
            let material = self.material[i];
            if !(self.go[i] && self.materials[material as usize].general) {
                continue;
            }
            let Some(hit) = self.found[i] else {
                continue;
            };
            // `shade_texels` read the tangent (it runs wherever some mesh has tangents).
            let tangent = match self.tangents {
                true => self.tangent4[i],
                false => None,
            };
            let (ns, ng) = (self.ns.get(i), self.ng.get(i));
            let bsdf = scene.hit_bsdf(material, &hit, ns, ng, tangent);
            self.diffuse_on[i] = bsdf.has_non_delta();
            self.general[i] = Some(bsdf);
        }
    }

    /// `trace_path` steps 3 and 4 (the BSDF sample, Russian roulette, the next ray) for each lane
    /// whose path goes on from a specular or a general material, after `scatter`, which gave
    /// these lanes no continuation (their albedo is zero, and they are not glossy), but gave a
    /// general one its light sample. The next ray's emission is counted in full after a delta
    /// sample (`mis` false), as `EmissionWeight::Full`. A transmission through a solid's boundary
    /// enters or leaves its volume (`volumes.rs`).
    pub(super) fn scatter_lane_by_lane(&mut self) {
        let rr = self.settings.rr;
        for i in 0..LANES {
            if !self.go[i] {
                continue;
            }
            let (p, ng, ns, wo) = (
                self.p.get(i),
                self.ng.get(i),
                self.ns.get(i),
                -self.d.get(i),
            );
            // A general lane's BSDF is borrowed where it lies (a whole `Bsdf` is large).
            let made;
            let bsdf = match (&self.general[i], &self.materials[self.material[i] as usize]) {
                (Some(general), _) => general,
                (None, m) => match &m.specular {
                    Some(template) => {
                        made = template.at(ns, ng, self.frame_tangent(i));
                        &made
                    }
                    // A guided lane's (`guided.rs`): its Lambertian or glossy BSDF.
                    None => match self.guided_bsdf(i) {
                        Some(bsdf) => {
                            made = bsdf;
                            &made
                        }
                        None => continue,
                    },
                },
            };
            let depth = self.depth[i];
            // The BSDF's four values, one group of four dimensions (`dims`), as `scatter` draws.
            // (A pure Lambertian texel of a general material ignores its lobe value, which
            // `trace_path` then does not draw: a pure function of the sample, drawing it changes
            // nothing.)
            let group = bounce_dim(depth, dims::BSDF_DIR);
            let offsets = [
                0,
                1,
                dims::BSDF_LOBE - dims::BSDF_DIR,
                dims::ROULETTE - dims::BSDF_DIR,
            ];
            let [u0, u1, u_lobe, u_rr] =
                owen_sobol_group_lanewise(self.key[i], self.index_rev[i], group, offsets);
            let u = Vec2::new(u0, u1);
            let sampled = match self.cells[i].filter(|_| self.guided[i]) {
                // As `trace_path`: the lobe's value chooses between the guide and the BSDF.
                Some(cell) => cell.sample_mixture(bsdf, wo, ng, u_lobe, u),
                None => bsdf.sample(wo, u_lobe, u),
            };
            let Some(bs) = sampled.filter(|bs| !is_black(bs.weight)) else {
                continue;
            };
            let mut beta = self.beta.get(i) * bs.weight;
            if is_black(beta) {
                continue;
            }
            let survive = survival(rr, depth, beta);
            if survive < 1.0 {
                if u_rr >= survive {
                    continue;
                }
                beta /= survive;
            }
            let corners = [
                self.corner_a.get(i),
                self.corner_b.get(i),
                self.corner_c.get(i),
            ];
            let thin_walled = bsdf.params().thin_walled;
            self.cross_boundary(i, thin_walled, &bs, wo);
            let side = if bs.wi.dot(ng) > 0.0 { ng } else { -ng };
            self.cont[i] = true;
            self.beta.set(i, beta);
            self.bsdf_pdf[i] = bs.pdf;
            self.mis[i] = !bs.delta;
            self.o
                .set(i, offset_unit_normal(p, side, spawn_clearance(corners)));
            self.d.set(i, bs.wi);
            self.depth[i] = depth + 1;
        }
    }
}
