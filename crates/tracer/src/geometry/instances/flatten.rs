//! Flattening: placements turned into world-space triangles, as the loader does.

use super::Placement;
use crate::geometry::Mesh;
use glam::{DMat3, Vec3};

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
