//! Light sources. Two families, each sampled by its own distribution over power:
//! - area lights: every emissive triangle ([`AreaLights`]); reached both by light sampling and by
//!   rays that hit them;
//! - punctual lights from `KHR_lights_punctual` ([`PunctualLight`]: point, spot, directional), each in
//!   its own file; delta distributions, so they are reached by light sampling only, whatever the
//!   direct-lighting strategy.

mod area;
mod directional;
mod point;
mod spot;

pub(crate) use area::point_on;
pub use area::{AreaLightSample, AreaLights};
pub use directional::DirectionalLight;
pub use point::PointLight;
pub use spot::SpotLight;

use crate::sampling::Distribution1D;
use glam::Vec3;

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
}

impl Lights {
    pub fn new(area: AreaLights, punctual: Vec<PunctualLight>, scene_radius: f32) -> Self {
        let powers: Vec<f32> = punctual.iter().map(|l| l.power(scene_radius)).collect();
        Lights {
            area,
            punctual_distribution: Distribution1D::new(&powers),
            punctual,
        }
    }

    /// Chooses a punctual light in proportion to power. Returns the light and its probability.
    #[inline]
    pub fn choose_punctual(&self, u: f32) -> Option<(&PunctualLight, f32)> {
        if self.punctual_distribution.is_empty() {
            return None;
        }
        let (i, pmf) = self.punctual_distribution.sample_discrete(u);
        Some((&self.punctual[i], pmf))
    }
}
