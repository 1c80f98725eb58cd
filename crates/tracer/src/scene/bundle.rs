//! Camera rays traced as bundles: the samples of a pixel (the render's work is runs of samples per
//! pixel) start at one point in nearly one direction, so their closest hits are found in one walk
//! of the world-space mesh's tree for up to [`BUNDLE`] rays (`Bvh::closest_bundle_in`). Each ray
//! gets its own [`Scene::intersect`], the same bits; the instances answer ray by ray (a bundle
//! walk of the instances' two levels measured no faster on the instanced scenes).

use super::{Hit, Scene};
use crate::geometry::{Ray, RayPrecomp, BUNDLE};

impl Scene {
    /// [`Scene::intersect`] of each ray r of `rays` (at most [`BUNDLE`]) in (0, ∞) with alpha
    /// value `alpha_u[r]`, written to `out[r]`. `INLINED` as in [`Scene::intersect_in`]: for
    /// callers compiled for an instruction set (the wavefront's steps), which its vector loops
    /// need to pay. (The scalar integrator's camera rays bundled too, by a build per instruction
    /// set, ran no faster: there the camera rays are a few percent of the time; docs/benchmarks.md.)
    #[inline(always)]
    pub(crate) fn intersect_bundle_in<const INLINED: bool>(
        &self,
        rays: &[Ray],
        alpha_u: &[f32],
        out: &mut [Option<Hit>],
    ) {
        let n = rays.len();
        assert!(
            n <= BUNDLE && alpha_u.len() >= n && out.len() >= n,
            "a bundle of {n} rays"
        );
        let pres: [RayPrecomp; BUNDLE] =
            std::array::from_fn(|r| RayPrecomp::new(&rays[r.min(n.max(1) - 1)]));
        let mut found = [None; BUNDLE];
        if self.any_alpha {
            self.bvh.closest_bundle_in::<INLINED>(
                &pres[..n],
                f32::INFINITY,
                |r, id, h| !self.passes_through(id as usize, h.b1, h.b2, alpha_u[r]),
                &mut found,
            );
        } else {
            self.bvh.closest_bundle_in::<INLINED>(
                &pres[..n],
                f32::INFINITY,
                |_, _, _| true,
                &mut found,
            );
        }
        for (r, slot) in out[..n].iter_mut().enumerate() {
            let hit = found[r].map(Hit::from_bvh);
            *slot = if self.instances.is_empty() {
                hit
            } else {
                self.intersect_instances(&rays[r], f32::INFINITY, alpha_u[r], hit)
            };
        }
    }
}
