//! The builds of the lanes' steps: the vector ones (`make_rays`, `shade_hit`, `scatter`) and the
//! scalar ray queries around them (`trace_closest`, `light_punctual`, `trace_shadows`), each compiled once per
//! instruction set (`#[target_feature]`), and the dispatch on the [`Isa`] that proves the
//! processor runs them.

use super::refill::CameraRays;
use super::{normals, Isa, Kind, Lanes};
use crate::camera::Camera;
use crate::integrator::PathResult;
use crate::scene::Scene;
use crate::settings::RenderSettings;

/// For each step: `$name(isa, args…)`, which runs the build `isa` names, and the two builds, the
/// step's body compiled for AVX-512 (F/BW/DQ/VL) and for AVX2 (with BMI1/2, LZCNT and POPCNT;
/// without FMA, whose fused rounding would change the bits). In the body, `$isa` is the build's
/// own `Isa`, a constant there. (`self` is passed in, so that the body's `self` is the method's.)
macro_rules! compiled_per_isa {
    ($(
        $(#[$doc:meta])*
        fn $name:ident, $avx512:ident, $avx2:ident
            (&mut $self:ident, $isa:ident: Isa $(, $arg:ident: $ty:ty)*) $body:block
    )*) => {$(
        $(#[$doc])*
        #[inline(always)]
        pub(super) fn $name(&mut $self, $isa: Isa $(, $arg: $ty)*) {
            match $isa.0 {
                // SAFETY (each arm): an `Isa` exists only where its features were detected.
                #[cfg(target_arch = "x86_64")]
                Kind::Avx512 => unsafe { $self.$avx512($($arg),*) },
                #[cfg(target_arch = "x86_64")]
                Kind::Avx2 => unsafe { $self.$avx2($($arg),*) },
            }
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl")]
        unsafe fn $avx512(&mut $self $(, $arg: $ty)*) {
            let $isa = Isa(Kind::Avx512);
            let _ = $isa;
            $body
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
        unsafe fn $avx2(&mut $self $(, $arg: $ty)*) {
            let $isa = Isa(Kind::Avx2);
            let _ = $isa;
            $body
        }
    )*};
}

impl Lanes<'_> {
    compiled_per_isa! {
        /// [`Lanes::trace_closest`] compiled for `isa`.
        fn trace_closest_for, trace_closest_avx512, trace_closest_avx2
            (&mut self, isa: Isa) {
            self.trace_closest();
        }

        /// [`Lanes::trace_shadows`] compiled for `isa`.
        fn trace_shadows_for, trace_shadows_avx512, trace_shadows_avx2
            (&mut self, isa: Isa, each: &mut impl FnMut(u32, u32, u32, PathResult)) {
            self.trace_shadows(each);
        }

        /// [`Lanes::light_punctual`] compiled for `isa`.
        fn light_punctual_for, light_punctual_avx512, light_punctual_avx2
            (&mut self, isa: Isa) {
            match self.any_glossy {
                true => self.light_punctual::<true>(),
                false => self.light_punctual::<false>(),
            }
        }

        /// [`Lanes::shade_hit`] compiled for `isa`.
        fn shade_hit_for, shade_hit_avx512, shade_hit_avx2
            (&mut self, isa: Isa) {
            match self.normals {
                normals::FLAT => self.shade_hit::<{ normals::FLAT }>(isa),
                normals::SMOOTH => self.shade_hit::<{ normals::SMOOTH }>(isa),
                _ => self.shade_hit::<{ normals::MIXED }>(isa),
            }
        }

        /// [`Lanes::light_environment`] compiled for `isa`.
        fn light_environment_for, light_environment_avx512, light_environment_avx2
            (&mut self, isa: Isa) {
            match self.any_glossy {
                true => self.light_environment::<true>(),
                false => self.light_environment::<false>(),
            }
        }

        /// [`Lanes::take_environment_shadows`] compiled for `isa`.
        fn take_environment_shadows_for, take_environment_shadows_avx512,
            take_environment_shadows_avx2 (&mut self, isa: Isa) {
            self.take_environment_shadows();
        }

        /// [`Lanes::scatter`] compiled for `isa`.
        fn scatter_for, scatter_avx512, scatter_avx2
            (&mut self, isa: Isa) {
            match self.any_glossy {
                true => self.scatter_by_roulette::<true>(),
                false => self.scatter_by_roulette::<false>(),
            }
        }
    }
}

impl CameraRays {
    compiled_per_isa! {
        /// [`CameraRays::make_rays`] compiled for `isa`.
        fn make_rays_for, make_rays_avx512, make_rays_avx2
            (&mut self, isa: Isa, camera: &Camera, settings: &RenderSettings) {
            self.make_rays(camera, settings);
        }

        /// [`CameraRays::trace`] compiled for `isa`.
        fn trace_for, trace_avx512, trace_avx2
            (&mut self, isa: Isa, scene: &Scene) {
            self.trace(scene);
        }
    }
}
