//! Step 3, `shade_hit` (vector): the hit point and normals, the emission the ray sees, and the
//! light sample's values; then the texels' and the general materials' BSDFs, and the lights the
//! values choose.

use super::{normals, Lanes, LANES, V3};
use crate::isa::Isa;
use crate::math::is_black;
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use crate::sampling::power_heuristic;
use crate::scene::shading_normal;

impl Lanes<'_> {
    /// The surface at each hit (`Scene::surface`), the emission the ray
    /// sees (`trace_path` step 1), and the sample values of the light sample.
    #[inline(always)]
    pub(super) fn shade_hit<const NORMALS: u8>(&mut self, isa: Isa) {
        // Inputs and outputs are copied to locals: the compiler vectorises a loop over distinct
        // local arrays, not one over fields of `self` indexed by a variable.
        let (hit, ca, cb, cc) = (self.hit, self.corner_a, self.corner_b, self.corner_c);
        let (na, nb, nc) = (self.normal_a, self.normal_b, self.normal_c);
        let smooth = self.smooth;
        let (b1s, b2s, ds, ts) = (self.b1, self.b2, self.d, self.t);
        let (ef, eb, mis, dens, pdfs) = (
            self.emission_front,
            self.emission_back,
            self.mis,
            self.light_density,
            self.bsdf_pdf,
        );
        let (mut ls, betas, mut vertices, depths) = (self.l, self.beta, self.vertices, self.depth);
        let (mut go, mut ps, mut ngs, mut nss) = ([false; LANES], V3::ZERO, V3::ZERO, V3::ZERO);
        let (keys, revs) = (self.key, self.index_rev);
        let (mut u_select, mut u_light) = ([0.0; LANES], [[0.0; LANES]; 2]);
        let mut u_punctual = [0.0; LANES];
        let limit = self.depth_limit;
        for i in 0..LANES {
            let on = hit[i];
            let (a, b, c) = (ca.get(i), cb.get(i), cc.get(i));
            let (b1, b2) = (b1s[i], b2s[i]);
            let b0 = 1.0 - b1 - b2;
            let p = a * b0 + b * b1 + c * b2;
            let ng = (b - a).cross(c - a).normalize();
            let d = ds.get(i);
            let front = d.dot(ng) < 0.0;
            let le = if front { ef.get(i) } else { eb.get(i) };
            let t = ts[i];
            let w = if mis[i] {
                let cos_l = d.dot(ng).abs();
                let light_pdf = dens[i] * t * t / cos_l;
                power_heuristic(pdfs[i], light_pdf)
            } else {
                1.0
            };
            let l = ls.get(i);
            let lit = l + betas.get(i) * le * w;
            ls.set(i, if on && !is_black(le) { lit } else { l });
            vertices[i] += u32::from(on);
            go[i] = on && depths[i] < limit;
            ps.set(i, p);
            ngs.set(i, ng);
            let normals = [na.get(i), nb.get(i), nc.get(i)];
            let ns = match NORMALS {
                normals::FLAT => ng,
                normals::SMOOTH => shading_normal(normals, [b0, b1, b2], ng),
                _ if smooth[i] => shading_normal(normals, [b0, b1, b2], ng),
                _ => ng,
            };
            nss.set(i, ns);
        }
        // The light sample's values in a loop of their own (see `scatter`).
        for i in 0..LANES {
            // One group of four dimensions (`dims`): its seed and shuffle computed once.
            let group = bounce_dim(depths[i], dims::LIGHT_POINT);
            let [point0, point1, select, punctual] = owen_sobol_group_lanewise(
                keys[i],
                revs[i],
                group,
                [
                    0,
                    1,
                    dims::LIGHT_SELECT - dims::LIGHT_POINT,
                    dims::PUNCTUAL_SELECT - dims::LIGHT_POINT,
                ],
            );
            (u_light[0][i], u_light[1][i], u_select[i]) = (point0, point1, select);
            u_punctual[i] = punctual;
        }
        (self.l, self.vertices, self.go, self.p, self.ng) = (ls, vertices, go, ps, ngs);
        (self.ns, self.u_punctual) = (nss, u_punctual);
        if self.texels {
            self.shade_texels();
        }
        if self.any_general {
            self.shade_general();
        }
        self.choose_lights(isa, &u_select, &u_light);
    }
}
