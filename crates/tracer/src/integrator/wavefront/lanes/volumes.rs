//! Absorbing volumes in the lanes (`KHR_materials_volume` with an attenuation: coloured glass):
//! each lane keeps the absorption coefficient of the medium its path is in (`Lanes::medium`,
//! zero outside), set where a specular or general material transmits (`scatter_lane_by_lane`), and applies it
//! where `trace_path` applies its `medium`: to the throughput over each segment the path travels
//! inside (`absorb_along_rays`), and to the light samples of a vertex inside (its shadow ray's
//! transmittance: the area light's value computed again before `scatter` and put in after it,
//! `light_punctual`'s lamps chosen again, lane by lane, so that the vector loops of scenes without
//! such volumes stay as they are). A lane outside every volume, or inside
//! a clear one, multiplies by nothing, as `trace_path` does with no medium: the same bits.

use super::{Lanes, LANES};
use crate::bsdf::{lambert_at, BsdfSample};
use crate::integrator::direct::LightGeometry;
use crate::math::det;
use glam::Vec3;

/// The transmittance of a medium of absorption `sigma` over `dist` (`Vertex::transmittance`'s,
/// for a path inside it): 1 over an infinite distance (an environment's sample).
#[inline(always)]
pub(super) fn transmittance(sigma: Vec3, dist: f32) -> Vec3 {
    match dist.is_finite() {
        true => (-sigma * dist).map(det::exp),
        false => Vec3::ONE,
    }
}

impl Lanes<'_> {
    /// Each hit lane's throughput times the transmittance of the medium it travelled through to
    /// its hit (`trace_path`'s, before the emission the ray sees).
    pub(super) fn absorb_along_rays(&mut self) {
        for i in 0..LANES {
            let sigma = self.medium.get(i);
            if self.hit[i] && sigma != Vec3::ZERO {
                let beta = self.beta.get(i) * (-sigma * self.t[i]).map(det::exp);
                self.beta.set(i, beta);
            }
        }
    }

    /// Before `scatter`: the area light sample's value (× the throughput) of each lane inside an
    /// absorbing medium, as `scatter` computes it (the same BSDF values, `LightGeometry::value`)
    /// with the medium's transmittance in place of 1 (`trace_path`'s `Vertex::transmittance`).
    pub(super) fn absorb_light_samples(&mut self) {
        // Lanes with a light sample (a non-delta vertex) inside a medium: rare (a surface inside
        // coloured glass, or seen through an open sheet of it), and none most steps.
        let lit_inside: [bool; LANES] = std::array::from_fn(|i| {
            self.go[i] && self.diffuse_on[i] && self.medium.get(i) != Vec3::ZERO
        });
        if !lit_inside.contains(&true) {
            return;
        }
        let mut absorbed = self.absorbed_value;
        for (i, &inside) in lit_inside.iter().enumerate() {
            if !inside {
                continue;
            }
            let sigma = self.medium.get(i);
            let (p, ng, ns, wo) = (
                self.p.get(i),
                self.ng.get(i),
                self.ns.get(i),
                -self.d.get(i),
            );
            let g = LightGeometry::new(p, self.light_point.get(i), self.light_normal.get(i));
            let le = if g.cos_l > 0.0 {
                self.light_front.get(i)
            } else {
                self.light_back.get(i)
            };
            // Lane by lane, as `trace_path` evaluates the BSDF (`Bsdf::eval_pdf`, whose values
            // the vector steps' equal): on coloured rough glass most vertices are inside.
            let (f, bsdf_pdf) = match (&self.general[i], self.lobes(i)) {
                (Some(bsdf), _) => bsdf.eval_pdf(wo, g.wi),
                (None, Some(lobes)) => lobes.at(ns, ng, self.frame_tangent(i)).eval_pdf(wo, g.wi),
                (None, None) => lambert_at::eval_pdf(ns, ng, self.albedo.get(i), wo, g.wi),
            };
            let bsdf_pdf = match self.guided[i] {
                true => crate::guide::mix_densities(self.guide_pdf[i], bsdf_pdf),
                false => bsdf_pdf,
            };
            let pdf_area = self.light_pdf_area[i];
            let t = transmittance(sigma, g.dist);
            let value = g.value(pdf_area, le, f, bsdf_pdf, t, true);
            let value = self.beta.get(i) * value.unwrap_or(Vec3::ZERO);
            absorbed.set(i, value);
        }
        self.absorbed_value = absorbed;
    }

    /// After `scatter`: the values of [`Lanes::absorb_light_samples`] in place of `scatter`'s,
    /// where a lane inside an absorbing medium has a shadow ray.
    pub(super) fn take_absorbed_light_samples(&mut self) {
        for i in 0..LANES {
            // (A lane with a shadow ray is at a non-delta vertex.)
            if self.shadow[i] && self.medium.get(i) != Vec3::ZERO {
                self.shadow_value.set(i, self.absorbed_value.get(i));
            }
        }
    }

    /// The medium lane `i`'s path is in after its specular material's sample `bs` from `wo`
    /// (`trace_path`'s: a transmission through a solid's boundary enters its volume from the
    /// front side and leaves it from the back, unless the material is thin-walled).
    #[inline(always)]
    pub(super) fn cross_boundary(
        &mut self,
        i: usize,
        thin_walled: bool,
        bs: &BsdfSample,
        wo: Vec3,
    ) {
        if !(self.any_absorbing && bs.transmitted) {
            return;
        }
        let material = &self.scene.materials[self.material[i] as usize];
        if let Some(v) = material.volume.filter(|_| !thin_walled) {
            let entering = wo.dot(self.ng.get(i)) > 0.0;
            self.medium
                .set(i, if entering { v.sigma_a } else { Vec3::ZERO });
        }
    }
}
