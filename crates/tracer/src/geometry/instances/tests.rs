//! Tests of the two levels: hits against flattened triangles, world boxes, ties, bad placements.

use super::*;
use crate::geometry::{Ray, RayPrecomp};
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
