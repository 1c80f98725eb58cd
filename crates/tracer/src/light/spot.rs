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
        let d = self.position - p;
        let r2 = d.length_squared();
        if r2 <= 0.0 {
            return None;
        }
        let dist = r2.sqrt();
        let wi = d / dist;
        let f = self.falloff((-wi).dot(self.direction));
        if f <= 0.0 {
            return None;
        }
        Some(PunctualSample {
            wi,
            dist,
            li: self.intensity * (f / r2),
        })
    }

    /// Power of the cone up to the middle of the falloff band (an estimate; only its proportion to
    /// other lights' matters).
    pub fn power(&self) -> f32 {
        let cos_mid = 0.5 * (self.cos_inner + self.cos_outer);
        2.0 * PI * (1.0 - cos_mid) * crate::math::luminance(self.intensity)
    }
}
