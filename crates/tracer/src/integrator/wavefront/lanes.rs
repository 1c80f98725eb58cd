//! The lanes of the wavefront integrator and its steps. One step moves every live path by one
//! vertex:
//!
//! 1. `refill` (scalar, `refill.rs`): lanes whose path ended take the next sample and its camera
//!    ray, made sixteen samples ahead by `make_rays` (vector);
//! 2. `trace_closest` (scalar, `trace.rs`): lanes without a hit yet trace their ray; lanes that
//!    hit nothing end (and take the environment's light along the ray: `add_escaped`), the
//!    others load their triangle (moved to world space, for an instance's) and material;
//! 3. `shade_hit` (vector, `shade.rs`): the hit point and normal, emission seen by the ray, the light's
//!    sample values;
//! 4. the light each lane's values choose (`lights.rs`, at the end of step 3): the environment
//!    (`sample_environment`, lane by lane) or an area light, whose triangle and point come from
//!    the scene's `LightTable` in the lanes, or for a scene of many lights from the light tree,
//!    lane by lane (`sample_by_tree`, scalar); and in a scene with punctual lamps, each lane's
//!    lamp sample (`lamps.rs`, `light_punctual`: a few lamps chosen per point in vector loops)
//!    with its shadow ray traced at once, two lanes a walk;
//! 5. `scatter` (vector, `scatter.rs`): the light sample's contribution and shadow ray, the BSDF sample, Russian
//!    roulette and the next ray (for a Lambertian, and for a glossy material where the scene has
//!    one: its BSDF made again in the lanes, `glossy.rs`; a specular or general material's lanes
//!    take theirs after it, lane by lane: `scatter_lane_by_lane`, `general.rs`, as do the lanes
//!    whose continuation the caustic guide's mixture draws: `guided.rs`);
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
mod guided;
mod lamps;
mod lights;
mod normals;
mod refill;
mod scatter;
mod shade;
mod trace;
mod volumes;

use glossy::GlossyLanes;
use refill::CameraRays;

use super::lights::LightTable;
use super::{DiffuseMaterial, DiffuseScene, LANES, V3};
use crate::bsdf::Bsdf;
use crate::guide::{CausticGuide, GuideCell};
use crate::integrator::PathResult;
use crate::isa::{Isa, Kind};
use crate::light::Environment;
use crate::sampler::{bounce_dim, dims, owen_sobol_group_lanewise};
use crate::scene::{Hit, Scene};
use crate::settings::RenderSettings;

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
    /// Each hit's tangent with its handedness (`Scene::hit_tangent`), where some mesh has
    /// tangents: read by `shade_texels` and taken again by `shade_general`.
    tangent4: [Option<glam::Vec4>; LANES],

    // The caustic guide (`guided.rs`), in a scene that has one.
    guide: Option<&'a CausticGuide>,
    /// The lane's continuation is drawn from the guide's mixture (its vertex has non-delta lobes
    /// and lies in a cell of the guide's, `cells`): its light sample's MIS weight takes the
    /// mixture's density, from the guide's density `guide_pdf` of the light's direction.
    guided: B,
    guide_pdf: F,
    cells: [Option<GuideCell<'a>>; LANES],
    /// A textured material's BSDF at the lane's hit, before `Bsdf::at` (`Scene::textured_bsdf`),
    /// kept by `shade_texels` in a scene with a guide for the guided lanes' samples.
    texel_bsdf: Box<[Option<Bsdf>; LANES]>,
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
            tangent4: [None; LANES],
            guide: scene.caustic_guide(),
            guided: [false; LANES],
            guide_pdf: [0.0; LANES],
            cells: [None; LANES],
            texel_bsdf: Box::new([None; LANES]),
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
            if self.guide.is_some() {
                self.find_guide_cells();
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
            if self.any_specular || self.any_general || self.guide.is_some() {
                self.scatter_lane_by_lane();
            }
            self.trace_shadows_for(isa, &mut each);
        }
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
}
