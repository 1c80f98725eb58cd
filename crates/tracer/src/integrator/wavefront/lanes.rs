//! The lanes of the wavefront integrator and its steps. One step moves every live path by one
//! vertex:
//!
//! 1. `refill` (scalar, `refill.rs`): lanes whose path ended take the next sample and its camera
//!    ray, made sixteen samples ahead by `make_rays` (vector);
//! 2. `trace_closest` (scalar, `trace.rs`): lanes without a hit yet trace their ray; lanes that
//!    hit nothing end (and take the environment's light along the ray: `add_escaped`), the
//!    others load their triangle (moved to world space, for an instance's) and material;
//! 3. `shade_hit` (vector): the hit point and normal, emission seen by the ray, the light's
//!    sample values;
//! 4. the light each lane's values choose (`lights.rs`, at the end of step 3): the environment
//!    (`sample_environment`, lane by lane) or an area light, whose triangle and point come from
//!    the scene's `LightTable` in the lanes, or for a scene of many lights from the light tree,
//!    lane by lane (`sample_by_tree`, scalar); and in a scene with punctual lamps, each lane's
//!    lamp sample (`lamps.rs`, `light_punctual`: a few lamps chosen per point in vector loops)
//!    with its shadow ray traced at once, two lanes a walk;
//! 5. `scatter` (vector): the light sample's contribution and shadow ray, the BSDF sample, Russian
//!    roulette and the next ray (for a Lambertian, and for a glossy material where the scene has
//!    one: its BSDF made again in the lanes, `glossy.rs`; a specular or general material's lanes
//!    take theirs after it, lane by lane: `scatter_lane_by_lane`, `general.rs`);
//! 6. `trace_shadows` (scalar, `trace.rs`): each shadow ray, together with the lane's next ray
//!    when the path goes on (as `trace_path` does), and the results of the paths that ended.
//!
//! The vector steps are loops over the lanes whose bodies are the scalar integrator's code for one
//! path: branches become selects, and a lane's result is only kept where its path is at that
//! stage. Steps 2 to 6 and the camera rays are compiled for AVX-512 and for AVX2, and the widest
//! the processor has runs ([`Isa`], detected at run time). The scalar trace steps are compiled
//! per instruction set so that a flat mesh's test is inlined into them (`Scene::intersect_in` and
//! its siblings with `INLINED`): a call to the test compiled on its own cost 4 % of the time.

// Elsewhere than x86-64 no `Isa` exists, so the lanes are compiled but never run.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

mod builds;
mod general;
mod glossy;
mod lamps;
mod lights;
mod normals;
mod refill;
mod trace;
mod volumes;

use glossy::GlossyLanes;
use refill::CameraRays;

use super::lights::LightTable;
use super::{DiffuseMaterial, DiffuseScene, LANES, V3};
use crate::bsdf::{lambert_at, Bsdf};
use crate::integrator::direct::LightGeometry;
use crate::integrator::path::survival;
use crate::integrator::PathResult;
use crate::isa::{Isa, Kind};
use crate::light::Environment;
use crate::math::{is_black, offset_unit_normal, spawn_clearance, Frame};
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use crate::sampling::power_heuristic;
use crate::scene::{shading_normal, Hit, Scene};
use crate::settings::{RenderSettings, RussianRoulette};
use glam::{Vec2, Vec3};

// The sample values each vector step draws lie in one group of four dimensions per bounce
// (`owen_sobol_group_lanewise`): bounces start on a group, and the light's three values share one,
// the continuation's and the roulette's another.
const _: () = assert!(dims::BOUNCE_BASE.is_multiple_of(4) && dims::PER_BOUNCE.is_multiple_of(4));
const _: () =
    assert!(dims::LIGHT_POINT.is_multiple_of(4) && dims::LIGHT_SELECT / 4 == dims::LIGHT_POINT / 4);
const _: () = assert!(dims::BSDF_DIR.is_multiple_of(4) && dims::ROULETTE / 4 == dims::BSDF_DIR / 4);
const _: () =
    assert!(dims::DIRECT_DIR.is_multiple_of(4) && dims::ALPHA / 4 == dims::DIRECT_DIR / 4);

/// The alpha-coverage value of bounce `depth` of the sample with `key` and `index_rev`
/// (`trace_path`'s `alpha_at`: `PixelSampler::bounce1(depth, dims::ALPHA)`), for the closest ray
/// that finds the vertex at `depth` and for that vertex's shadow rays.
#[inline(always)]
fn alpha_value(key: u32, index_rev: u32, depth: u32) -> f32 {
    let group = bounce_dim(depth, dims::DIRECT_DIR);
    owen_sobol_group_lanewise(key, index_rev, group, [dims::ALPHA - dims::DIRECT_DIR])[0]
}

type F = [f32; LANES];
type U = [u32; LANES];
type B = [bool; LANES];

/// Every lane's state. A lane is `alive` while it holds a path; the other masks say where that
/// path is within the current step.
pub(super) struct Lanes<'a> {
    scene: &'a Scene,
    materials: &'a [DiffuseMaterial],
    /// The lights in the lanes' layout; None: chosen by the light tree, lane by lane.
    lights: Option<&'a LightTable>,
    settings: &'a RenderSettings,
    depth_limit: u32,
    /// The scene has punctual lights: each vertex samples one (`light_punctual`).
    punctual: bool,
    /// The scene's environment, if it has one.
    environment: Option<&'a Environment>,
    /// The light sample may choose the environment (`Lights::sampled_environment`).
    sampled_environment: bool,
    /// Which of the scene's meshes have vertex normals (a constant of `shade_hit`'s: one of
    /// [`normals`]).
    normals: u8,

    // The sample each lane renders.
    x: U,
    y: U,
    index: U,
    /// The pixel's sampler key and the index bit-reversed, as `PixelSampler` holds them.
    key: U,
    index_rev: U,
    alive: B,
    /// The next samples' camera rays, made ahead of the lanes that take them.
    camera_rays: CameraRays,

    // The path.
    o: V3,
    d: V3,
    beta: V3,
    l: V3,
    /// Emission found by the current ray is MIS-weighted against light sampling with this BSDF
    /// pdf (false: counted in full, for camera rays).
    mis: B,
    bsdf_pdf: F,
    depth: U,
    rays: U,
    vertices: U,
    /// The current ray's closest hit is yet to be traced (it was not traced with a shadow ray).
    untraced: B,
    found: [Option<Hit>; LANES],

    // The hit, loaded by `trace_closest`.
    hit: B,
    t: F,
    b1: F,
    b2: F,
    corner_a: V3,
    corner_b: V3,
    corner_c: V3,
    /// The hit triangle's vertex normals (zero for a mesh without them: never read then).
    normal_a: V3,
    normal_b: V3,
    normal_c: V3,
    /// The hit triangle's mesh has vertex normals (kept only where some meshes have them and
    /// others not: `normals::MIXED`).
    smooth: B,
    albedo: V3,
    /// The glossy lobes at a textured material's hit (`Lanes::lobes`; stale elsewhere).
    texel_lobes: [Option<crate::bsdf::GlossyLobes>; LANES],
    emission_front: V3,
    emission_back: V3,
    diffuse_on: B,
    /// Where the ray hit an emitter after a BSDF sample with MIS: the area density with which the
    /// light sample at the vertex it left picks that point (`AreaLights::pdf`), × the area
    /// lights' choice; zero elsewhere.
    light_density: F,

    // Set by `shade_hit`.
    p: V3,
    ng: V3,
    /// The shading normal (`ng` for a mesh without vertex normals).
    ns: V3,
    /// The path goes on from this vertex (it is within the depth limit).
    go: B,

    // Set at the end of `shade_hit`, from the light table.
    light_ok: B,
    light_point: V3,
    light_normal: V3,
    light_pdf_area: F,
    light_front: V3,
    light_back: V3,
    /// The sample value that chooses the punctual light.
    u_punctual: F,

    // Set by `scatter`.
    shadow: B,
    shadow_o: V3,
    shadow_d: V3,
    shadow_t_max: F,
    shadow_value: V3,
    /// The path continues with the new ray in `o`, `d`.
    cont: B,

    // Set at the end of `shade_hit` and by `light_environment`, in a scene with an environment.
    // Declared last: among the fields above, they slowed the steps of every scene
    // (docs/benchmarks.md, December 5).
    /// The lane's light sample is the environment's (not an area light's): a direction
    /// `env_wi` with radiance `env_radiance` and density `env_pdf` (× the environment's choice),
    /// where `env_ok`. Then (`light_environment`) `env_ok` says whether it contributes
    /// `env_value` if the shadow ray from `env_o` along `env_wi` is clear.
    env_light: B,
    env_ok: B,
    env_wi: V3,
    env_radiance: V3,
    env_pdf: F,
    env_value: V3,
    env_o: V3,

    /// The hit's material (for a specular one's BSDF: `scatter_lane_by_lane`).
    material: U,
    /// Some material is specular (`DiffuseMaterial::specular`).
    any_specular: bool,
    /// Some material is glossy or general (`DiffuseMaterial::glossy`, `::general`): the vector
    /// steps that evaluate and sample the BSDF run their copies that model it (`GLOSSY`), and
    /// take the general lanes' values from `GlossyLanes`.
    any_glossy: bool,
    /// Some mesh has tangents (`DiffuseScene::tangents`): frames are oriented by `tangent`.
    tangents: bool,
    /// The hit's tangent (zero where its mesh has none, which orients a frame as none does).
    tangent: V3,
    /// Some material is textured or some mesh has tangents: `shade_texels` runs.
    texels: bool,
    /// Some material's volume absorbs (`Volume::sigma_a` not zero): each lane tracks the
    /// absorption of the medium its path is in (`volumes.rs`).
    any_absorbing: bool,
    /// The absorption coefficient of the medium each lane's path is in (zero outside every
    /// volume, and inside a clear one: its transmittance is exactly 1 either way).
    medium: V3,
    /// For each lane inside an absorbing medium, its light sample's value with the medium's
    /// transmittance (`absorb_light_samples`), which `scatter`'s loop leaves out.
    absorbed_value: V3,
    /// Some material has alpha (`Scene::any_alpha`): each ray query takes its lane's coverage
    /// value (`Lanes::alpha_at`).
    alpha: bool,
    /// Some material is general (`DiffuseMaterial::general`).
    any_general: bool,
    /// Each lane's BSDF at its hit, where its material is general (`Lanes::shade_general`);
    /// None elsewhere.
    general: Box<[Option<Bsdf>; LANES]>,
}

impl<'a> Lanes<'a> {
    pub(super) fn new(
        scene: &'a Scene,
        diffuse: &'a DiffuseScene,
        settings: &'a RenderSettings,
    ) -> Self {
        Lanes {
            scene,
            materials: &diffuse.materials,
            lights: diffuse.lights.as_deref(),
            settings,
            depth_limit: settings.depth_limit(),
            punctual: !scene.lights.punctual.is_empty(),
            environment: scene.lights.environment.as_ref(),
            sampled_environment: scene.lights.sampled_environment().is_some(),
            normals: normals::of(scene),
            x: [0; LANES],
            y: [0; LANES],
            index: [0; LANES],
            key: [0; LANES],
            index_rev: [0; LANES],
            alive: [false; LANES],
            camera_rays: CameraRays::new(),
            o: V3::ZERO,
            d: V3::ZERO,
            beta: V3::ZERO,
            l: V3::ZERO,
            mis: [false; LANES],
            bsdf_pdf: [0.0; LANES],
            depth: [0; LANES],
            rays: [0; LANES],
            vertices: [0; LANES],
            untraced: [false; LANES],
            found: [None; LANES],
            hit: [false; LANES],
            t: [0.0; LANES],
            b1: [0.0; LANES],
            b2: [0.0; LANES],
            corner_a: V3::ZERO,
            corner_b: V3::ZERO,
            corner_c: V3::ZERO,
            normal_a: V3::ZERO,
            normal_b: V3::ZERO,
            normal_c: V3::ZERO,
            smooth: [false; LANES],
            albedo: V3::ZERO,
            texel_lobes: [None; LANES],
            emission_front: V3::ZERO,
            emission_back: V3::ZERO,
            diffuse_on: [false; LANES],
            light_density: [0.0; LANES],
            p: V3::ZERO,
            ng: V3::ZERO,
            ns: V3::ZERO,
            go: [false; LANES],
            light_ok: [false; LANES],
            light_point: V3::ZERO,
            light_normal: V3::ZERO,
            light_pdf_area: [0.0; LANES],
            light_front: V3::ZERO,
            light_back: V3::ZERO,
            u_punctual: [0.0; LANES],
            env_light: [false; LANES],
            env_ok: [false; LANES],
            env_wi: V3::ZERO,
            env_radiance: V3::ZERO,
            env_pdf: [0.0; LANES],
            env_value: V3::ZERO,
            env_o: V3::ZERO,
            material: [0; LANES],
            any_specular: diffuse.materials.iter().any(|m| m.specular.is_some()),
            any_glossy: diffuse
                .materials
                .iter()
                .any(|m| m.glossy.is_some() || m.general),
            tangents: diffuse.tangents,
            tangent: V3::ZERO,
            texels: diffuse.tangents || diffuse.materials.iter().any(|m| m.textured),
            any_absorbing: diffuse.absorbing,
            medium: V3::ZERO,
            absorbed_value: V3::ZERO,
            alpha: scene.any_alpha(),
            any_general: diffuse.materials.iter().any(|m| m.general),
            general: Box::new([None; LANES]),
            shadow: [false; LANES],
            shadow_o: V3::ZERO,
            shadow_d: V3::ZERO,
            shadow_t_max: [0.0; LANES],
            shadow_value: V3::ZERO,
            cont: [false; LANES],
        }
    }

    /// Renders all of `work`, handing each sample's result to `each`, with the vector steps
    /// compiled for `isa`.
    pub(super) fn run(
        &mut self,
        isa: Isa,
        mut work: impl Iterator<Item = (u32, u32, u32)>,
        mut each: impl FnMut(u32, u32, u32, PathResult),
    ) {
        loop {
            self.refill(isa, &mut work, &mut each);
            if !self.alive.iter().any(|&a| a) {
                return;
            }
            self.trace_closest_for(isa);
            if let Some(env) = self.environment {
                self.add_escaped(env);
            }
            if self.any_absorbing {
                self.absorb_along_rays();
            }
            self.shade_hit_for(isa);
            if self.punctual {
                self.light_punctual_for(isa);
            }
            if self.sampled_environment {
                self.light_environment_for(isa);
            }
            if self.any_absorbing {
                self.absorb_light_samples();
            }
            self.scatter_for(isa);
            if self.any_absorbing {
                self.take_absorbed_light_samples();
            }
            if self.sampled_environment {
                self.take_environment_shadows_for(isa);
            }
            if self.any_specular || self.any_general {
                self.scatter_lane_by_lane();
            }
            self.trace_shadows_for(isa, &mut each);
        }
    }

    /// The surface at each hit (`Scene::surface`), the emission the ray
    /// sees (`trace_path` step 1), and the sample values of the light sample.
    #[inline(always)]
    fn shade_hit<const NORMALS: u8>(&mut self, isa: Isa) {
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

    /// Lane `i`'s alpha-coverage value for bounce `depth` ([`alpha_value`]; 0 in a scene
    /// without alpha, as `trace_path` takes it).
    #[inline(always)]
    fn alpha_at(&self, i: usize, depth: u32) -> f32 {
        match self.alpha {
            true => alpha_value(self.key[i], self.index_rev[i], depth),
            false => 0.0,
        }
    }

    /// [`Lanes::scatter`] with the roulette's variant a constant in each copy: a `match` on it
    /// inside the loop would keep the loop from being vectorised.
    #[inline(always)]
    fn scatter_by_roulette<const GLOSSY: bool>(&mut self) {
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
            let mut cont = go && sampled && !is_black(beta_next);

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
    }
}
