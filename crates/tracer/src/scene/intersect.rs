//! Ray queries against the scene: closest hit, shadow (visibility) rays, and the surface
//! interaction at a hit.

use super::Scene;
use crate::geometry::{Ray, RayPrecomp, RayQuery, TriangleHit};
use crate::sampler::hash_u32;
use glam::{Vec2, Vec3, Vec4};

/// A ray's closest intersection.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub triangle: u32,
    pub b1: f32,
    pub b2: f32,
}

impl Hit {
    /// The hit of triangle `triangle` that the BVH reports.
    #[inline(always)]
    fn from_bvh((triangle, h): (u32, TriangleHit)) -> Hit {
        Hit {
            t: h.t,
            triangle,
            b1: h.b1,
            b2: h.b2,
        }
    }
}

/// Everything the integrator needs to know about a hit point.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceInteraction {
    pub p: Vec3,
    /// How far from the surface rays spawned here start, beyond the ULP offset
    /// ([`crate::math::spawn_clearance`]).
    pub clearance: f32,
    /// Unit geometric normal on the front (counter-clockwise) side.
    pub ng: Vec3,
    /// Unit interpolated shading normal, on the same side as `ng` (equal to it without normals).
    pub ns: Vec3,
    pub uv: [Vec2; 2],
    pub tangent: Option<Vec4>,
    pub material: u32,
    pub triangle: u32,
    /// The ray arrived from the front side.
    pub front: bool,
}

// The ray queries and the surface interaction are `#[inline(always)]`: called a few times per
// path vertex, their call boundaries (arguments and results through memory) cost 4–6 % of a
// sample's time (same-time A/B runs, docs/benchmarks.md).
impl Scene {
    /// Whether a ray passes through the (alpha-tested) surface of `triangle` at barycentrics
    /// (b1, b2). `u` drives stochastic (BLEND) coverage.
    #[inline]
    fn passes_through(&self, triangle: usize, b1: f32, b2: f32, u: f32) -> bool {
        let m = &self.materials[self.mesh.material[triangle] as usize];
        if !m.has_alpha() {
            return false;
        }
        let uv = self.uv_at(triangle, b1, b2);
        // Decorrelate the coverage decision of different surfaces along one ray.
        let u = if matches!(m.alpha_mode, crate::material::AlphaMode::Blend) {
            let h = hash_u32(u.to_bits() ^ hash_u32(triangle as u32));
            crate::sampler::bits_to_unit(h)
        } else {
            u
        };
        m.passes_through(&self.textures, &uv, u)
    }

    /// The closest surface hit by `ray` in (0, t_max). `alpha_u` ∈ [0,1) drives stochastic alpha.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray, t_max: f32, alpha_u: f32) -> Option<Hit> {
        self.intersect_in::<false>(ray, t_max, alpha_u)
    }

    /// [`Scene::intersect`], with a flat mesh's test inlined into the caller where `INLINED`:
    /// only for callers compiled for that test's instruction set (the wavefront's steps; see
    /// `Bvh::closest_in`).
    #[inline(always)]
    pub(crate) fn intersect_in<const INLINED: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        alpha_u: f32,
    ) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let found = if self.any_alpha {
            self.bvh.closest_in::<INLINED>(&pre, ray.d, t_max, |id, h| {
                !self.passes_through(id as usize, h.b1, h.b2, alpha_u)
            })
        } else {
            self.bvh
                .closest_in::<INLINED>(&pre, ray.d, t_max, |_, _| true)
        };
        found.map(Hit::from_bvh)
    }

    /// True if nothing blocks the segment from `ray.o` along `ray.d` up to distance `t_max`.
    #[inline(always)]
    pub fn visible(&self, ray: &Ray, t_max: f32, alpha_u: f32) -> bool {
        self.visible_in::<false>(ray, t_max, alpha_u)
    }

    /// [`Scene::visible`], `INLINED` as in [`Scene::intersect_in`].
    #[inline(always)]
    pub(crate) fn visible_in<const INLINED: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        alpha_u: f32,
    ) -> bool {
        let pre = RayPrecomp::new(ray);
        if self.any_alpha {
            !self.bvh.any_in::<INLINED>(&pre, ray.d, t_max, |id, h| {
                !self.passes_through(id as usize, h.b1, h.b2, alpha_u)
            })
        } else {
            !self.bvh.any_in::<INLINED>(&pre, ray.d, t_max, |_, _| true)
        }
    }

    /// [`Scene::intersect`] of `ray` and [`Scene::visible`] of `shadow`, traced together (the two
    /// traversals interleaved, see `Bvh::closest_and_any`): the same answers as the two calls.
    #[inline(always)]
    pub fn intersect_and_visible(
        &self,
        ray: &Ray,
        alpha_u: f32,
        shadow: &Ray,
        shadow_t_max: f32,
        shadow_alpha_u: f32,
    ) -> (Option<Hit>, bool) {
        self.intersect_and_visible_in::<false>(ray, alpha_u, shadow, shadow_t_max, shadow_alpha_u)
    }

    /// [`Scene::intersect_and_visible`], `INLINED` as in [`Scene::intersect_in`].
    #[inline(always)]
    pub(crate) fn intersect_and_visible_in<const INLINED: bool>(
        &self,
        ray: &Ray,
        alpha_u: f32,
        shadow: &Ray,
        shadow_t_max: f32,
        shadow_alpha_u: f32,
    ) -> (Option<Hit>, bool) {
        let (pre, shadow_pre) = (RayPrecomp::new(ray), RayPrecomp::new(shadow));
        let a = RayQuery {
            pre: &pre,
            d: ray.d,
            t_max: f32::INFINITY,
        };
        let b = RayQuery {
            pre: &shadow_pre,
            d: shadow.d,
            t_max: shadow_t_max,
        };
        let (found, blocked) = if self.any_alpha {
            self.bvh.closest_and_any_in::<INLINED>(
                a,
                |id, h| !self.passes_through(id as usize, h.b1, h.b2, alpha_u),
                b,
                |id, h| !self.passes_through(id as usize, h.b1, h.b2, shadow_alpha_u),
            )
        } else {
            self.bvh
                .closest_and_any_in::<INLINED>(a, |_, _| true, b, |_, _| true)
        };
        (found.map(Hit::from_bvh), !blocked)
    }

    #[inline]
    fn uv_at(&self, tri: usize, b1: f32, b2: f32) -> [Vec2; 2] {
        let b0 = 1.0 - b1 - b2;
        let interp = |t: &[Vec2; 3]| t[0] * b0 + t[1] * b1 + t[2] * b2;
        [
            self.mesh
                .uv0
                .as_ref()
                .map_or(Vec2::ZERO, |u| interp(&u[tri])),
            self.mesh
                .uv1
                .as_ref()
                .map_or(Vec2::ZERO, |u| interp(&u[tri])),
        ]
    }

    /// The surface at a hit of `ray`.
    #[inline(always)]
    pub fn surface(&self, ray: &Ray, hit: &Hit) -> SurfaceInteraction {
        let tri = hit.triangle as usize;
        let [a, b, c] = self.mesh.positions[tri];
        let (b1, b2) = (hit.b1, hit.b2);
        let b0 = 1.0 - b1 - b2;
        // Interpolating the vertices is more accurate than o + t·d far from the origin.
        let p = a * b0 + b * b1 + c * b2;
        let ng = (b - a).cross(c - a).normalize();
        let ns = match &self.mesh.normals {
            Some(n) => {
                let [n0, n1, n2] = n[tri];
                let s = (n0 * b0 + n1 * b1 + n2 * b2).normalize_or_zero();
                if s == Vec3::ZERO || !s.is_finite() {
                    ng
                } else if s.dot(ng) < 0.0 {
                    // Normals that disagree with the winding: trust the winding for the side.
                    -s
                } else {
                    s
                }
            }
            None => ng,
        };
        let tangent = self.mesh.tangents.as_ref().map(|t| {
            let [t0, t1, t2] = t[tri];
            t0 * b0 + t1 * b1 + t2 * b2
        });
        SurfaceInteraction {
            p,
            clearance: crate::math::spawn_clearance([a, b, c]),
            ng,
            ns,
            uv: self.uv_at(tri, b1, b2),
            tangent,
            material: self.mesh.material[tri],
            triangle: hit.triangle,
            front: ray.d.dot(ng) < 0.0,
        }
    }
}
