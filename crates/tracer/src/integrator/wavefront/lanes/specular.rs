//! The continuation of the lanes whose hit is on a specular material (delta lobes only: a perfect
//! mirror, smooth glass), lane by lane through the material's own `Bsdf::sample`.

use super::{Lanes, LANES};
use crate::integrator::path::survival;
use crate::math::{is_black, offset_unit_normal, spawn_clearance};
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use glam::Vec2;

impl Lanes<'_> {
    /// `trace_path` steps 3 and 4 (the BSDF sample, Russian roulette, the next ray) for each lane
    /// whose path goes on from a specular material, after `scatter`, which gave these lanes no
    /// continuation (their albedo is zero) and no light sample (they have no non-delta lobe). The
    /// next ray's emission is counted in full after a delta sample (`mis` false), as
    /// `EmissionWeight::Full`. A transmission through a solid's boundary enters or leaves its
    /// volume (`volumes.rs`).
    pub(super) fn scatter_specular(&mut self) {
        let rr = self.settings.rr;
        for i in 0..LANES {
            if !self.go[i] {
                continue;
            }
            let Some(template) = &self.materials[self.material[i] as usize].specular else {
                continue;
            };
            let (p, ng, ns, wo) = (
                self.p.get(i),
                self.ng.get(i),
                self.ns.get(i),
                -self.d.get(i),
            );
            let depth = self.depth[i];
            // The BSDF's four values, one group of four dimensions (`dims`), as `scatter` draws.
            let group = bounce_dim(depth, dims::BSDF_DIR);
            let offsets = [
                0,
                1,
                dims::BSDF_LOBE - dims::BSDF_DIR,
                dims::ROULETTE - dims::BSDF_DIR,
            ];
            let [u0, u1, u_lobe, u_rr] =
                owen_sobol_group_lanewise(self.key[i], self.index_rev[i], group, offsets);
            let bsdf = template.at(ns, ng, self.frame_tangent(i));
            let Some(bs) = bsdf
                .sample(wo, u_lobe, Vec2::new(u0, u1))
                .filter(|bs| !is_black(bs.weight))
            else {
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
            self.cross_boundary(i, &bsdf, &bs, wo);
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
