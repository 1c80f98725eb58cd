//! Instancing without flattening: a two-level BVH.
//!
//! A mesh that several nodes place is kept once, in its own (object) space, with its own 4-wide BVH
//! (a [`Prototype`]); each placement is an [`Instance`] (a transform and its inverse), and a 4-wide
//! tree over the instances' world boxes ([`BoxTree`]) finds the instances a ray may hit. A ray entering an instance
//! is moved into object space (o and d by the inverse transform; d is not renormalised, so t is
//! the same parameter in both spaces) and answered by the prototype's BVH. Which meshes are kept
//! this way is the loader's decision (`gltf::instancing`); hand-built scenes pass their own.
//!
//! Contract (the one of [`super::Bvh`], across levels): the closest hit is the one with the
//! smallest `(t, instance, triangle)` among all accepted hits in (0, t_max), so the answer never
//! depends on the order the tree is walked in; the instance boxes are padded so that they never cull
//! an instance whose object-space test would hit.

use super::bvh::{BoxTree, MAX_BOXES};
use super::{Bvh, Mesh, Ray, RayPrecomp, TriangleHit};
use glam::{Affine3A, DAffine3, DMat3, DMat4, DVec3, Mat3A, Vec3, Vec3A};
use std::sync::Arc;

/// A mesh kept once in object space, with its BVH.
#[derive(Clone, Debug)]
pub struct Prototype {
    pub mesh: Mesh,
    pub bvh: Bvh,
    /// Object-space boxes that together hold every triangle (see [`Bvh::cover`]): what a
    /// placement's world box is made of.
    cover: Vec<(Vec3, Vec3)>,
}

/// The most boxes of a prototype's tree moved into world space to bound one placement: three
/// levels of a 4-wide tree.
const COVER_BOXES: usize = 64;

/// Where a loader places a prototype: its index and the node's world transform (an affine matrix;
/// the last row is ignored, as glTF requires it to be 0 0 0 1).
#[derive(Clone, Debug)]
pub struct Placement {
    pub prototype: u32,
    pub to_world: DMat4,
}

/// One placement of a prototype, with what a hit needs to move into world space.
#[derive(Clone, Debug)]
pub struct Instance {
    pub prototype: u32,
    pub to_world: Affine3A,
    pub to_object: Affine3A,
    /// The inverse transpose of the linear part times |det| (the cofactor matrix times the sign of
    /// the determinant): world normals up to length, computed as the flattening loader does.
    pub normal_matrix: Mat3A,
    /// The transform mirrors (negative determinant): two corners of each triangle swap, so that
    /// the counter-clockwise side stays the front, as the flattening loader does.
    pub flip: bool,
}

/// The SAH cost of a node visit against one instance test, for the top-level tree's leaf decision:
/// with one instance a leaf it decides nothing (every range of two or more is split), and is
/// obvhs' default, which built this tree before.
const TOP_TRAVERSAL_COST: f64 = 3.0;

/// Every instance of the scene and the tree over them. Empty for a scene without instances, and
/// then free: its queries return at once. The prototypes are shared (an animated scene's frames
/// place the same prototypes, each built once).
#[derive(Clone, Debug, Default)]
pub struct Instances {
    pub prototypes: Vec<Arc<Prototype>>,
    /// In the top-level tree's leaf order (the index is the instance's identity in hits).
    pub instances: Vec<Instance>,
    tree: BoxTree,
}

/// Placements dropped for a singular or non-finite transform, and the triangles they would have
/// placed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Unplaced {
    pub placements: usize,
    pub triangles: usize,
}

/// Why placements cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum InstanceError {
    #[error("instance {instance} places prototype {prototype}, but there are {count} prototypes")]
    Prototype {
        instance: usize,
        prototype: u32,
        count: usize,
    },
    #[error("{count} instances: at most {max} can be placed")]
    TooMany { count: usize, max: usize },
}

impl Prototype {
    /// Builds the prototype's BVH. The mesh must hold only renderable triangles (as
    /// [`crate::scene::Scene::build`] leaves them).
    pub fn new(mesh: Mesh) -> Prototype {
        let bvh = Bvh::build(&mesh);
        let cover = bvh
            .cover(COVER_BOXES)
            .unwrap_or_else(|| vec![mesh.bounds()]);
        Prototype { mesh, bvh, cover }
    }

    /// Approximate bytes held.
    pub fn bytes(&self) -> usize {
        self.mesh.bytes() + self.bvh.bytes()
    }
}

impl Instance {
    /// The instance of `prototype` under `to_world`, or `None` when the transform is singular or
    /// not finite (nothing of it could be hit or shaded).
    fn new(prototype: u32, to_world: &DMat4) -> Option<Instance> {
        let affine = DAffine3::from_mat4(*to_world);
        let m3 = affine.matrix3;
        let det = m3.determinant();
        if !(det.is_finite() && det != 0.0 && affine.translation.is_finite()) {
            return None;
        }
        let inverse = affine.inverse();
        if !(inverse.matrix3.is_finite() && inverse.translation.is_finite()) {
            return None;
        }
        let sign = if det < 0.0 { -1.0 } else { 1.0 };
        let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
        let normal_matrix = DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign;
        let f32_affine = |a: DAffine3| {
            Affine3A::from_mat3_translation(a.matrix3.as_mat3(), a.translation.as_vec3())
        };
        Some(Instance {
            prototype,
            to_world: f32_affine(affine),
            to_object: f32_affine(inverse),
            normal_matrix: Mat3A::from(normal_matrix.as_mat3()),
            flip: det < 0.0,
        })
    }

    /// The world box of the object boxes `cover` under this instance, from the f64 transform,
    /// padded for the rounding of the object-space ray: a small fraction of its size and position.
    fn world_box(to_world: &DMat4, cover: &[(Vec3, Vec3)]) -> (Vec3A, Vec3A) {
        let (mut wlo, mut whi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (k, &(lo, hi)) in (0..8).flat_map(|k| cover.iter().map(move |b| (k, b))) {
            let pick = |bit: usize, a: f32, b: f32| if k & bit == 0 { a } else { b } as f64;
            let corner = DVec3::new(
                pick(1, lo.x, hi.x),
                pick(2, lo.y, hi.y),
                pick(4, lo.z, hi.z),
            );
            let w = to_world.transform_point3(corner);
            wlo = wlo.min(w);
            whi = whi.max(w);
        }
        let scale = (whi - wlo)
            .max_element()
            .max(wlo.abs().max(whi.abs()).max_element());
        let pad = DVec3::splat(scale * 1e-5 + f32::MIN_POSITIVE as f64);
        (
            Vec3A::from((wlo - pad).as_vec3()),
            Vec3A::from((whi + pad).as_vec3()),
        )
    }
}

/// Placements that place something, each with its instance.
pub type Usable<'a> = Vec<(&'a Placement, Instance)>;

/// The placements that place something (their prototype, of `triangles[prototype]` triangles,
/// has any; their transform is invertible and finite) with their instances, and those dropped for
/// their transform: what [`Instances::place`] places, decided without building anything.
pub fn usable_placements<'a>(
    triangles: &[usize],
    placements: &'a [Placement],
) -> Result<(Usable<'a>, Unplaced), InstanceError> {
    check_placements(triangles.len(), placements)?;
    let mut usable = Vec::with_capacity(placements.len());
    let mut dropped = Unplaced::default();
    for p in placements {
        let n = triangles[p.prototype as usize];
        if n == 0 {
            continue;
        }
        match Instance::new(p.prototype, &p.to_world) {
            Some(inst) => usable.push((p, inst)),
            None => {
                dropped.placements += 1;
                dropped.triangles += n;
            }
        }
    }
    Ok((usable, dropped))
}

fn check_placements(prototypes: usize, placements: &[Placement]) -> Result<(), InstanceError> {
    match placements
        .iter()
        .enumerate()
        .find(|(_, p)| p.prototype as usize >= prototypes)
    {
        Some((instance, p)) => Err(InstanceError::Prototype {
            instance,
            prototype: p.prototype,
            count: prototypes,
        }),
        None => Ok(()),
    }
}

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
    /// The prototypes (their BVHs built) and the placements that are usable, with the tree over
    /// them. A singular or non-finite transform drops its placement (nothing of it could be hit):
    /// the dropped placements and the triangles they would have placed are returned.
    pub fn build(
        prototypes: Vec<Mesh>,
        placements: &[Placement],
    ) -> Result<(Instances, Unplaced), InstanceError> {
        check_placements(prototypes.len(), placements)?;
        let prototypes = prototypes
            .into_iter()
            .map(|m| Arc::new(Prototype::new(m)))
            .collect();
        Self::place(prototypes, placements)
    }

    /// The instances of prototypes already built (shared with other scenes): only the tree over
    /// the placements is built. As [`Instances::build`] otherwise.
    pub fn place(
        prototypes: Vec<Arc<Prototype>>,
        placements: &[Placement],
    ) -> Result<(Instances, Unplaced), InstanceError> {
        let triangles: Vec<usize> = prototypes.iter().map(|p| p.mesh.len()).collect();
        let (usable, dropped) = usable_placements(&triangles, placements)?;
        let mut instances = Vec::with_capacity(usable.len());
        let mut boxes = Vec::with_capacity(usable.len());
        for (p, inst) in usable {
            let proto = &prototypes[p.prototype as usize];
            boxes.push(Instance::world_box(&p.to_world, &proto.cover));
            instances.push(inst);
        }
        if instances.is_empty() {
            return Ok((
                Instances {
                    prototypes,
                    ..Instances::default()
                },
                dropped,
            ));
        }
        if instances.len() >= MAX_BOXES {
            return Err(InstanceError::TooMany {
                count: instances.len(),
                max: MAX_BOXES - 1,
            });
        }
        // One instance a leaf: each placement's own box is tested before its ray is moved.
        let (tree, order) = BoxTree::build(&boxes, TOP_TRAVERSAL_COST);
        // The instances in leaf order, so that a leaf's range indexes them directly.
        let ordered: Vec<Instance> = order
            .iter()
            .map(|&i| instances[i as usize].clone())
            .collect();
        Ok((
            Instances {
                prototypes,
                instances: ordered,
                tree,
            },
            dropped,
        ))
    }

    /// Whether the scene has any instance.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.instances.is_empty()
    }

    /// The world-space box of everything instanced, or `None` without instances.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.tree.bounds()
    }

    /// Triangles stored once per prototype.
    pub fn stored_triangles(&self) -> usize {
        self.prototypes.iter().map(|p| p.mesh.len()).sum()
    }

    /// Triangles the instances place in the world (each prototype's count once per instance).
    pub fn placed_triangles(&self) -> u64 {
        self.instances
            .iter()
            .map(|i| self.prototypes[i.prototype as usize].mesh.len() as u64)
            .sum()
    }

    /// Approximate bytes held: prototypes, instances and the tree.
    pub fn bytes(&self) -> usize {
        self.prototypes.iter().map(|p| p.bytes()).sum::<usize>()
            + self.instances.len() * std::mem::size_of::<Instance>()
            + self.tree.bytes()
    }

    /// The instance and its prototype.
    #[inline(always)]
    pub fn get(&self, instance: u32) -> (&Instance, &Prototype) {
        let inst = &self.instances[instance as usize];
        (inst, &self.prototypes[inst.prototype as usize])
    }

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

/// Appends the placements to `mesh` as world-space triangles, as the loader flattens a mesh:
/// positions by the f64 transform, normals by its inverse transpose, tangents by its linear part
/// (the handedness flipped under a mirror), two corners swapped under a mirror. Attributes one side
/// lacks are zero on it (a zero normal or tangent means "none" to the shading). For consumers that
/// want world triangles, and for tests that hold the two levels to the one.
pub fn flatten_into(prototypes: &[Mesh], placements: &[Placement], mesh: &mut Mesh) {
    fn ensure<T: Copy>(slot: &mut Option<Vec<T>>, wanted: bool, len: usize, zero: T) {
        if wanted && slot.is_none() {
            *slot = Some(vec![zero; len]);
        }
    }
    let any = |f: fn(&Mesh) -> bool| prototypes.iter().any(f);
    let len = mesh.len();
    ensure(
        &mut mesh.normals,
        any(|m| m.normals.is_some()),
        len,
        [Vec3::ZERO; 3],
    );
    ensure(
        &mut mesh.uv0,
        any(|m| m.uv0.is_some()),
        len,
        [glam::Vec2::ZERO; 3],
    );
    ensure(
        &mut mesh.uv1,
        any(|m| m.uv1.is_some()),
        len,
        [glam::Vec2::ZERO; 3],
    );
    ensure(
        &mut mesh.tangents,
        any(|m| m.tangents.is_some()),
        len,
        [glam::Vec4::ZERO; 3],
    );
    for p in placements {
        let Some(proto) = prototypes.get(p.prototype as usize) else {
            continue;
        };
        let m3 = DMat3::from_mat4(p.to_world);
        let det = m3.determinant();
        let sign = if det < 0.0 { -1.0 } else { 1.0 };
        let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
        let normal_matrix = DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign;
        let order = if det < 0.0 { [0, 2, 1] } else { [0, 1, 2] };
        for t in 0..proto.len() {
            let pos = order.map(|i| {
                p.to_world
                    .transform_point3(proto.positions[t][i].as_dvec3())
                    .as_vec3()
            });
            mesh.positions.push(pos);
            mesh.material.push(proto.material[t]);
            if let Some(out) = &mut mesh.normals {
                out.push(proto.normals.as_ref().map_or([Vec3::ZERO; 3], |n| {
                    order.map(|i| {
                        (normal_matrix * n[t][i].as_dvec3())
                            .normalize_or_zero()
                            .as_vec3()
                    })
                }));
            }
            for (out, src) in [(&mut mesh.uv0, &proto.uv0), (&mut mesh.uv1, &proto.uv1)] {
                if let Some(out) = out {
                    out.push(
                        src.as_ref()
                            .map_or([glam::Vec2::ZERO; 3], |u| order.map(|i| u[t][i])),
                    );
                }
            }
            if let Some(out) = &mut mesh.tangents {
                out.push(proto.tangents.as_ref().map_or([glam::Vec4::ZERO; 3], |ts| {
                    order.map(|i| {
                        let v = ts[t][i];
                        let xyz = (m3 * v.truncate().as_dvec3()).normalize_or_zero().as_vec3();
                        xyz.extend(v.w * sign as f32)
                    })
                }));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, Vec3};

    /// A unit cube's twelve triangles around the origin.
    fn cube() -> Mesh {
        let mut mesh = Mesh::default();
        let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) - 0.5;
        let quads = [
            [c(0., 0., 0.), c(1., 0., 0.), c(1., 1., 0.), c(0., 1., 0.)],
            [c(0., 0., 1.), c(0., 1., 1.), c(1., 1., 1.), c(1., 0., 1.)],
            [c(0., 0., 0.), c(0., 1., 0.), c(0., 1., 1.), c(0., 0., 1.)],
            [c(1., 0., 0.), c(1., 0., 1.), c(1., 1., 1.), c(1., 1., 0.)],
            [c(0., 0., 0.), c(0., 0., 1.), c(1., 0., 1.), c(1., 0., 0.)],
            [c(0., 1., 0.), c(1., 1., 0.), c(1., 1., 1.), c(0., 1., 1.)],
        ];
        for q in quads {
            mesh.positions.push([q[0], q[1], q[2]]);
            mesh.positions.push([q[0], q[2], q[3]]);
            mesh.material.extend([0, 0]);
        }
        mesh
    }

    fn placements(n: usize) -> Vec<Placement> {
        (0..n)
            .map(|i| {
                let f = i as f64;
                Placement {
                    prototype: 0,
                    to_world: DMat4::from_scale_rotation_translation(
                        DVec3::new(
                            0.3 + 0.1 * (f % 3.0),
                            0.4,
                            if i % 4 == 0 { -0.5 } else { 0.5 },
                        ),
                        DQuat::from_rotation_y(0.7 * f) * DQuat::from_rotation_x(0.3 * f),
                        DVec3::new((f % 7.0) - 3.0, (f % 5.0) - 2.0, -(f % 3.0)),
                    ),
                }
            })
            .collect()
    }

    /// The same placements flattened to world triangles (in f64, as the loader does).
    fn flattened(proto: &Mesh, placements: &[Placement]) -> Vec<[Vec3; 3]> {
        let mut out = Vec::new();
        for p in placements {
            for t in &proto.positions {
                out.push(t.map(|v| p.to_world.transform_point3(v.as_dvec3()).as_vec3()));
            }
        }
        out
    }

    /// Rays from a grid of origins in random directions: the two-level answer equals a brute-force
    /// test of every flattened triangle (t to a relative 1e-5; the hit's identity where the nearest
    /// two are not within that of each other), and `any` agrees with it.
    #[test]
    fn two_levels_find_what_flattening_finds() {
        two_levels_match_flattening(cube(), 200);
        two_levels_match_flattening(rod(), 40);
    }

    /// Small triangles along the diagonal of the cube [−0.5, 0.5]³, enough for a tree of a few
    /// levels: its box is the cube, its cover ([`Bvh::cover`]) much less.
    fn rod() -> Mesh {
        let mut mesh = Mesh::default();
        for i in 0..400 {
            let c = Vec3::splat(i as f32 / 399.0 - 0.5) * 0.84;
            let s = 0.08;
            mesh.positions.push([
                c + Vec3::new(-s, -s, 0.0),
                c + Vec3::new(s, -s, s),
                c + Vec3::new(0.0, s, -s),
            ]);
            mesh.material.push(0);
        }
        mesh
    }

    /// A placement's world box holds every corner of its triangles moved by the f64 transform,
    /// is never larger than the prototype's box moved, and is much smaller for the rod turned.
    #[test]
    fn world_boxes_hold_the_triangles_and_little_else() {
        let proto = Prototype::new(rod());
        assert!(proto.cover.len() > 4 && proto.cover.len() <= COVER_BOXES);
        let whole = [proto.mesh.bounds()];
        let mut ratios = Vec::new();
        for p in placements(24) {
            let (lo, hi) = Instance::world_box(&p.to_world, &proto.cover);
            for v in proto.mesh.positions.iter().flatten() {
                let w = Vec3A::from(p.to_world.transform_point3(v.as_dvec3()).as_vec3());
                assert!(
                    w.cmpge(lo).all() && w.cmple(hi).all(),
                    "{w} outside {lo}..{hi}"
                );
            }
            let (wlo, whi) = Instance::world_box(&p.to_world, &whole);
            // Within the rounding of the tree's boxes, which hold the mesh's box.
            let slack = Vec3A::splat(1e-5);
            assert!(lo.cmpge(wlo - slack).all() && hi.cmple(whi + slack).all());
            let volume = |lo: Vec3A, hi: Vec3A| (hi - lo).x * (hi - lo).y * (hi - lo).z;
            ratios.push(volume(lo, hi) / volume(wlo, whi));
        }
        let mean = ratios.iter().sum::<f32>() / ratios.len() as f32;
        assert!(mean < 0.6, "cover boxes' volume {mean} of the whole box's");
    }

    /// Rays from a grid of origins in random directions against `proto` placed 40 times.
    fn two_levels_match_flattening(proto: Mesh, enough: usize) {
        let places = placements(40);
        let (inst, dropped) = Instances::build(vec![proto.clone()], &places).unwrap();
        assert_eq!(dropped, Unplaced::default());
        assert_eq!(inst.instances.len(), 40);
        let world = flattened(&proto, &places);
        let mut state = 0x1234_5678u32;
        let mut rnd = || {
            state = crate::sampler::hash_u32(state);
            crate::sampler::bits_to_unit(state)
        };
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..4000 {
            let o = Vec3::new(rnd() * 10.0 - 5.0, rnd() * 8.0 - 4.0, 6.0 * rnd() - 3.0);
            let d = (Vec3::new(rnd(), rnd(), rnd()) * 2.0 - 1.0).normalize();
            let ray = Ray::new(o, d);
            let pre = RayPrecomp::new(&ray);
            let brute = world
                .iter()
                .filter_map(|t| crate::geometry::intersect_watertight(&pre, t, f32::INFINITY))
                .map(|h| h.t)
                .fold(f32::INFINITY, f32::min);
            let two = inst.closest(&ray, f32::INFINITY, None, |_, _, _| true);
            match two {
                Some(h) => {
                    hits += 1;
                    assert!(
                        (h.t - brute).abs() <= 1e-5 * brute.max(1.0),
                        "t {} against {brute}",
                        h.t
                    );
                    assert!(inst.any(&ray, f32::INFINITY, |_, _, _| true));
                    assert!(!inst.any(&ray, h.t * 0.999, |_, _, _| true));
                }
                None => {
                    misses += 1;
                    assert!(brute.is_infinite(), "missed a hit at {brute}");
                    assert!(!inst.any(&ray, f32::INFINITY, |_, _, _| true));
                }
            }
        }
        assert!(
            hits > enough && misses > enough,
            "{hits} hits, {misses} misses"
        );
    }

    /// Two instances in the same place: the tie goes to the smaller instance index, whichever of
    /// them the walk meets first, and a filter that refuses one instance finds the other.
    #[test]
    fn ties_go_to_the_smaller_instance() {
        let p = Placement {
            prototype: 0,
            to_world: DMat4::from_translation(DVec3::new(0.0, 0.0, -3.0)),
        };
        let (inst, _) = Instances::build(vec![cube()], &[p.clone(), p]).unwrap();
        let ray = Ray::new(Vec3::ZERO, -Vec3::Z);
        let h = inst
            .closest(&ray, f32::INFINITY, None, |_, _, _| true)
            .unwrap();
        assert_eq!(h.t, 2.5);
        assert_eq!(h.instance, 0);
        let h = inst
            .closest(&ray, f32::INFINITY, None, |k, _, _| k == 1)
            .unwrap();
        assert_eq!((h.t, h.instance), (2.5, 1));
        // A better flat hit given as `best` wins; a worse one loses.
        let flat = |t: f32| InstanceHit {
            t,
            instance: u32::MAX,
            triangle: 0,
            b1: 0.0,
            b2: 0.0,
        };
        let got = inst.closest(&ray, f32::INFINITY, Some(flat(1.0)), |_, _, _| true);
        assert_eq!(got.unwrap().instance, u32::MAX);
        let got = inst.closest(&ray, f32::INFINITY, Some(flat(3.0)), |_, _, _| true);
        assert_eq!(got.unwrap().instance, 0);
    }

    /// A singular transform drops its placement; a missing prototype is an error.
    #[test]
    fn unusable_placements() {
        let zero = Placement {
            prototype: 0,
            to_world: DMat4::from_scale(DVec3::new(1.0, 0.0, 1.0)),
        };
        let (inst, dropped) = Instances::build(vec![cube()], &[zero]).unwrap();
        let unplaced = Unplaced {
            placements: 1,
            triangles: 12,
        };
        assert_eq!((inst.instances.len(), dropped), (0, unplaced));
        assert!(inst.is_empty());
        let ray = Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z);
        assert!(inst
            .closest(&ray, f32::INFINITY, None, |_, _, _| true)
            .is_none());
        let bad = Placement {
            prototype: 3,
            to_world: DMat4::IDENTITY,
        };
        assert!(Instances::build(vec![cube()], &[bad]).is_err());
    }
}
