use super::PunctualSample;
use glam::Vec3;
use std::f32::consts::PI;

/// A spot light: a point light restricted to a cone, with the smooth angular falloff between the
/// inner and outer cone angles that `KHR_lights_punctual` specifies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpotLight {
    pub position: Vec3,
    /// Unit direction the spot points to.
    pub direction: Vec3,
    pub intensity: Vec3,
    pub cos_inner: f32,
    pub cos_outer: f32,
}

impl SpotLight {
    /// The falloff exactly as `KHR_lights_punctual`'s reference code writes it:
    /// scale = 1 / max(0.001, cos inner − cos outer), offset = −cos outer · scale,
    /// t = saturate(cos θ · scale + offset), attenuation t².
    #[inline]
    pub fn falloff(&self, cos_theta: f32) -> f32 {
        let scale = 1.0 / (self.cos_inner - self.cos_outer).max(1e-3);
        let offset = -self.cos_outer * scale;
        let t = (cos_theta * scale + offset).clamp(0.0, 1.0);
        t * t
    }

    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<PunctualSample> {
        let (sample, lit) = self.sample_li_masked(p);
        lit.then_some(sample)
    }

    /// [`SpotLight::sample_li`] without a branch (see `PointLight::sample_li_masked`).
    #[inline(always)]
    pub fn sample_li_masked(&self, p: Vec3) -> (PunctualSample, bool) {
        let d = self.position - p;
        let r2 = d.length_squared();
        let dist = r2.sqrt();
        let wi = d / dist;
        let f = self.falloff((-wi).dot(self.direction));
        let sample = PunctualSample {
            wi,
            dist,
            li: self.intensity * (f / r2),
        };
        (sample, (r2 > 0.0 || r2.is_nan()) && (f > 0.0 || f.is_nan()))
    }

    /// Power of the cone up to the middle of the falloff band (an estimate; only its proportion to
    /// other lights' matters).
    pub fn power(&self) -> f32 {
        let cos_mid = 0.5 * (self.cos_inner + self.cos_outer);
        2.0 * PI * (1.0 - cos_mid) * crate::math::luminance(self.intensity)
    }
}
