//! The lanes' light samples (`trace_path`'s `light_query` and `direct_punctual`, lane by lane or in
//! the lanes): which light each lane samples at its vertex (`choose_lights`: the environment or
//! an area light, from the light table or the light tree), the environment's sample
//! (`sample_environment`) and its light along the rays that leave the scene (`add_escaped`). The
//! punctual lamps' samples are `lamps.rs`'s.

use super::{GlossyLanes, Lanes, F, LANES, V3};
use crate::bsdf::lambert_at;
use crate::integrator::direct::{environment_value, light_uv};
use crate::isa::Isa;
use crate::light::{AreaLightSample, Environment};
use crate::math::{offset_unit_normal, spawn_clearance};
use crate::sampling::power_heuristic;
use glam::{Vec2, Vec3};

/// Light-tree walks made side by side (`AreaLights::sample_many`).
const TREE_WALKS: usize = 2;

impl Lanes<'_> {
    /// Chooses each lane's light sample from its values (`light_query`): with an environment,
    /// the environment with probability `Lights::environment_choice`, and otherwise an area light
    /// chosen by the selection value remapped to the rest of its range; without one, always an
    /// area light, by the value as drawn.
    #[inline(always)]
    pub(super) fn choose_lights(&mut self, isa: Isa, u_select: &F, u_light: &[F; 2]) {
        let Some(env) = self.environment.filter(|_| self.sampled_environment) else {
            self.choose_area_lights::<false>(isa, u_select, u_light);
            return;
        };
        let lights = &self.scene.lights;
        let (p_env, area_choice) = (lights.environment_choice, lights.area_choice);
        let (mut to_env, mut u_area) = ([false; LANES], [0.0; LANES]);
        for i in 0..LANES {
            to_env[i] = u_select[i] < p_env;
            u_area[i] = ((u_select[i] - p_env) / area_choice).min(1.0 - f32::EPSILON / 2.0);
        }
        self.env_light = to_env;
        self.sample_environment(env, p_env, u_light);
        self.choose_area_lights::<true>(isa, &u_area, u_light);
    }

    /// The area light's triangle and point for each lane that samples one, from the scene's
    /// `LightTable`, in the lanes, or from the light tree, lane by lane. `ENV`: the scene has an
    /// environment, which the lanes of `env_light` sample instead, and the area lights' densities
    /// include their family's choice (without an environment, the code is what it was before
    /// there was one).
    #[inline(always)]
    fn choose_area_lights<const ENV: bool>(&mut self, isa: Isa, u_area: &F, u_light: &[F; 2]) {
        let Some(table) = self.lights else {
            if self.scene.lights.area.is_empty() {
                // Nothing to choose (a scene lit by lamps or the sky alone): no walk per lane.
                self.light_ok = [false; LANES];
            } else {
                self.sample_by_tree::<ENV>(u_area, u_light);
            }
            return;
        };
        let (go, diffuse_on, env_light) = (self.go, self.diffuse_on, self.env_light);
        let mut ok = [false; LANES];
        for i in 0..LANES {
            ok[i] = go[i] && diffuse_on[i] && !(ENV && env_light[i]);
        }
        let s = table.sample(u_area, u_light, &self.p, &ok, Some(isa));
        (self.light_ok, self.light_point, self.light_normal) = (ok, s.point, s.normal);
        (self.light_pdf_area, self.light_front, self.light_back) = (s.pdf_area, s.front, s.back);
        if ENV {
            let area_choice = self.scene.lights.area_choice;
            for pdf in &mut self.light_pdf_area {
                *pdf *= area_choice;
            }
        }
    }

    /// Chooses each lane's light triangle and point by the light tree at the lane's vertex, or by
    /// power where a scene without a tree has emissive textures (`AreaLights::sample`'s answers:
    /// [`TREE_WALKS`] lanes' walks at a time) and loads the light's emission.
    fn sample_by_tree<const ENV: bool>(&mut self, u_select: &F, u_light: &[F; 2]) {
        let scene = self.scene;
        let mut waiting = [0usize; LANES];
        let mut count = 0;
        for i in 0..LANES {
            self.light_ok[i] = false;
            if self.go[i] && self.diffuse_on[i] && !(ENV && self.env_light[i]) {
                waiting[count] = i;
                count += 1;
            }
        }
        let query = |lanes: &Self, i: usize| {
            let u = Vec2::new(u_light[0][i], u_light[1][i]);
            (lanes.p.get(i), lanes.ng.get(i), u_select[i], u)
        };
        let mut groups = waiting[..count].chunks_exact(TREE_WALKS);
        for group in &mut groups {
            let lanes: [usize; TREE_WALKS] = std::array::from_fn(|w| group[w]);
            let samples = scene.lights.area.sample_many(lanes.map(|i| query(self, i)));
            for (i, ls) in lanes.into_iter().zip(samples) {
                self.take_light::<ENV>(i, ls);
            }
        }
        for &i in groups.remainder() {
            let (p, n, u_select, u) = query(self, i);
            let ls = scene.lights.area.sample(p, n, u_select, u);
            self.take_light::<ENV>(i, ls);
        }
    }

    /// Lane `i`'s light sample `ls`, its emission loaded from the light's material.
    #[inline(always)]
    fn take_light<const ENV: bool>(&mut self, i: usize, ls: Option<AreaLightSample>) {
        let Some(ls) = ls else { return };
        let scene = self.scene;
        let m = &self.materials[scene.mesh.material[ls.triangle as usize] as usize];
        self.light_ok[i] = true;
        self.light_point.set(i, ls.point);
        self.light_normal.set(i, ls.normal);
        self.light_pdf_area[i] = if ENV {
            ls.pdf_area * scene.lights.area_choice
        } else {
            ls.pdf_area
        };
        self.light_front.set(i, m.emission_front);
        self.light_back.set(i, m.emission_back);
        if m.emissive_textured {
            // The texel where the sample lands (`area_light_query`'s `light_uv`).
            let tri = ls.triangle as usize;
            let uv = light_uv(scene, tri, ls.barycentrics);
            let material = &scene.materials[scene.mesh.material[tri] as usize];
            self.light_front
                .set(i, material.emission(&scene.textures, &uv, true));
            self.light_back
                .set(i, material.emission(&scene.textures, &uv, false));
        }
    }

    /// The environment's direction, radiance and density (× its choice `p_env`) for each lane
    /// that chose it (`env_light`) (`Environment::sample`, lane by lane: one colour or an image's distribution).
    fn sample_environment(&mut self, env: &Environment, p_env: f32, u: &[F; 2]) {
        for (i, (&u0, &u1)) in u[0].iter().zip(&u[1]).enumerate() {
            self.env_ok[i] = false;
            if !(self.env_light[i] && self.go[i] && self.diffuse_on[i]) {
                continue;
            }
            let Some(es) = env.sample(Vec2::new(u0, u1)) else {
                continue;
            };
            self.env_ok[i] = true;
            self.env_wi.set(i, es.wi);
            self.env_radiance.set(i, es.radiance);
            self.env_pdf[i] = p_env * es.pdf;
        }
    }

    /// `scatter`'s step 2 for the lanes whose light sample is the environment's (`light_query`):
    /// its value and shadow ray's origin, before `scatter` moves the lanes to their next rays,
    /// and handed to the shadow rays after it (`take_environment_shadows`): inside `scatter`, the
    /// same work slowed scenes without an environment (docs/benchmarks.md, December 5). Vector
    /// code, as `scatter`'s loops: every lane computed, the environment's lanes kept.
    /// `GLOSSY` as in `scatter`.
    #[inline(always)]
    pub(super) fn light_environment<const GLOSSY: bool>(&mut self) {
        let glossy = match GLOSSY {
            true => self.glossy_lanes(),
            false => GlossyLanes::none(),
        };
        let (env_light, env_ok, go) = (self.env_light, self.env_ok, self.go);
        let (ps, ngs, nss, ds) = (self.p, self.ng, self.ns, self.d);
        let (albedos, betas) = (self.albedo, self.beta);
        let (wis, radiances, pdfs) = (self.env_wi, self.env_radiance, self.env_pdf);
        let (ca, cb, cc) = (self.corner_a, self.corner_b, self.corner_c);
        let (guided, guide_pdfs) = (self.guided, self.guide_pdf);
        let (mut ok, mut values, mut origins) = ([false; LANES], V3::ZERO, V3::ZERO);
        let (glossy_f, glossy_pdf) = match GLOSSY {
            true => glossy.eval_pdf(&nss, &ngs, &ds, &wis),
            false => (V3::ZERO, [0.0; LANES]),
        };
        for i in 0..LANES {
            let (p, ng, wi) = (ps.get(i), ngs.get(i), wis.get(i));
            let (wo, albedo) = (-ds.get(i), albedos.get(i));
            let (f, bsdf_pdf) = lambert_at::eval_pdf(nss.get(i), ng, albedo, wo, wi);
            let (f, bsdf_pdf) = match GLOSSY && glossy.shaded[i] {
                true => (glossy_f.get(i), glossy_pdf[i]),
                false => (f, bsdf_pdf),
            };
            let bsdf_pdf = match guided[i] {
                true => crate::guide::mix_densities(guide_pdfs[i], bsdf_pdf),
                false => bsdf_pdf,
            };
            let (radiance, pdf) = (radiances.get(i), pdfs[i]);
            let query = environment_value(radiance, pdf, f, bsdf_pdf, true);
            ok[i] = env_light[i] & go[i] & env_ok[i] & query.is_some();
            let value = query.unwrap_or(Vec3::ZERO);
            values.set(i, betas.get(i) * value);
            let clearance = spawn_clearance([ca.get(i), cb.get(i), cc.get(i)]);
            let side = if wi.dot(ng) > 0.0 { ng } else { -ng };
            origins.set(i, offset_unit_normal(p, side, clearance));
        }
        (self.env_ok, self.env_value, self.env_o) = (ok, values, origins);
    }

    /// The environment's light samples as the lanes' shadow rays (after `scatter`, which gave
    /// these lanes none).
    #[inline(always)]
    pub(super) fn take_environment_shadows(&mut self) {
        let (env_light, env_ok) = (self.env_light, self.env_ok);
        let (values, origins, wis) = (self.env_value, self.env_o, self.env_wi);
        let (mut shadow, mut rays) = (self.shadow, self.rays);
        let (mut shadow_value, mut shadow_o) = (self.shadow_value, self.shadow_o);
        let (mut shadow_d, mut shadow_t_max) = (self.shadow_d, self.shadow_t_max);
        for i in 0..LANES {
            if env_light[i] {
                shadow[i] = env_ok[i];
                rays[i] += u32::from(env_ok[i]);
                shadow_value.set(i, values.get(i));
                shadow_o.set(i, origins.get(i));
                shadow_d.set(i, wis.get(i));
                shadow_t_max[i] = f32::INFINITY;
            }
        }
        (self.shadow, self.rays) = (shadow, rays);
        (self.shadow_value, self.shadow_o) = (shadow_value, shadow_o);
        (self.shadow_d, self.shadow_t_max) = (shadow_d, shadow_t_max);
    }

    /// Adds the environment's light along the ray of each live lane that hit nothing, weighted as
    /// `trace_path` weighs it: in full for a camera ray, by the power heuristic against the
    /// environment's sample after a BSDF sample.
    #[inline(always)]
    pub(super) fn add_escaped(&mut self, env: &Environment) {
        let p_env = self.scene.lights.environment_choice;
        for i in 0..LANES {
            if !self.alive[i] || self.hit[i] {
                continue;
            }
            let d = self.d.get(i);
            let w = if self.mis[i] {
                power_heuristic(self.bsdf_pdf[i], p_env * env.pdf(d))
            } else {
                1.0
            };
            if w > 0.0 {
                let l = self.l.get(i) + self.beta.get(i) * env.radiance(d) * w;
                self.l.set(i, l);
            }
        }
    }
}
