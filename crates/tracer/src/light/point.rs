use super::PunctualSample;
use glam::Vec3;
use std::f32::consts::PI;

/// An isotropic point light of `intensity` (candela-like units, linear RGB).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: Vec3,
    pub intensity: Vec3,
}

impl PointLight {
    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<PunctualSample> {
        let d = self.position - p;
        let r2 = d.length_squared();
        if r2 <= 0.0 {
            return None;
        }
        let dist = r2.sqrt();
        Some(PunctualSample {
            wi: d / dist,
            dist,
            li: self.intensity / r2,
        })
    }

    pub fn power(&self) -> f32 {
        4.0 * PI * crate::math::luminance(self.intensity)
    }
}
