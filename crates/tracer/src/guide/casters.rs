//! The caustic casters: the scene's specular triangles (materials of delta lobes only: mirrors,
//! smooth glass) gathered into clusters by a coarse grid, each a bounding sphere the photons are
//! aimed at. Aiming spends every photon on light that can become a caustic, instead of the few
//! percent of a light's photons that a small glass object intercepts.

use crate::scene::Scene;
use glam::Vec3;
use std::collections::BTreeMap;

/// Grid cells per axis of the scene's bounds the casters are clustered by.
const CLUSTER_CELLS: f32 = 16.0;

/// A bounding sphere of specular triangles.
#[derive(Clone, Copy, Debug)]
pub(super) struct Caster {
    pub center: Vec3,
    pub radius: f32,
}

/// The scene's caster clusters, in the order of their grid cells (the same for every build of
/// the same scene). Empty where no world-space triangle is specular.
pub(super) fn casters(scene: &Scene) -> Vec<Caster> {
    // Most scenes have no specular material: then no triangle need be looked at.
    let any_specular = (0..scene.materials.len() as u32).any(|m| scene.is_specular_material(m));
    if !any_specular {
        return Vec::new();
    }
    let (lo, hi) = (scene.info.bounds_min, scene.info.bounds_max);
    let cell = ((hi - lo).max_element() / CLUSTER_CELLS).max(1e-6);
    let mut boxes: BTreeMap<[i64; 3], (Vec3, Vec3)> = BTreeMap::new();
    let mesh = &scene.mesh;
    for (tri, corners) in mesh.positions.iter().enumerate() {
        if !scene.is_specular_material(mesh.material[tri]) {
            continue;
        }
        let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
        let c = ((centroid - lo) / cell).floor();
        let key = [c.x as i64, c.y as i64, c.z as i64];
        let (tlo, thi) = (
            corners[0].min(corners[1]).min(corners[2]),
            corners[0].max(corners[1]).max(corners[2]),
        );
        let entry = boxes.entry(key).or_insert((tlo, thi));
        entry.0 = entry.0.min(tlo);
        entry.1 = entry.1.max(thi);
    }
    boxes
        .values()
        .filter(|(blo, bhi)| blo.is_finite() && bhi.is_finite())
        .map(|&(blo, bhi)| Caster {
            center: (blo + bhi) * 0.5,
            radius: ((bhi - blo) * 0.5).length().max(1e-6),
        })
        .collect()
}
