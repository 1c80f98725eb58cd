//! Light sources. Three families:
//! - area lights: every emissive triangle ([`AreaLights`]); reached both by light sampling and by
//!   rays that hit them; a few are chosen by power, many by a light tree ([`LightTree`]) in
//!   proportion to what each may send to the shading point;
//! - the environment ([`Environment`]): radiance from infinitely far away, one colour or an
//!   equirectangular image; reached by light sampling and by rays that leave the scene. Area lights
//!   and the environment share one light sample per vertex: the environment is chosen with
//!   probability [`Lights::environment_choice`] (by power), an area light otherwise;
//! - punctual lights from `KHR_lights_punctual` ([`PunctualLight`]: point, spot, directional), each in
//!   its own file; delta distributions, so they are reached by light sampling only, whatever the
//!   direct-lighting strategy. They get a light sample of their own: a few chosen at each point
//!   by what each sends there ([`choose_by_contribution`]), many (a lit street) by a light tree
//!   over the point and spot lamps ([`PunctualTree`]).
//!
//! Whether a family is chosen by a tree is decided in one place, [`chooses_by_tree`], from the
//! number of its lights alone; whether lamps are chosen per point, in [`chooses_per_point`].
//!
//! Units: radiometric, linear RGB. Emission and the environment are radiance (W/(m²·sr)), point and
//! spot intensities W/sr, directional irradiance W/m²; pixels are radiance. glTF's photometric
//! punctual lights are converted by the loader (`gltf/lights.rs`, 683 lm/W).

mod area;
mod directional;
mod environment;
mod per_point_choice;
mod point;
mod punctual_choice;
mod spot;
mod tree;

#[cfg(test)]
pub(crate) use area::by_solid_angle;
pub(crate) use area::point_on;
pub(crate) use area::{near_plane, solid_angle_sample_lane};
pub use area::{AreaLightSample, AreaLights, MAX_POWER_CHOSEN};
pub use directional::DirectionalLight;
#[cfg(test)]
pub(crate) use environment::map_for_tests;
pub use environment::{
    Environment, EnvironmentError, EnvironmentSample, MAX_DISTRIBUTION_SIZE, MAX_ENVIRONMENT_TEXELS,
};
pub(crate) use per_point_choice::draw_step;
pub use per_point_choice::{choose_by_contribution, ChosenLamp};
pub use point::PointLight;
pub use punctual_choice::PunctualTree;
pub use spot::SpotLight;
pub use tree::LightTree;

use crate::sampling::Distribution1D;
use glam::Vec3;

/// Whether a family of `lights` lights (emissive triangles, or point and spot lamps) is chosen by
/// a light tree rather than by power alone: the one place that decides, from the count alone
/// (see [`MAX_POWER_CHOSEN`]).
pub fn chooses_by_tree(lights: usize) -> bool {
    lights > MAX_POWER_CHOSEN
}

/// Whether a scene's punctual lamps (`lamps` of them, all kinds) are chosen at each shading point
/// by what each sends there ([`choose_by_contribution`]) rather than by power or a tree: the one
/// place that decides. Up to [`MAX_POWER_CHOSEN`], where evaluating every lamp at every vertex
/// stays cheaper than the shadow ray. One lamp too: the choice is then certain, its cost the
/// lamp's light and the BSDF that the sample needs anyway, and the wavefront's lanes make it in
/// vector code (`lanes/lamps.rs`).
pub fn chooses_per_point(lamps: usize) -> bool {
    (1..=MAX_POWER_CHOSEN).contains(&lamps)
}

/// Incident light from a punctual light at a point.
#[derive(Clone, Copy, Debug)]
pub struct PunctualSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3,
    /// Distance to the light (∞ for directional lights).
    pub dist: f32,
    /// Irradiance at normal incidence carried along `wi` (intensity / r² for positional lights).
    pub li: Vec3,
}

/// A `KHR_lights_punctual` light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PunctualLight {
    Point(PointLight),
    Spot(SpotLight),
    Directional(DirectionalLight),
}

impl PunctualLight {
    /// Light arriving at `p`, or `None` where the light sends none.
    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<PunctualSample> {
        match self {
            PunctualLight::Point(l) => l.sample_li(p),
            PunctualLight::Spot(l) => l.sample_li(p),
            PunctualLight::Directional(l) => l.sample_li(p),
        }
    }

    /// Emitted power (W-like units), used to choose among lights. Directional lights are credited
    /// with the power they deliver to a disk of the scene's bounding radius.
    pub fn power(&self, scene_radius: f32) -> f32 {
        match self {
            PunctualLight::Point(l) => l.power(),
            PunctualLight::Spot(l) => l.power(),
            PunctualLight::Directional(l) => l.power(scene_radius),
        }
    }
}

/// All lights of a scene.
#[derive(Clone, Debug, Default)]
pub struct Lights {
    pub area: AreaLights,
    pub punctual: Vec<PunctualLight>,
    /// Choice among punctual lights, proportional to power.
    pub punctual_distribution: Distribution1D,
    /// Many point and spot lamps: chosen by a light tree instead (see [`chooses_by_tree`]).
    pub punctual_tree: Option<PunctualTree>,
    /// A few lamps: chosen at each point by what each sends there instead (see
    /// [`chooses_per_point`]).
    pub punctual_per_point: bool,
    /// The environment, if the render has one (see [`Lights::set_environment`]).
    pub environment: Option<Environment>,
    /// Probability that a vertex's light sample goes to the environment rather than to an area
    /// light (by power; 1 without area lights, 0 without an environment, and 0 for an
    /// environment of one colour: see [`Lights::set_environment`]).
    pub environment_choice: f32,
    /// 1 − `environment_choice`: the probability of the area lights (exactly 1 without an
    /// environment, so the area lights' densities keep their bits).
    pub area_choice: f32,
}

impl Lights {
    pub fn new(area: AreaLights, punctual: Vec<PunctualLight>, scene_radius: f32) -> Self {
        let powers: Vec<f32> = punctual.iter().map(|l| l.power(scene_radius)).collect();
        let positional = punctual
            .iter()
            .filter(|l| !matches!(l, PunctualLight::Directional(_)))
            .count();
        let punctual_tree = chooses_by_tree(positional)
            .then(|| PunctualTree::new(&punctual, &powers))
            .flatten();
        Lights {
            area,
            punctual_distribution: Distribution1D::new(&powers),
            punctual_per_point: punctual_tree.is_none() && chooses_per_point(punctual.len()),
            punctual_tree,
            punctual,
            environment: None,
            environment_choice: 0.0,
            area_choice: 1.0,
        }
    }

    /// Sets the environment (none, or one whose every direction is black, removes it) and the
    /// choice between it and the area lights, by power over a scene of radius `scene_radius`.
    ///
    /// An environment of one colour is never light-sampled (its choice is 0): the path's own
    /// BSDF-sampled rays find it, counted in full. Sampling it can only spend a shadow ray on a
    /// direction the BSDF would draw at least as well: the same radiance everywhere, drawn
    /// uniformly over the sphere (half of it below the surface) against the BSDF's own lobe.
    /// Cycles does the same for a constant world. Measured: docs/benchmarks.md (December 6).
    pub fn set_environment(&mut self, environment: Option<Environment>, scene_radius: f32) {
        self.environment = environment.filter(|e| !e.is_black());
        (self.environment_choice, self.area_choice) = match &self.environment {
            None => (0.0, 1.0),
            Some(env) if env.is_uniform() => (0.0, 1.0),
            Some(_) if self.area.is_empty() => (1.0, 0.0),
            Some(env) => {
                let env_power = env.power(scene_radius) as f64;
                let p = (env_power / (env_power + self.area.total_power())) as f32;
                // Neither family is starved: each keeps at least 1/16 of the samples.
                let p = p.clamp(1.0 / 16.0, 15.0 / 16.0);
                (p, 1.0 - p)
            }
        };
    }

    /// Area lights or a light-sampled environment: something for the shared light sample to find.
    #[inline]
    pub fn has_sampled(&self) -> bool {
        !self.area.is_empty() || self.sampled_environment().is_some()
    }

    /// The environment, where the shared light sample may choose it (see
    /// [`Lights::set_environment`]).
    #[inline]
    pub fn sampled_environment(&self) -> Option<&Environment> {
        self.environment
            .as_ref()
            .filter(|_| self.environment_choice > 0.0)
    }

    /// Chooses a punctual light for the point `p` with unit normal `n` (zero: none): by the tree
    /// where there is one, in proportion to power otherwise. Returns the light and its
    /// probability; None when no light can reach `p`. (Where [`Lights::punctual_per_point`] holds,
    /// the integrator chooses by [`choose_by_contribution`] instead.)
    #[inline]
    pub fn choose_punctual(&self, p: Vec3, n: Vec3, u: f32) -> Option<(&PunctualLight, f32)> {
        if let Some(tree) = &self.punctual_tree {
            let (i, pmf) = tree.choose(p, n, u)?;
            return Some((&self.punctual[i], pmf));
        }
        if self.punctual_distribution.is_empty() {
            return None;
        }
        let (i, pmf) = self.punctual_distribution.sample_discrete(u);
        Some((&self.punctual[i], pmf))
    }

    /// Chooses the punctual lights by power alone even where [`chooses_by_tree`] or
    /// [`chooses_per_point`] says otherwise: the same expected image, for tests and benchmarks
    /// that compare the choices.
    pub fn choose_punctual_by_power(&mut self) {
        self.punctual_tree = None;
        self.punctual_per_point = false;
    }
}
