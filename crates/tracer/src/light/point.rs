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
        let (sample, lit) = self.sample_li_masked(p);
        lit.then_some(sample)
    }

    /// [`PointLight::sample_li`] without a branch: the sample, and whether there is one (where
    /// not, the values mean nothing). For the wavefront's vector loops over lanes.
    #[inline(always)]
    pub fn sample_li_masked(&self, p: Vec3) -> (PunctualSample, bool) {
        let d = self.position - p;
        let r2 = d.length_squared();
        let dist = r2.sqrt();
        let sample = PunctualSample {
            wi: d / dist,
            dist,
            li: self.intensity / r2,
        };
        // Not `r2 > 0.0`: a NaN distance is lit, as the branch `r2 <= 0.0 → None` had it.
        (sample, r2 > 0.0 || r2.is_nan())
    }

    pub fn power(&self) -> f32 {
        4.0 * PI * crate::math::luminance(self.intensity)
    }
}
