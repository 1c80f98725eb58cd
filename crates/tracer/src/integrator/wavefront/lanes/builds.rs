//! The builds of the lanes' steps: the vector ones (`make_rays`, `shade_hit`, `scatter`) and the
//! scalar ray queries around them (`trace_closest`, `trace_shadows`), each compiled once per
//! instruction set (`#[target_feature]`), and the dispatch on the [`Isa`] that proves the
//! processor runs them.

use super::refill::CameraRays;
use super::{Isa, Kind, Lanes};
use crate::camera::Camera;
use crate::integrator::PathResult;
use crate::settings::RenderSettings;

impl Lanes<'_> {
    /// [`Lanes::trace_closest`] compiled for `isa`.
    #[inline(always)]
    pub(super) fn trace_closest_for(&mut self, isa: Isa) {
        match isa.0 {
            // SAFETY (each arm): an `Isa` exists only where its features were detected.
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => unsafe { self.trace_closest_avx512() },
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => unsafe { self.trace_closest_avx2() },
        }
    }

    /// [`Lanes::trace_shadows`] compiled for `isa`.
    #[inline(always)]
    pub(super) fn trace_shadows_for(
        &mut self,
        isa: Isa,
        each: &mut impl FnMut(u32, u32, u32, PathResult),
    ) {
        match isa.0 {
            // SAFETY (each arm): an `Isa` exists only where its features were detected.
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => unsafe { self.trace_shadows_avx512(each) },
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => unsafe { self.trace_shadows_avx2(each) },
        }
    }

    /// [`Lanes::shade_hit`] compiled for `isa`.
    #[inline(always)]
    pub(super) fn shade_hit_for(&mut self, isa: Isa) {
        match isa.0 {
            // SAFETY (each arm): an `Isa` exists only where its features were detected.
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => unsafe { self.shade_hit_avx512() },
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => unsafe { self.shade_hit_avx2() },
        }
    }

    /// [`Lanes::scatter`] compiled for `isa`.
    #[inline(always)]
    pub(super) fn scatter_for(&mut self, isa: Isa) {
        match isa.0 {
            // SAFETY (each arm): an `Isa` exists only where its features were detected.
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => unsafe { self.scatter_avx512() },
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => unsafe { self.scatter_avx2() },
        }
    }

    /// `trace_closest` compiled for AVX-512.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn trace_closest_avx512(&mut self) {
        self.trace_closest();
    }

    /// `trace_closest` compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn trace_closest_avx2(&mut self) {
        self.trace_closest();
    }

    /// `trace_shadows` compiled for AVX-512.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn trace_shadows_avx512(&mut self, each: &mut impl FnMut(u32, u32, u32, PathResult)) {
        self.trace_shadows(each);
    }

    /// `trace_shadows` compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn trace_shadows_avx2(&mut self, each: &mut impl FnMut(u32, u32, u32, PathResult)) {
        self.trace_shadows(each);
    }

    /// `shade_hit` compiled for AVX-512.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn shade_hit_avx512(&mut self) {
        self.shade_hit(Isa(Kind::Avx512));
    }

    /// `shade_hit` compiled for AVX2 (with BMI1/2, LZCNT and POPCNT; without FMA, whose fused
    /// rounding would change the bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn shade_hit_avx2(&mut self) {
        self.shade_hit(Isa(Kind::Avx2));
    }

    /// `scatter` compiled for AVX-512.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn scatter_avx512(&mut self) {
        self.scatter_by_roulette();
    }

    /// `scatter` compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn scatter_avx2(&mut self) {
        self.scatter_by_roulette();
    }
}

impl CameraRays {
    /// [`CameraRays::make_rays`] compiled for `isa`.
    #[inline(always)]
    pub(super) fn make_rays_for(&mut self, isa: Isa, camera: &Camera, settings: &RenderSettings) {
        match isa.0 {
            // SAFETY (each arm): an `Isa` exists only where its features were detected.
            #[cfg(target_arch = "x86_64")]
            Kind::Avx512 => unsafe { self.make_rays_avx512(camera, settings) },
            #[cfg(target_arch = "x86_64")]
            Kind::Avx2 => unsafe { self.make_rays_avx2(camera, settings) },
        }
    }

    /// `make_rays` compiled for AVX-512.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn make_rays_avx512(&mut self, camera: &Camera, settings: &RenderSettings) {
        self.make_rays(camera, settings);
    }

    /// `make_rays` compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn make_rays_avx2(&mut self, camera: &Camera, settings: &RenderSettings) {
        self.make_rays(camera, settings);
    }
}
