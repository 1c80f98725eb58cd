use super::PunctualSample;
use glam::Vec3;
use std::f32::consts::PI;

/// A directional light (sun-like): parallel light of `illuminance` (lux-like units) travelling along
/// `direction`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionalLight {
    /// Unit direction the light travels in.
    pub direction: Vec3,
    pub illuminance: Vec3,
}

impl DirectionalLight {
    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<PunctualSample> {
        Some(self.sample_li_masked(p).0)
    }

    /// [`DirectionalLight::sample_li`] as `PointLight::sample_li_masked` gives it: always lit.
    #[inline(always)]
    pub fn sample_li_masked(&self, _p: Vec3) -> (PunctualSample, bool) {
        let sample = PunctualSample {
            wi: -self.direction,
            dist: f32::INFINITY,
            li: self.illuminance,
        };
        (sample, true)
    }

    pub fn power(&self, scene_radius: f32) -> f32 {
        PI * scene_radius * scene_radius * crate::math::luminance(self.illuminance)
    }
}
