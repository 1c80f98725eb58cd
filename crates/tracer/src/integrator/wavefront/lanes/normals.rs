//! Which meshes of a scene have vertex normals, as `shade_hit` reads it: a constant of each of its
//! copies, so that a scene whose meshes are all alike pays for no per-lane select.

use crate::scene::Scene;

/// No mesh has vertex normals: the shading normal is the geometric one.
pub const FLAT: u8 = 0;
/// Every mesh has them.
pub const SMOOTH: u8 = 1;
/// Some have them: each lane's hit says (`Lanes::smooth`).
pub const MIXED: u8 = 2;

/// Which of the three `scene` is.
pub fn of(scene: &Scene) -> u8 {
    let world = (!scene.mesh.is_empty()).then_some(&*scene.mesh);
    let meshes = world
        .into_iter()
        .chain(scene.instances.prototypes.iter().map(|p| &p.mesh));
    let (mut any, mut all) = (false, true);
    for m in meshes {
        any |= m.normals.is_some();
        all &= m.normals.is_some();
    }
    match (any, all) {
        (false, _) => FLAT,
        (true, true) => SMOOTH,
        (true, false) => MIXED,
    }
}
