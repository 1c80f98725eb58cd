//! The lanes' punctual lamp samples (`trace_path`'s `direct_punctual`): each lane's lamp and
//! shadow ray (`punctual_query`'s), the shadow rays traced two lanes a walk
//! (`Scene::visible_pair_in`), and the light they let through added before the area light's
//! sample (whose shadow ray is traced later), as `trace_path` adds them.
//!
//! Where a few lamps are chosen per point by what each sends there (`choose_by_contribution`), the
//! lanes make the choice in vector loops, lamp by lamp across the lanes, with each lane's
//! operations those of the scalar choice (the same bits): the Lambertian lanes' BSDF in the loop,
//! the glossy and general lanes' in `GlossyLanes::eval`'s. The lamps chosen by power or a tree take
//! `punctual_query` lane by lane.

use super::glossy::GlossyLanes;
use super::volumes::transmittance;
use super::{Lanes, B, F, LANES, V3};
use crate::bsdf::lambert_at;
use crate::integrator::direct::{lamp_shadow, punctual_query, PunctualAt, ShadowQuery};
use crate::light::{draw_step, PunctualLight, PunctualSample};
use crate::math::{luminance, spawn_clearance};
use glam::Vec3;

/// The running per-point choice of every lane (`choose_by_contribution`'s state, lane by lane).
struct LampDraw {
    u: F,
    total: F,
    chosen: B,
    wi: V3,
    dist: F,
    li: V3,
    contribution: V3,
    weight: F,
}

impl Lanes<'_> {
    /// Each lane's punctual light sample (see the module documentation). `GLOSSY`: some lanes
    /// may hold a glossy material (as in `scatter`).
    #[inline(always)]
    pub(super) fn light_punctual<const GLOSSY: bool>(&mut self) {
        let scene = self.scene;
        let mut on = [false; LANES];
        for (i, on) in on.iter_mut().enumerate() {
            *on = self.go[i] && self.diffuse_on[i];
        }
        let mut queries: [Option<ShadowQuery>; LANES] = [None; LANES];
        let per_point = scene.lights.punctual_per_point;
        if per_point {
            let glossy = match GLOSSY {
                true => self.glossy_lanes(),
                false => GlossyLanes::none(),
            };
            self.lamps_per_point::<GLOSSY>(&on, &glossy, &mut queries);
        }
        for i in 0..LANES {
            if !on[i] || per_point {
                continue;
            }
            queries[i] = self.lamp_query(i, |_| Vec3::ONE);
        }
        if self.any_absorbing {
            // Lanes inside an absorbing medium, again with its transmittance (which also weighs
            // a per-point choice of lamp).
            for i in 0..LANES {
                let sigma = self.medium.get(i);
                if on[i] && sigma != Vec3::ZERO {
                    queries[i] = self.lamp_query(i, |dist| transmittance(sigma, dist));
                }
            }
        }
        // The shadow rays, two lanes a walk; inlined: this step is compiled for the test's
        // instruction set (`builds.rs`).
        let mut traced = [0u8; LANES];
        let mut n = 0;
        for (i, q) in queries.iter().enumerate() {
            traced[n] = i as u8;
            n += usize::from(q.is_some());
        }
        let mut visible = [false; LANES];
        let mut pairs = traced[..n].chunks_exact(2);
        for pair in &mut pairs {
            let (i, j) = (usize::from(pair[0]), usize::from(pair[1]));
            let (Some(a), Some(b)) = (&queries[i], &queries[j]) else {
                continue;
            };
            (visible[i], visible[j]) = scene.visible_pair_in::<true>(
                (&a.ray, a.t_max, a.alpha_u),
                (&b.ray, b.t_max, b.alpha_u),
            );
        }
        for &i in pairs.remainder() {
            let i = usize::from(i);
            if let Some(q) = &queries[i] {
                visible[i] = scene.visible_in::<true>(&q.ray, q.t_max, q.alpha_u);
            }
        }
        for i in 0..LANES {
            if !on[i] {
                continue;
            }
            self.rays[i] += u32::from(queries[i].is_some());
            let value = match &queries[i] {
                Some(q) if visible[i] => q.value,
                _ => Vec3::ZERO,
            };
            let l = self.l.get(i) + self.beta.get(i) * value;
            self.l.set(i, l);
        }
    }

    /// Lane `i`'s lamp sample, lane by lane: `punctual_query` with its BSDF (`trace_path`'s
    /// `direct_punctual`) and the medium's `transmittance` over a distance.
    #[inline(always)]
    fn lamp_query(&self, i: usize, transmittance: impl Fn(f32) -> Vec3) -> Option<ShadowQuery> {
        let scene = self.scene;
        let at = self.punctual_at(i);
        let (ng, ns, wo) = (self.ng.get(i), self.ns.get(i), -self.d.get(i));
        let albedo = self.albedo.get(i);
        if let Some(bsdf) = &self.general[i] {
            return punctual_query(scene, &at, |wi| bsdf.eval(wo, wi), transmittance);
        }
        match &self.lobes(i) {
            // The glossy BSDF as `trace_path` evaluates it (`Bsdf::eval`, out of line).
            Some(lobes) => {
                let bsdf = lobes.at(ns, ng, self.frame_tangent(i));
                punctual_query(scene, &at, |wi| bsdf.eval(wo, wi), transmittance)
            }
            None => {
                let eval = |wi| lambert_at::eval_pdf(ns, ng, albedo, wo, wi).0;
                punctual_query(scene, &at, eval, transmittance)
            }
        }
    }

    /// Where lane `i` samples a lamp.
    #[inline(always)]
    fn punctual_at(&self, i: usize) -> PunctualAt {
        PunctualAt {
            p: self.p.get(i),
            ng: self.ng.get(i),
            clearance: spawn_clearance([
                self.corner_a.get(i),
                self.corner_b.get(i),
                self.corner_c.get(i),
            ]),
            u_select: self.u_punctual[i],
            alpha_u: self.alpha_at(i, self.depth[i]),
        }
    }

    /// `punctual_query` with lamps chosen per point, for the lanes of `on`: the choice of
    /// `choose_by_contribution`, lamp by lamp across the lanes.
    #[inline(always)]
    fn lamps_per_point<const GLOSSY: bool>(
        &self,
        on: &B,
        glossy: &GlossyLanes,
        queries: &mut [Option<ShadowQuery>; LANES],
    ) {
        let mut draw = LampDraw {
            u: self.u_punctual,
            total: [0.0; LANES],
            chosen: [false; LANES],
            wi: V3::ZERO,
            dist: [0.0; LANES],
            li: V3::ZERO,
            contribution: V3::ZERO,
            weight: [0.0; LANES],
        };
        for lamp in &self.scene.lights.punctual {
            // The lamp's kind decided once for all lanes.
            match lamp {
                PunctualLight::Point(l) => {
                    self.offer_lamp::<GLOSSY>(on, glossy, &mut draw, |p| l.sample_li_masked(p))
                }
                PunctualLight::Spot(l) => {
                    self.offer_lamp::<GLOSSY>(on, glossy, &mut draw, |p| l.sample_li_masked(p))
                }
                PunctualLight::Directional(l) => {
                    self.offer_lamp::<GLOSSY>(on, glossy, &mut draw, |p| l.sample_li_masked(p))
                }
            }
        }
        for i in 0..LANES {
            let total = draw.total[i];
            if !(on[i] && draw.chosen[i] && total > 0.0 && total.is_finite()) {
                continue;
            }
            let ls = PunctualSample {
                wi: draw.wi.get(i),
                dist: draw.dist[i],
                li: draw.li.get(i),
            };
            let pmf = draw.weight[i] / total;
            let value = draw.contribution.get(i) / pmf;
            queries[i] = Some(lamp_shadow(&self.punctual_at(i), &ls, value));
        }
    }

    /// One lamp's step of the per-point choice in every lane (`choose_by_contribution`'s loop
    /// body): the lamp's light at each lane's point, the BSDF's f · |cos θi| towards it (the
    /// glossy lanes' in a loop of their own, `GlossyLanes::eval_pdf`), and the draw.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // one lane index over the lanes' and the draw's arrays
    fn offer_lamp<const GLOSSY: bool>(
        &self,
        on: &B,
        glossy: &GlossyLanes,
        draw: &mut LampDraw,
        sample_li: impl Fn(Vec3) -> (PunctualSample, bool),
    ) {
        let (mut wi, mut dist, mut li, mut lit) =
            (V3::ZERO, [0.0; LANES], V3::ZERO, [false; LANES]);
        for i in 0..LANES {
            let ls;
            (ls, lit[i]) = sample_li(self.p.get(i));
            wi.set(i, ls.wi);
            dist[i] = ls.dist;
            li.set(i, ls.li);
        }
        let f_glossy = match GLOSSY {
            true => glossy.eval(&self.ns, &self.ng, &self.d, &wi),
            false => V3::ZERO,
        };
        for i in 0..LANES {
            let (ng, ns, wo) = (self.ng.get(i), self.ns.get(i), -self.d.get(i));
            let (wi_i, li_i) = (wi.get(i), li.get(i));
            let lambert = lambert_at::eval_pdf(ns, ng, self.albedo.get(i), wo, wi_i).0;
            let f = if GLOSSY && glossy.shaded[i] {
                f_glossy.get(i)
            } else {
                lambert
            };
            let contribution = f * li_i * Vec3::ONE;
            let w = luminance(contribution);
            // NaN or negative (a BSDF's rounding) lights nothing.
            let valid = on[i] && lit[i] && w > 0.0 && w.is_finite();
            let take;
            (take, draw.total[i], draw.u[i]) = draw_step(draw.u[i], draw.total[i], w, valid);
            // Selects rather than a branch, so that the loop can run in vector registers.
            let pick = |new: Vec3, old: Vec3| if take { new } else { old };
            draw.chosen[i] |= take;
            draw.wi.set(i, pick(wi_i, draw.wi.get(i)));
            draw.li.set(i, pick(li_i, draw.li.get(i)));
            draw.contribution
                .set(i, pick(contribution, draw.contribution.get(i)));
            draw.dist[i] = if take { dist[i] } else { draw.dist[i] };
            draw.weight[i] = if take { w } else { draw.weight[i] };
        }
    }
}
