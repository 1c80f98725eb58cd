//! Ray queries against the scene: closest hit, shadow (visibility) rays, and the surface
//! interaction at a hit.

use super::Scene;
use crate::geometry::{InstanceHit, Mesh, Ray, RayPrecomp, RayQuery, TriangleHit};
use crate::sampler::hash_u32;
use glam::{Vec2, Vec3, Vec4};

/// A ray's closest intersection.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    /// The triangle: of the world-space mesh, or of the instance's prototype.
    pub triangle: u32,
    pub b1: f32,
    pub b2: f32,
    /// The instance hit, or [`Hit::WORLD`] for the world-space mesh.
    pub instance: u32,
}

impl Hit {
    /// `instance` of a hit of the world-space mesh.
    pub const WORLD: u32 = u32::MAX;

    /// The hit of triangle `triangle` that the BVH reports.
    #[inline(always)]
    pub(super) fn from_bvh((triangle, h): (u32, TriangleHit)) -> Hit {
        Hit {
            t: h.t,
            triangle,
            b1: h.b1,
            b2: h.b2,
            instance: Hit::WORLD,
        }
    }

    #[inline(always)]
    fn as_instance_hit(&self) -> InstanceHit {
        InstanceHit {
            t: self.t,
            instance: self.instance,
            triangle: self.triangle,
            b1: self.b1,
            b2: self.b2,
        }
    }

    #[inline(always)]
    fn from_instance_hit(h: InstanceHit) -> Hit {
        Hit {
            t: h.t,
            triangle: h.triangle,
            b1: h.b1,
            b2: h.b2,
            instance: h.instance,
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
    pub(super) fn passes_through(&self, triangle: usize, b1: f32, b2: f32, u: f32) -> bool {
        self.passes_through_in(&self.mesh, triangle, 0, b1, b2, u)
    }

    /// [`Scene::passes_through`] for a triangle of `mesh` (the world-space mesh, or instance
    /// `salt − 1`'s prototype: the salt decorrelates the instances' coverage).
    #[inline]
    fn passes_through_in(
        &self,
        mesh: &Mesh,
        triangle: usize,
        salt: u32,
        b1: f32,
        b2: f32,
        u: f32,
    ) -> bool {
        let m = &self.materials[mesh.material[triangle] as usize];
        if !m.has_alpha() {
            return false;
        }
        let uv = uv_at(mesh, triangle, b1, b2);
        // Decorrelate the coverage decision of different surfaces along one ray.
        let u = if matches!(m.alpha_mode, crate::material::AlphaMode::Blend) {
            let h =
                hash_u32(u.to_bits() ^ hash_u32(triangle as u32) ^ salt.wrapping_mul(0x9E37_79B9));
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
        let found = found.map(Hit::from_bvh);
        if self.instances.is_empty() {
            return found;
        }
        self.intersect_instances(ray, t_max, alpha_u, found)
    }

    /// [`Scene::intersect_in`] of two rays (no limit; alpha values `alpha_a`, `alpha_b`), their
    /// world-space walks traced together (`Bvh::closest_pair_in`): the same answers as the two
    /// calls.
    #[inline(always)]
    pub(crate) fn intersect_pair_in<const INLINED: bool>(
        &self,
        (a, alpha_a): (&Ray, f32),
        (b, alpha_b): (&Ray, f32),
    ) -> (Option<Hit>, Option<Hit>) {
        let (pre_a, pre_b) = (RayPrecomp::new(a), RayPrecomp::new(b));
        let query = |pre, d| RayQuery {
            pre,
            d,
            t_max: f32::INFINITY,
        };
        let (qa, qb) = (query(&pre_a, a.d), query(&pre_b, b.d));
        let (found_a, found_b) = if self.any_alpha {
            let accept = |alpha_u: f32| {
                move |id: u32, h: &TriangleHit| {
                    !self.passes_through(id as usize, h.b1, h.b2, alpha_u)
                }
            };
            self.bvh
                .closest_pair_in::<INLINED>(qa, accept(alpha_a), qb, accept(alpha_b))
        } else {
            self.bvh
                .closest_pair_in::<INLINED>(qa, |_, _| true, qb, |_, _| true)
        };
        let (found_a, found_b) = (found_a.map(Hit::from_bvh), found_b.map(Hit::from_bvh));
        if self.instances.is_empty() {
            return (found_a, found_b);
        }
        (
            self.intersect_instances(a, f32::INFINITY, alpha_a, found_a),
            self.intersect_instances(b, f32::INFINITY, alpha_b, found_b),
        )
    }

    /// The closest instanced hit that beats `found` (the world-space mesh's), or `found`.
    #[inline(never)]
    pub(super) fn intersect_instances(
        &self,
        ray: &Ray,
        t_max: f32,
        alpha_u: f32,
        found: Option<Hit>,
    ) -> Option<Hit> {
        let best = found.map(|h| h.as_instance_hit());
        let better = if self.any_alpha {
            self.instances.closest(ray, t_max, best, |k, tri, h| {
                let (_, proto) = self.instances.get(k);
                !self.passes_through_in(&proto.mesh, tri as usize, k + 1, h.b1, h.b2, alpha_u)
            })
        } else {
            self.instances.closest(ray, t_max, best, |_, _, _| true)
        };
        better.map(Hit::from_instance_hit)
    }

    /// Whether an instanced triangle blocks the segment (see [`Scene::visible`]).
    #[inline(never)]
    fn instance_blocks(&self, ray: &Ray, t_max: f32, alpha_u: f32) -> bool {
        if self.any_alpha {
            self.instances.any(ray, t_max, |k, tri, h| {
                let (_, proto) = self.instances.get(k);
                !self.passes_through_in(&proto.mesh, tri as usize, k + 1, h.b1, h.b2, alpha_u)
            })
        } else {
            self.instances.any(ray, t_max, |_, _, _| true)
        }
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
        let blocked = if self.any_alpha {
            self.bvh.any_in::<INLINED>(&pre, ray.d, t_max, |id, h| {
                !self.passes_through(id as usize, h.b1, h.b2, alpha_u)
            })
        } else {
            self.bvh.any_in::<INLINED>(&pre, ray.d, t_max, |_, _| true)
        };
        !blocked && (self.instances.is_empty() || !self.instance_blocks(ray, t_max, alpha_u))
    }

    /// [`Scene::visible_in`] of two segments (each with its limit and alpha value), their
    /// world-space walks traced together (`Bvh::any_pair_in`): the same answers as the two calls.
    #[inline(always)]
    pub(crate) fn visible_pair_in<const INLINED: bool>(
        &self,
        (a, a_max, alpha_a): (&Ray, f32, f32),
        (b, b_max, alpha_b): (&Ray, f32, f32),
    ) -> (bool, bool) {
        let (pre_a, pre_b) = (RayPrecomp::new(a), RayPrecomp::new(b));
        let query = |pre, d, t_max| RayQuery { pre, d, t_max };
        let (qa, qb) = (query(&pre_a, a.d, a_max), query(&pre_b, b.d, b_max));
        let (blocked_a, blocked_b) = if self.any_alpha {
            let accept = |alpha_u: f32| {
                move |id: u32, h: &TriangleHit| {
                    !self.passes_through(id as usize, h.b1, h.b2, alpha_u)
                }
            };
            self.bvh
                .any_pair_in::<INLINED>(qa, accept(alpha_a), qb, accept(alpha_b))
        } else {
            self.bvh
                .any_pair_in::<INLINED>(qa, |_, _| true, qb, |_, _| true)
        };
        if self.instances.is_empty() {
            return (!blocked_a, !blocked_b);
        }
        (
            !blocked_a && !self.instance_blocks(a, a_max, alpha_a),
            !blocked_b && !self.instance_blocks(b, b_max, alpha_b),
        )
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
        let found = found.map(Hit::from_bvh);
        if self.instances.is_empty() {
            return (found, !blocked);
        }
        let found = self.intersect_instances(ray, f32::INFINITY, alpha_u, found);
        let blocked = blocked || self.instance_blocks(shadow, shadow_t_max, shadow_alpha_u);
        (found, !blocked)
    }

    /// The texture coordinates at a hit, as [`Scene::surface`] reads them (an instanced hit's
    /// from its prototype, at the barycentrics its walk found).
    #[inline]
    pub(crate) fn hit_uv(&self, hit: &Hit) -> [Vec2; 2] {
        let mesh = if hit.instance == Hit::WORLD {
            &self.mesh
        } else {
            &self.instances.get(hit.instance).1.mesh
        };
        uv_at(mesh, hit.triangle as usize, hit.b1, hit.b2)
    }

    /// The surface at a hit of `ray`.
    #[inline(always)]
    pub fn surface(&self, ray: &Ray, hit: &Hit) -> SurfaceInteraction {
        if hit.instance != Hit::WORLD {
            return self.instance_surface(ray, hit);
        }
        let tri = hit.triangle as usize;
        let mesh = &self.mesh;
        interaction(
            ray,
            hit,
            mesh.positions[tri],
            (hit.b1, hit.b2),
            mesh.normals.as_ref().map(|n| n[tri]),
            mesh.tangents.as_ref().map(|t| t[tri]),
            uv_at(mesh, tri, hit.b1, hit.b2),
            mesh.material[tri],
        )
    }

    /// [`Scene::surface`] of an instanced hit: the prototype's triangle moved to world space
    /// ([`Scene::instance_triangle`]), its tangents by the transform's linear part with the
    /// handedness flipped under a mirror, then shaded as a world-space triangle.
    #[inline(never)]
    fn instance_surface(&self, ray: &Ray, hit: &Hit) -> SurfaceInteraction {
        let mesh = &self.instances.get(hit.instance).1.mesh;
        let tri = hit.triangle as usize;
        let world = self.instance_triangle(hit);
        let tangents = self.instance_tangents(hit);
        interaction(
            ray,
            hit,
            world.corners,
            world.bary,
            world.normals,
            tangents,
            uv_at(mesh, tri, hit.b1, hit.b2),
            world.material,
        )
    }

    /// The tangents at the corners of an instanced hit's triangle in world space, in the order of
    /// [`Scene::instance_triangle`]'s corners: by the transform's linear part, the handedness
    /// flipped under a mirror. `None` for a prototype without tangents.
    #[inline]
    fn instance_tangents(&self, hit: &Hit) -> Option<[Vec4; 3]> {
        let (inst, proto) = self.instances.get(hit.instance);
        let sign = if inst.flip { -1.0 } else { 1.0 };
        proto.mesh.tangents.as_ref().map(|t| {
            let t = t[hit.triangle as usize];
            corner_order(inst.flip).map(|i| {
                let xyz = inst
                    .to_world
                    .transform_vector3(t[i].truncate())
                    .normalize_or_zero();
                xyz.extend(t[i].w * sign)
            })
        })
    }

    /// The interpolated tangent at a hit, as [`Scene::surface`] makes it (`None` for a mesh
    /// without tangents).
    #[inline(never)]
    pub(crate) fn hit_tangent(&self, hit: &Hit) -> Option<Vec4> {
        if hit.instance == Hit::WORLD {
            let corners = self.mesh.tangents.as_ref()?[hit.triangle as usize];
            Some(interpolated_tangent(corners, (hit.b1, hit.b2)))
        } else {
            let corners = self.instance_tangents(hit)?;
            let flip = self.instances.get(hit.instance).0.flip;
            Some(interpolated_tangent(corners, corner_bary(flip, hit)))
        }
    }

    /// The triangle of an instanced hit in world space, moved as the flattening loader moves it:
    /// positions by the transform, normals by its inverse transpose (the flat normal where one
    /// collapses), and two corners swapped under a mirror, with the hit's barycentrics swapped to
    /// match. The scalar integrator's surfaces and the wavefront lanes both read instanced hits
    /// through it, so both have the same bits.
    #[inline(never)]
    pub(crate) fn instance_triangle(&self, hit: &Hit) -> WorldTriangle {
        let (inst, proto) = self.instances.get(hit.instance);
        let mesh = &proto.mesh;
        let tri = hit.triangle as usize;
        let order = corner_order(inst.flip);
        let bary = corner_bary(inst.flip, hit);
        let corners = mesh.positions[tri];
        let positions = order.map(|i| inst.to_world.transform_point3(corners[i]));
        let (a, b, c) = (positions[0], positions[1], positions[2]);
        let flat = (b - a).cross(c - a).normalize_or_zero();
        let normals = mesh.normals.as_ref().map(|n| {
            let n = n[tri];
            order.map(|i| {
                let w = (inst.normal_matrix * glam::Vec3A::from(n[i])).normalize_or_zero();
                if w == glam::Vec3A::ZERO {
                    flat
                } else {
                    w.into()
                }
            })
        });
        WorldTriangle {
            corners: positions,
            normals,
            bary,
            material: mesh.material[tri],
        }
    }
}

/// An instanced hit's triangle in world space (see [`Scene::instance_triangle`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct WorldTriangle {
    /// Corners in front-face (counter-clockwise) order.
    pub corners: [Vec3; 3],
    /// The corners' vertex normals, for a mesh that has them.
    pub normals: Option<[Vec3; 3]>,
    /// The hit's barycentrics (b1, b2) for these corners.
    pub bary: (f32, f32),
    pub material: u32,
}

/// The order in which an instance's corners are read: two swap under a mirror, so that the
/// counter-clockwise side stays the front, as the flattening loader does.
#[inline(always)]
fn corner_order(flip: bool) -> [usize; 3] {
    if flip {
        [0, 2, 1]
    } else {
        [0, 1, 2]
    }
}

/// A hit's barycentrics (b1, b2) for its corners read in [`corner_order`]: under a mirror the
/// corners are (a, c, b), whose weights are (b0, b2, b1).
#[inline(always)]
fn corner_bary(flip: bool, hit: &Hit) -> (f32, f32) {
    if flip {
        (hit.b2, hit.b1)
    } else {
        (hit.b1, hit.b2)
    }
}

/// The texture coordinates of `mesh`'s triangle `tri` at barycentrics (b1, b2).
#[inline]
fn uv_at(mesh: &Mesh, tri: usize, b1: f32, b2: f32) -> [Vec2; 2] {
    let b0 = 1.0 - b1 - b2;
    let interp = |t: &[Vec2; 3]| t[0] * b0 + t[1] * b1 + t[2] * b2;
    [
        mesh.uv0.as_ref().map_or(Vec2::ZERO, |u| interp(&u[tri])),
        mesh.uv1.as_ref().map_or(Vec2::ZERO, |u| interp(&u[tri])),
    ]
}

/// The shading normal at barycentrics `b` of a triangle whose corners carry `normals`, on the side
/// of its geometric normal `ng`: the scalar integrator's (`Scene::surface`) and the wavefront
/// lanes' one body of code, so both have the same bits.
#[inline(always)]
pub(crate) fn shading_normal([n0, n1, n2]: [Vec3; 3], [b0, b1, b2]: [f32; 3], ng: Vec3) -> Vec3 {
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

/// The tangent at barycentrics (b1, b2) of a triangle whose corners carry `corners`.
#[inline(always)]
fn interpolated_tangent([t0, t1, t2]: [Vec4; 3], (b1, b2): (f32, f32)) -> Vec4 {
    let b0 = 1.0 - b1 - b2;
    t0 * b0 + t1 * b1 + t2 * b2
}

/// The surface at barycentrics (b1, b2) of a world-space triangle with these corners (front-face
/// order) and corner attributes.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn interaction(
    ray: &Ray,
    hit: &Hit,
    [a, b, c]: [Vec3; 3],
    (b1, b2): (f32, f32),
    normals: Option<[Vec3; 3]>,
    tangents: Option<[Vec4; 3]>,
    uv: [Vec2; 2],
    material: u32,
) -> SurfaceInteraction {
    let b0 = 1.0 - b1 - b2;
    // Interpolating the vertices is more accurate than o + t·d far from the origin.
    let p = a * b0 + b * b1 + c * b2;
    let ng = (b - a).cross(c - a).normalize();
    let ns = match normals {
        Some(corners) => shading_normal(corners, [b0, b1, b2], ng),
        None => ng,
    };
    let tangent = tangents.map(|corners| interpolated_tangent(corners, (b1, b2)));
    SurfaceInteraction {
        p,
        clearance: crate::math::spawn_clearance([a, b, c]),
        ng,
        ns,
        uv,
        tangent,
        material,
        triangle: hit.triangle,
        front: ray.d.dot(ng) < 0.0,
    }
}
