//! Step 1 of the lanes: the lanes whose path ended take the next samples of the work, with their
//! camera rays. The rays are made sixteen samples at a time, ahead of the lanes that take them
//! ([`CameraRays`]), in vector code: the Sobol values of the jitter and the camera's divisions
//! and square root, one lane at a time, were a tenth of the render's time, and made only for the
//! lanes that had just been freed (a third of them, on the Cornell box) they cost as much in
//! vector code as one at a time.

use super::{Lanes, F, U};
use crate::camera::{Camera, Projection};
use crate::geometry::{Ray, BUNDLE};
use crate::integrator::wavefront::{Isa, LANES, V3};
use crate::integrator::PathResult;
use crate::sampler::{dims, hash_words, owen_sobol_group_lanewise};
use crate::scene::{Hit, Scene};
use crate::settings::RenderSettings;
use glam::{Vec2, Vec3};

// A batch of camera rays is traced as one bundle.
const _: () = assert!(LANES <= BUNDLE);

/// The next samples of the work, up to [`LANES`], with their camera rays: `render_sample`'s
/// sampler key, jitter and ray.
pub(super) struct CameraRays {
    x: U,
    y: U,
    index: U,
    key: U,
    index_rev: U,
    o: V3,
    d: V3,
    /// Each ray's closest hit, traced as one bundle when the rays are made
    /// ([`CameraRays::trace`]).
    found: [Option<Hit>; LANES],
    /// Entries `0..len` hold the batch; `next` is the first not yet handed to a lane.
    len: usize,
    next: usize,
    /// The last pixel whose key was hashed, with its key (the work is a run of samples per
    /// pixel, mostly, as `render_samples` sets up its sampler).
    keyed: Option<(u32, u32, u32)>,
}

impl CameraRays {
    pub(super) fn new() -> CameraRays {
        CameraRays {
            x: [0; LANES],
            y: [0; LANES],
            index: [0; LANES],
            key: [0; LANES],
            index_rev: [0; LANES],
            o: V3::ZERO,
            d: V3::ZERO,
            found: [None; LANES],
            len: 0,
            next: 0,
            keyed: None,
        }
    }

    /// Takes the next samples of `work` and makes their rays; false when `work` has none left.
    fn fill(
        &mut self,
        isa: Isa,
        scene: &Scene,
        settings: &RenderSettings,
        work: &mut impl Iterator<Item = (u32, u32, u32)>,
    ) -> bool {
        let seed = settings.seed;
        let mut len = 0;
        for (x, y, index) in work.by_ref() {
            let key = match self.keyed {
                Some((kx, ky, key)) if (kx, ky) == (x, y) => key,
                _ => hash_words(&[seed as u32, (seed >> 32) as u32, x, y]),
            };
            self.keyed = Some((x, y, key));
            (self.x[len], self.y[len], self.index[len], self.key[len]) = (x, y, index, key);
            len += 1;
            if len == LANES {
                break;
            }
        }
        (self.len, self.next) = (len, 0);
        if len > 0 {
            self.make_rays_for(isa, &scene.camera, settings);
            self.trace_for(isa, scene);
        }
        len > 0
    }

    /// Traces the batch's camera rays together (`Scene::intersect_bundle_in`): the samples of
    /// a batch are mostly of one pixel, so their rays enter the same boxes. A ray that is not
    /// finite (its sample is handed on without a path) is traced as a harmless one, and its
    /// answer never read.
    #[inline(always)]
    pub(super) fn trace(&mut self, scene: &Scene) {
        let rays: [Ray; LANES] = std::array::from_fn(|k| {
            let (o, d) = (self.o.get(k), self.d.get(k));
            if d.is_finite() && o.is_finite() {
                Ray::new(o, d)
            } else {
                Ray::new(Vec3::ZERO, Vec3::Z)
            }
        });
        // The coverage values of bounce 0, in a scene with alpha (`Lanes::alpha_at`).
        let alpha_u: [f32; LANES] = match scene.any_alpha() {
            true => std::array::from_fn(|k| super::alpha_value(self.key[k], self.index_rev[k], 0)),
            false => [0.0; LANES],
        };
        // Inlined: this step is compiled for the test's instruction set (`builds.rs`).
        scene.intersect_bundle_in::<true>(&rays[..self.len], &alpha_u, &mut self.found);
    }

    /// [`CameraRays::make_rays_with`] with the camera's projection fixed in each copy: a `match`
    /// on it inside the loop would keep the loop from being vectorised.
    #[inline(always)]
    pub(super) fn make_rays(&mut self, camera: &Camera, settings: &RenderSettings) {
        match &camera.projection {
            Projection::Perspective(p) => {
                self.make_rays_with(camera, settings, |ndc, aspect| p.local_ray(ndc, aspect))
            }
            Projection::Orthographic(p) => {
                self.make_rays_with(camera, settings, |ndc, aspect| p.local_ray(ndc, aspect))
            }
        }
    }

    /// The jitter and camera ray of every lane (those beyond `len` too: computing them is
    /// cheaper than skipping them).
    #[inline(always)]
    fn make_rays_with(
        &mut self,
        camera: &Camera,
        settings: &RenderSettings,
        local_ray: impl Fn(Vec2, f32) -> (Vec3, Vec3),
    ) {
        let (w, h) = (settings.width, settings.height);
        // Copied to locals, as in `shade_hit`.
        let (xs, ys, indices, keys) = (self.x, self.y, self.index, self.key);
        // The sample values in a loop of their own (their table lookups are gathers; see
        // `scatter`).
        let (mut revs, mut jx, mut jy): (U, F, F) = ([0; LANES], [0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            revs[i] = indices[i].reverse_bits();
            [jx[i], jy[i]] = owen_sobol_group_lanewise(keys[i], revs[i], dims::PIXEL, [0, 1]);
        }
        let (mut os, mut ds) = (V3::ZERO, V3::ZERO);
        for i in 0..LANES {
            let film = Vec2::new(xs[i] as f32 + jx[i], ys[i] as f32 + jy[i]);
            let ray = camera.ray_through(film, w, h, &local_ray);
            os.set(i, ray.o);
            ds.set(i, ray.d);
        }
        (self.index_rev, self.o, self.d) = (revs, os, ds);
    }
}

impl Lanes<'_> {
    /// Gives every lane without a path the next sample of `work`, with its camera ray. A sample
    /// whose camera ray is not finite is handed on at once with a NaN radiance, as
    /// `render_sample` does, and its lane takes the next one.
    pub(super) fn refill(
        &mut self,
        isa: Isa,
        work: &mut impl Iterator<Item = (u32, u32, u32)>,
        each: &mut impl FnMut(u32, u32, u32, PathResult),
    ) {
        for i in 0..LANES {
            if self.alive[i] {
                continue;
            }
            loop {
                let rays = &mut self.camera_rays;
                if rays.next == rays.len && !rays.fill(isa, self.scene, self.settings, work) {
                    return;
                }
                let k = rays.next;
                rays.next += 1;
                let (x, y, index) = (rays.x[k], rays.y[k], rays.index[k]);
                let d = rays.d.get(k);
                if !d.is_finite() {
                    let nan = PathResult {
                        radiance: Vec3::splat(f32::NAN),
                        rays: 0,
                        vertices: 0,
                    };
                    each(x, y, index, nan);
                    continue;
                }
                (self.x[i], self.y[i], self.index[i]) = (x, y, index);
                (self.key[i], self.index_rev[i]) = (rays.key[k], rays.index_rev[k]);
                self.alive[i] = true;
                self.o.set(i, rays.o.get(k));
                self.d.set(i, d);
                self.beta.set(i, Vec3::ONE);
                if self.any_absorbing {
                    self.medium.set(i, Vec3::ZERO);
                }
                self.l.set(i, Vec3::ZERO);
                self.mis[i] = false;
                self.bsdf_pdf[i] = 0.0;
                self.depth[i] = 0;
                // The camera ray was traced with its batch's (`CameraRays::trace`).
                self.found[i] = rays.found[k];
                self.rays[i] = 1;
                self.vertices[i] = 0;
                self.untraced[i] = false;
                break;
            }
        }
    }
}
