//! Instancing without flattening (`geometry::Instances`): a scene whose meshes are kept once and
//! placed by transforms is the scene with those meshes flattened into world triangles — the same
//! hits and surfaces (to rounding), the same image (to noise) — and renders the same bits however
//! its work is split.

mod common;

use common::*;
use glam::Vec3;
use pathfarm_tracer::geometry::Ray;
use pathfarm_tracer::{render_image, RenderSettings, Scene};

fn both() -> (Scene, Scene) {
    let parts = instanced_room();
    let flat = Scene::build(parts.clone().flatten_instances()).expect("flattened scene builds");
    let inst = Scene::build(parts).expect("instanced scene builds");
    (inst, flat)
}

#[test]
fn the_scene_is_kept_instanced() {
    let (inst, flat) = both();
    assert_eq!(inst.info.instances, 14);
    assert_eq!(inst.instances.prototypes.len(), 2);
    let sphere = inst.instances.prototypes[0].mesh.len();
    assert_eq!(inst.info.instanced_triangles, 12 * sphere as u64 + 2 * 2);
    // Stored once: the room, the panel, one sphere and one quad.
    assert_eq!(inst.info.triangles, 14 + sphere + 2);
    assert_eq!(flat.info.triangles, 14 + 12 * sphere + 2 * 2);
    assert_eq!(flat.info.instances, 0);
    assert!(inst.info.bytes < flat.info.bytes);
    // The bounds are the room's either way.
    assert!(
        (inst.info.bounds_min - flat.info.bounds_min)
            .abs()
            .max_element()
            < 1e-3
    );
    assert!(
        (inst.info.bounds_max - flat.info.bounds_max)
            .abs()
            .max_element()
            < 1e-3
    );
}

/// Rays from all over the room in every direction: the instanced scene hits what the flattened one
/// hits, at the same distance, with the same surface (position, normals, tangent, texture
/// coordinates, material, side) to rounding; shadow queries agree; the cut-out quads let rays
/// through in both.
#[test]
fn instanced_surfaces_are_the_flattened_surfaces() {
    let (inst, flat) = both();
    let mut rng = Pcg32::seeded(7);
    let (mut compared, mut on_spheres, mut disagree) = (0, 0, 0);
    let (mut shadows, mut shadows_disagree) = (0, 0);
    let n = 20_000;
    for _ in 0..n {
        let o = Vec3::new(
            rng.f32() * 7.0 - 3.5,
            rng.f32() * 7.0 - 3.5,
            rng.f32() * 7.0 - 3.5,
        );
        let d = (Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0).normalize_or_zero();
        if d == Vec3::ZERO {
            continue;
        }
        let ray = Ray::new(o, d);
        let u = rng.f32();
        let (a, b) = (
            inst.intersect(&ray, f32::INFINITY, u),
            flat.intersect(&ray, f32::INFINITY, u),
        );
        let (Some(a), Some(b)) = (a, b) else {
            panic!("the room is closed: every ray hits something ({a:?}, {b:?})");
        };
        let (sa, sb) = (inst.surface(&ray, &a), flat.surface(&ray, &b));
        // Rays that graze a silhouette may pass one copy and hit the other: rare, and counted.
        if (a.t - b.t).abs() > 1e-4 * a.t.max(1.0) || sa.material != sb.material {
            disagree += 1;
            continue;
        }
        compared += 1;
        assert_ne!(sa.material, 3, "the cut-out quads are never hit");
        on_spheres += usize::from(sa.material == 2);
        assert!(
            (sa.p - sb.p).length() < 1e-4,
            "{:?} against {:?}",
            sa.p,
            sb.p
        );
        assert!(sa.ng.dot(sb.ng) > 0.9999, "{:?} against {:?}", sa.ng, sb.ng);
        assert!(sa.ns.dot(sb.ns) > 0.9999, "{:?} against {:?}", sa.ns, sb.ns);
        assert_eq!(sa.front, sb.front);
        assert!((sa.uv[0] - sb.uv[0]).length() < 1e-4);
        // Flattening gives the room zero tangents where the instanced scene has none: the same
        // to the shading.
        let (ta, tb) = (
            sa.tangent.unwrap_or(glam::Vec4::ZERO),
            sb.tangent.unwrap_or(glam::Vec4::ZERO),
        );
        let (xa, xb) = (ta.truncate(), tb.truncate());
        assert!(
            xa.dot(xb) >= 0.9999 * xa.length() * xb.length(),
            "{ta:?} against {tb:?}"
        );
        assert!(
            (ta.w - tb.w).abs() < 1e-5,
            "handedness {} against {}",
            ta.w,
            tb.w
        );
        // A shadow query towards the ceiling panel's centre.
        let target = Vec3::new(0.0, 3.9, 0.0);
        let to = target - sa.p;
        let shadow = Ray::new(
            sa.p + sa.ng * 1e-3 * if sa.front { 1.0 } else { -1.0 },
            to.normalize(),
        );
        let dist = to.length() * 0.999;
        if dist > 1e-2 {
            shadows += 1;
            // Grazing shadow rays may pass one copy and meet the other: rare, and counted.
            shadows_disagree +=
                usize::from(inst.visible(&shadow, dist, u) != flat.visible(&shadow, dist, u));
        }
    }
    assert!(shadows > n / 2);
    assert!(
        shadows_disagree * 1000 < shadows,
        "{shadows_disagree} of {shadows} shadow rays disagree"
    );
    assert!(disagree * 1000 < n, "{disagree} of {n} rays disagree");
    assert!(compared > n * 9 / 10, "{compared} compared");
    assert!(
        on_spheres > 1000,
        "{on_spheres} hits on the instanced spheres"
    );
}

/// The same render of both scenes: their means agree within noise (the geometry differs only by
/// rounding, so most paths are the same paths and the difference is far below the error bars).
#[test]
fn instanced_scene_renders_as_flattened() {
    let (inst, flat) = both();
    let settings = RenderSettings {
        seed: 5,
        ..RenderSettings::new(48, 40)
    };
    let a = render_image(&inst, &settings, 16, 0..64, &|_| {});
    let b = render_image(&flat, &settings, 16, 0..64, &|_| {});
    let ((ma, sa), (mb, sb)) = (image_mean_and_stderr(&a), image_mean_and_stderr(&b));
    let z = (ma - mb) / (sa * sa + sb * sb).sqrt();
    assert!(ma > 0.05, "the room is lit: {ma}");
    assert!(
        z.abs() < 1.0,
        "instanced {ma} ± {sa}, flattened {mb} ± {sb} (z {z})"
    );
    // And pixel by pixel, most pixels are the same to a few parts in a thousand.
    let close = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .filter(|(p, q)| {
            let (p, q) = (p.mean(), q.mean());
            (0..3).all(|c| (p[c] - q[c]).abs() <= 2e-3 * q[c].abs().max(0.05))
        })
        .count();
    assert!(
        close * 10 > a.pixels.len() * 8,
        "{close} of {} pixels close",
        a.pixels.len()
    );
}
