//! Step 5, `scatter` (vector): the light sample's value and shadow ray, the BSDF sample, Russian
//! roulette and the next ray, for the Lambertian lanes and, where the scene has them, the glossy
//! ones (`glossy.rs`).

use super::{GlossyLanes, Lanes, B, F, LANES, V3};
use crate::bsdf::lambert_at;
use crate::guide::mix_densities;
use crate::integrator::direct::LightGeometry;
use crate::integrator::path::survival;
use crate::math::{is_black, offset_unit_normal, spawn_clearance, Frame};
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use crate::settings::RussianRoulette;
use glam::{Vec2, Vec3};

impl Lanes<'_> {
    /// [`Lanes::scatter`] with the roulette's variant a constant in each copy: a `match` on it
    /// inside the loop would keep the loop from being vectorised.
    #[inline(always)]
    pub(super) fn scatter_by_roulette<const GLOSSY: bool>(&mut self) {
        match self.settings.rr {
            RussianRoulette::Off => self.scatter::<GLOSSY>(RussianRoulette::Off),
            RussianRoulette::Auto => self.scatter::<GLOSSY>(RussianRoulette::Auto),
            RussianRoulette::Max => self.scatter::<GLOSSY>(RussianRoulette::Max),
            RussianRoulette::Fixed(p) => self.scatter::<GLOSSY>(RussianRoulette::Fixed(p)),
            RussianRoulette::Threshold { terminate, below } => {
                self.scatter::<GLOSSY>(RussianRoulette::Threshold { terminate, below })
            }
        }
    }

    /// `scatter`'s Lambertian samples (direction, weight, density, kept) in frames oriented by
    /// the lanes' tangents (`Bsdf::at`'s with a tangent), for a scene with tangents; compiled
    /// for AVX2 as `GlossyLanes::eval_pdf_oriented` is.
    #[cfg_attr(
        target_arch = "x86_64",
        target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")
    )]
    unsafe fn lambert_samples_oriented(&self, u0: F, u1: F) -> (V3, V3, F, B) {
        let (mut wis, mut weights, mut pdfs, mut oks) =
            (V3::ZERO, V3::ZERO, [0.0; LANES], [false; LANES]);
        for i in 0..LANES {
            let (ng, wo, albedo) = (self.ng.get(i), -self.d.get(i), self.albedo.get(i));
            let frame = Frame::from_zx(self.ns.get(i), self.tangent.get(i));
            let u = Vec2::new(u0[i], u1[i]);
            let bs =
                lambert_at::sample_wi(&frame, ng, albedo, wo, u).filter(|bs| !is_black(bs.weight));
            oks[i] = bs.is_some();
            let (wi, weight, pdf) =
                bs.map_or((Vec3::Z, Vec3::ZERO, 0.0), |bs| (bs.wi, bs.weight, bs.pdf));
            wis.set(i, wi);
            weights.set(i, weight);
            pdfs[i] = pdf;
        }
        (wis, weights, pdfs, oks)
    }

    /// `trace_path` steps 2 to 4 for every lane whose path goes on from its hit: the light
    /// sample's value and shadow ray (traced later), the BSDF sample, Russian roulette and the
    /// next ray. A lane whose path ends here keeps `cont` false. `GLOSSY`: some lanes may hold a
    /// glossy material, whose BSDF is evaluated and sampled beside the Lambertian's in every
    /// lane, the glossy lanes keeping its results (`lanes/glossy.rs`).
    #[inline(always)]
    fn scatter<const GLOSSY: bool>(&mut self, rr: RussianRoulette) {
        // Copied to locals, as in `shade_hit`.
        let (gos, ps, ngs, ds, albedos) = (self.go, self.p, self.ng, self.d, self.albedo);
        let glossy = match GLOSSY {
            true => self.glossy_lanes(),
            false => GlossyLanes::none(),
        };
        let (nss, tangents) = (self.ns, self.tangents);
        // How far from the surface rays spawned at the hit start (`spawn_clearance`), from the
        // hit triangles' corners, which are still in place.
        let (ca, cb, cc) = (self.corner_a, self.corner_b, self.corner_c);
        let clearances: F =
            std::array::from_fn(|i| spawn_clearance([ca.get(i), cb.get(i), cc.get(i)]));
        let (mut betas, depths, keys, revs) = (self.beta, self.depth, self.key, self.index_rev);
        let (light_ok, light_point, light_normal, light_pdf) = (
            self.light_ok,
            self.light_point,
            self.light_normal,
            self.light_pdf_area,
        );
        let (light_front, light_back, mut rays) = (self.light_front, self.light_back, self.rays);
        let (guided, guide_pdfs) = (self.guided, self.guide_pdf);
        let (mut shadows, mut shadow_o, mut shadow_d) = ([false; LANES], V3::ZERO, V3::ZERO);
        let (mut shadow_t_max, mut shadow_value) = ([0.0; LANES], V3::ZERO);
        let mut light_wi = V3::ZERO;
        // The glossy lanes' BSDF values towards their light points (`glossy.rs`), where some
        // lane has one (none in a scene lit by lamps alone).
        let (glossy_f, glossy_pdf) = match GLOSSY && light_ok.iter().any(|&ok| ok) {
            true => {
                let mut wi = V3::ZERO;
                for i in 0..LANES {
                    let (p, point) = (ps.get(i), light_point.get(i));
                    wi.set(i, LightGeometry::new(p, point, light_normal.get(i)).wi);
                }
                glossy.eval_pdf(&nss, &ngs, &ds, &wi)
            }
            false => (V3::ZERO, [0.0; LANES]),
        };
        let (mut os, mut new_ds, mut pdfs, mut mis) = (self.o, ds, self.bsdf_pdf, self.mis);
        let (mut new_depths, mut conts) = (depths, [false; LANES]);
        for i in 0..LANES {
            let go = gos[i];
            let p = ps.get(i);
            let ng = ngs.get(i);
            let wo = -ds.get(i);
            let albedo = albedos.get(i);
            let beta = betas.get(i);

            // 2. Direct lighting: the light sample's contribution, if its shadow ray is clear.
            let g = LightGeometry::new(p, light_point.get(i), light_normal.get(i));
            let le = if g.cos_l > 0.0 {
                light_front.get(i)
            } else {
                light_back.get(i)
            };
            let (f, bsdf_pdf) = lambert_at::eval_pdf(nss.get(i), ng, albedo, wo, g.wi);
            let (f, bsdf_pdf) = match GLOSSY && glossy.shaded[i] {
                true => (glossy_f.get(i), glossy_pdf[i]),
                false => (f, bsdf_pdf),
            };
            // A guided lane's continuation is drawn from the caustic guide's mixture (`guided.rs`).
            let bsdf_pdf = match guided[i] {
                true => mix_densities(guide_pdfs[i], bsdf_pdf),
                false => bsdf_pdf,
            };
            let query = g.value(light_pdf[i], le, f, bsdf_pdf, Vec3::ONE, true);
            // `&`, not `&&`: the short-circuit's branch kept this whole loop scalar
            // (docs/benchmarks.md, December 6).
            let shadow = go & light_ok[i] & query.is_some();
            let value = query.unwrap_or(Vec3::ZERO);
            shadows[i] = shadow;
            light_wi.set(i, g.wi);
            shadow_value.set(i, beta * value);
            rays[i] += u32::from(shadow);
        }
        // The shadow segments in a loop of their own (inside the loop above they cost more;
        // docs/benchmarks.md, November 27). A lane without a shadow ray is never traced: its
        // segment may be NaN.
        for i in 0..LANES {
            let (p, ng, wi) = (ps.get(i), ngs.get(i), light_wi.get(i));
            let side = if wi.dot(ng) > 0.0 { ng } else { -ng };
            let origin = offset_unit_normal(p, side, clearances[i]);
            let (d, t_max) = LightGeometry::shadow_segment(origin, light_point.get(i));
            shadow_o.set(i, origin);
            shadow_d.set(i, d);
            shadow_t_max[i] = t_max;
        }
        let mut sampled_wi = V3::ZERO;
        let mut sampled_weight = V3::ZERO;
        let mut sampled_pdf = [0.0; LANES];
        let mut sampled_ok = [false; LANES];
        // The sample values first, in a loop of their own: their table lookups are gathers, which
        // the compiler does not use for AVX2, and they would keep the loop below scalar.
        // The roulette's value is drawn for every lane, whether or not it plays: a pure function
        // of the lane's sample, so drawing it changes nothing else.
        let (mut u0, mut u1, mut u_rr) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let mut u_lobe = [0.0; LANES];
        for i in 0..LANES {
            // One group of four dimensions (`dims`), as in `shade_hit`.
            let group = bounce_dim(depths[i], dims::BSDF_DIR);
            let (lobe, roulette) = (
                dims::BSDF_LOBE - dims::BSDF_DIR,
                dims::ROULETTE - dims::BSDF_DIR,
            );
            if GLOSSY {
                // The lobe's value too (a Lambertian lane does not read it).
                let offsets = [0, 1, lobe, roulette];
                [u0[i], u1[i], u_lobe[i], u_rr[i]] =
                    owen_sobol_group_lanewise(keys[i], revs[i], group, offsets);
            } else {
                let offsets = [0, 1, roulette];
                [u0[i], u1[i], u_rr[i]] =
                    owen_sobol_group_lanewise(keys[i], revs[i], group, offsets);
            }
        }
        let glossy_sample = match GLOSSY {
            true => Some(glossy.sample(&nss, &ngs, &ds, [&u_lobe, &u0, &u1])),
            false => None,
        };
        for i in 0..LANES {
            let ng = ngs.get(i);
            let wo = -ds.get(i);
            let albedo = albedos.get(i);
            // 3. The continuation: a cosine-weighted direction (one lobe, no lobe choice).
            let u = Vec2::new(u0[i], u1[i]);
            let frame = Frame::from_z(nss.get(i));
            let bs =
                lambert_at::sample_wi(&frame, ng, albedo, wo, u).filter(|bs| !is_black(bs.weight));
            sampled_ok[i] = bs.is_some();
            let (wi, weight, pdf) =
                bs.map_or((Vec3::Z, Vec3::ZERO, 0.0), |bs| (bs.wi, bs.weight, bs.pdf));
            let (wi, weight, pdf) = match &glossy_sample {
                Some(s) if glossy.on[i] => {
                    sampled_ok[i] = s.ok[i];
                    (s.wi.get(i), s.weight.get(i), s.pdf[i])
                }
                _ => (wi, weight, pdf),
            };
            sampled_wi.set(i, wi);
            sampled_weight.set(i, weight);
            sampled_pdf[i] = pdf;
        }
        if tangents {
            // The loop above stays free of the choice (it cost scenes without tangents 2.7 %),
            // and this one out of line (inlined, 2 %).
            // SAFETY: the lanes run only where an `Isa` was detected, and both have AVX2.
            let (wis, weights, pdfs, oks) = unsafe { self.lambert_samples_oriented(u0, u1) };
            for i in 0..LANES {
                if !(GLOSSY && glossy.on[i]) {
                    sampled_wi.set(i, wis.get(i));
                    sampled_weight.set(i, weights.get(i));
                    sampled_pdf[i] = pdfs[i];
                    sampled_ok[i] = oks[i];
                }
            }
        }
        // Guided lanes (`guided.rs`): a Lambertian whose mixture draws the BSDF's branch keeps the
        // sample above, reweighed; the others continue lane by lane.
        let lane_by_lane = match self.guide {
            Some(_) => self.mix_lambert_samples(
                GLOSSY.then_some((glossy.on, &u_lobe)),
                &sampled_wi,
                &mut sampled_weight,
                &mut sampled_pdf,
                &mut sampled_ok,
            ),
            None => [false; LANES],
        };
        for i in 0..LANES {
            let go = gos[i];
            let p = ps.get(i);
            let clearance = clearances[i];
            let ng = ngs.get(i);
            let beta = betas.get(i);
            let depth = depths[i];
            let spawn = |wi: Vec3| {
                let side = if wi.dot(ng) > 0.0 { ng } else { -ng };
                offset_unit_normal(p, side, clearance)
            };
            let (wi, weight, pdf, sampled) = (
                sampled_wi.get(i),
                sampled_weight.get(i),
                sampled_pdf[i],
                sampled_ok[i],
            );
            let mut beta_next = beta * weight;
            // The other guided lanes' continuation is `scatter_lane_by_lane`'s.
            let mut cont = go && !lane_by_lane[i] && sampled && !is_black(beta_next);

            // 4. Russian roulette.
            let survive = survival(rr, depth, beta_next);
            if survive < 1.0 {
                cont &= u_rr[i] < survive;
                beta_next /= survive;
            }
            conts[i] = cont;
            if cont {
                betas.set(i, beta_next);
                pdfs[i] = pdf;
                mis[i] = true;
                os.set(i, spawn(wi));
                new_ds.set(i, wi);
                new_depths[i] = depth + 1;
            }
        }
        (self.shadow, self.shadow_o, self.shadow_d) = (shadows, shadow_o, shadow_d);
        (self.shadow_t_max, self.shadow_value, self.rays) = (shadow_t_max, shadow_value, rays);
        (self.beta, self.bsdf_pdf, self.mis, self.o, self.d) = (betas, pdfs, mis, os, new_ds);
        (self.depth, self.cont) = (new_depths, conts);
        self.guided = lane_by_lane;
    }
}
