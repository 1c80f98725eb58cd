//! Rays against the instances: the walk over their tree, the closest hit and any hit.

use super::{Instance, Instances};
use crate::geometry::{Ray, RayPrecomp, TriangleHit};

/// The closest hit so far: `(t, instance, triangle)` and the barycentrics.
#[derive(Clone, Copy, Debug)]
pub struct InstanceHit {
    pub t: f32,
    pub instance: u32,
    pub triangle: u32,
    pub b1: f32,
    pub b2: f32,
}

/// The smallest f32 above `t` (t itself for infinity): a query limit that still admits a hit at
/// exactly `t`, for the tie rule.
#[inline]
fn just_above(t: f32) -> f32 {
    if t.is_finite() && t >= 0.0 {
        f32::from_bits(t.to_bits() + 1)
    } else {
        t
    }
}

impl Instances {
    /// Visits the instances whose boxes the ray enters within the current limit (which `visit`
    /// may lower by returning a new one), nearer boxes first. `visit` returns `None` to stop.
    #[inline(always)]
    fn walk(
        &self,
        ray: &Ray,
        limit: f32,
        mut visit: impl FnMut(u32, &Instance, f32) -> Option<f32>,
    ) {
        self.tree.walk(ray.o, ray.d, limit, |k, limit| {
            visit(k, &self.instances[k as usize], limit)
        });
    }

    /// The ray in the instance's object space (the same parameter t).
    #[inline(always)]
    fn object_ray(inst: &Instance, ray: &Ray) -> Ray {
        Ray::new(
            inst.to_object.transform_point3(ray.o),
            inst.to_object.transform_vector3(ray.d),
        )
    }

    /// The closest accepted instanced hit that beats `best` (smallest `(t, instance, triangle)`),
    /// for t in (0, t_max). `accept(instance, triangle, hit)` decides alpha cutouts.
    #[inline]
    pub fn closest(
        &self,
        ray: &Ray,
        t_max: f32,
        best: Option<InstanceHit>,
        mut accept: impl FnMut(u32, u32, &TriangleHit) -> bool,
    ) -> Option<InstanceHit> {
        let mut best = best;
        let limit = best.map_or(t_max, |b| just_above(b.t).min(t_max));
        self.walk(ray, limit, |k, inst, limit| {
            let proto = &self.prototypes[inst.prototype as usize];
            let object = Self::object_ray(inst, ray);
            let pre = RayPrecomp::new(&object);
            let found = proto
                .bvh
                .closest(&pre, object.d, limit, |tri, h| accept(k, tri, h));
            if let Some((triangle, h)) = found {
                let beats = match best {
                    None => true,
                    Some(b) => {
                        h.t < b.t || (h.t == b.t && (k, triangle) < (b.instance, b.triangle))
                    }
                };
                if beats {
                    best = Some(InstanceHit {
                        t: h.t,
                        instance: k,
                        triangle,
                        b1: h.b1,
                        b2: h.b2,
                    });
                }
            }
            Some(best.map_or(limit, |b| just_above(b.t).min(limit)))
        });
        best
    }

    /// Whether some instanced triangle that `accept` lets through is hit in (0, t_max).
    #[inline]
    pub fn any(
        &self,
        ray: &Ray,
        t_max: f32,
        mut accept: impl FnMut(u32, u32, &TriangleHit) -> bool,
    ) -> bool {
        let mut hit = false;
        self.walk(ray, t_max, |k, inst, limit| {
            let proto = &self.prototypes[inst.prototype as usize];
            let object = Self::object_ray(inst, ray);
            let pre = RayPrecomp::new(&object);
            hit = proto
                .bvh
                .any(&pre, object.d, limit, |tri, h| accept(k, tri, h));
            (!hit).then_some(limit)
        });
        hit
    }
}
