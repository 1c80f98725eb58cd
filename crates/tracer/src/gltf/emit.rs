//! Emitting a primitive's triangles under a transform: positions by the world matrix, normals by its
//! inverse transpose, tangents by the matrix with the handedness sign flipped under a mirroring
//! transform, and two corners swapped under a negative determinant so that counter-clockwise stays
//! the front face. Degenerate triangles (zero area or non-finite corners after the transform) are
//! dropped and counted. The loader emits each node's primitives once; an animated scene emits the
//! ones that move or deform again for every frame (`animated/frame.rs`), through the same function.

use super::bounds::{outside, Far};
use super::mesh::PrimitiveMaterial;
use crate::geometry::{renderable, Mesh};
use glam::{DMat3, DMat4, Vec2, Vec3, Vec4};
use std::sync::Arc;

/// A primitive's tangents: per vertex (a file's TANGENT, or MikkTSpace's where no vertex was
/// split), or per triangle corner, in the order of the primitive's triangles.
#[derive(Clone, Copy, Debug)]
pub(crate) enum TangentsRef<'a> {
    Vertex(&'a [Vec4]),
    Corner(&'a [[Vec4; 3]]),
}

/// A primitive in its mesh's space, as slices: the triangles (indices into the vertex arrays) and
/// the vertex attributes, every index checked by the reader.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Vertices<'a> {
    /// The primitive's index in its mesh (for messages).
    pub primitive: usize,
    pub triangles: &'a [[u32; 3]],
    pub positions: &'a [Vec3],
    pub normals: Option<&'a [Vec3]>,
    pub uv: [Option<&'a [Vec2]>; 2],
    pub tangents: Option<TangentsRef<'a>>,
}

/// A primitive's tangents, owned.
#[derive(Clone, Debug)]
pub(crate) enum LocalTangents {
    Vertex(Arc<[Vec4]>),
    Corner(Arc<[[Vec4; 3]]>),
}

/// A primitive in its mesh's space, owned and shareable between threads: what an animated scene
/// keeps of the primitives it emits again at every frame.
#[derive(Clone, Debug)]
pub(crate) struct LocalPrimitive {
    pub primitive: usize,
    pub material: PrimitiveMaterial,
    pub triangles: Arc<[[u32; 3]]>,
    pub positions: Arc<[Vec3]>,
    pub normals: Option<Arc<[Vec3]>>,
    pub uv: [Option<Arc<[Vec2]>>; 2],
    pub tangents: Option<LocalTangents>,
}

impl LocalPrimitive {
    pub fn vertices(&self) -> Vertices<'_> {
        Vertices {
            primitive: self.primitive,
            triangles: &self.triangles,
            positions: &self.positions,
            normals: self.normals.as_deref(),
            uv: [self.uv[0].as_deref(), self.uv[1].as_deref()],
            tangents: self.tangents.as_ref().map(|t| match t {
                LocalTangents::Vertex(v) => TangentsRef::Vertex(v),
                LocalTangents::Corner(c) => TangentsRef::Corner(c),
            }),
        }
    }
}

/// What an emission did.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Emitted {
    /// Triangles dropped as degenerate.
    pub dropped: usize,
    /// The first kept corner beyond ±`MAX_COORDINATE` (when asked to look for one).
    pub far: Option<Far>,
}

/// Where emitted triangles come from, for [`Far`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Origin {
    pub node: usize,
    pub mesh: usize,
}

/// Appends primitive `p` under `world` to `out` (which stores the attribute arrays it has), with
/// material `mat`. Looks for a corner beyond ±`MAX_COORDINATE` when `find_far`.
pub(crate) fn emit(
    out: &mut Mesh,
    p: &Vertices<'_>,
    world: &DMat4,
    mat: PrimitiveMaterial,
    origin: Origin,
    find_far: bool,
) -> Emitted {
    let mut done = Emitted::default();
    let m3 = DMat3::from_mat4(*world);
    let det = m3.determinant();
    let flip = det < 0.0;
    let sign = if flip { -1.0 } else { 1.0 };
    // Cofactor matrix = det · M^{-T}; times sign(det) it is |det| · M^{-T}, defined even if singular.
    let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
    let normal_matrix = DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign;
    let wp: Vec<Vec3> = p
        .positions
        .iter()
        .map(|v| world.transform_point3(v.as_dvec3()).as_vec3())
        .collect();
    let wn: Option<Vec<Vec3>> = p.normals.map(|ns| {
        ns.iter()
            .map(|n| (normal_matrix * n.as_dvec3()).normalize_or_zero().as_vec3())
            .collect()
    });
    let tangent = |t: &Vec4| {
        let xyz = (m3 * t.truncate().as_dvec3()).normalize_or_zero().as_vec3();
        let w = if t.w < 0.0 { -1.0 } else { 1.0 } * sign as f32;
        xyz.extend(w)
    };
    // Per vertex, or per corner (MikkTSpace split some vertex); at most one is set.
    let (wt, wt_corners): (Option<Vec<Vec4>>, Option<Vec<[Vec4; 3]>>) = match p.tangents {
        Some(TangentsRef::Vertex(ts)) => (Some(ts.iter().map(tangent).collect()), None),
        Some(TangentsRef::Corner(ts)) => (
            None,
            Some(ts.iter().map(|c| c.map(|t| tangent(&t))).collect()),
        ),
        None => (None, None),
    };
    let tangent_uv = mat
        .normal_map_uv
        .and_then(|s| p.uv.get(s as usize).copied().flatten());
    for (k, t) in p.triangles.iter().enumerate() {
        // The corners in the order they are stored (two swapped under a mirroring transform).
        let order = if flip { [0, 2, 1] } else { [0, 1, 2] };
        let [a, b, c] = order.map(|i| t[i]);
        let [a, b, c] = [a as usize, b as usize, c as usize];
        let pos = [wp[a], wp[b], wp[c]];
        if !renderable(&pos) {
            done.dropped += 1;
            continue;
        }
        if find_far && done.far.is_none() {
            if let Some(&corner) = pos.iter().find(|v| outside(**v)) {
                done.far = Some(Far {
                    node: origin.node,
                    mesh: origin.mesh,
                    primitive: p.primitive,
                    corner,
                });
            }
        }
        out.positions.push(pos);
        out.material.push(mat.index);
        let flat = (pos[1] - pos[0]).cross(pos[2] - pos[0]).normalize_or_zero();
        if let Some(normals) = &mut out.normals {
            let corner = |i: usize| match &wn {
                Some(wn) if wn[i] != Vec3::ZERO => wn[i],
                _ => flat,
            };
            normals.push([corner(a), corner(b), corner(c)]);
        }
        for (set, slot) in [&mut out.uv0, &mut out.uv1].into_iter().enumerate() {
            if let Some(out) = slot {
                out.push(match p.uv[set] {
                    Some(uv) => [uv[a], uv[b], uv[c]],
                    None => [Vec2::ZERO; 3],
                });
            }
        }
        if let Some(out) = &mut out.tangents {
            out.push(match (&wt, &wt_corners, tangent_uv) {
                (Some(wt), _, _) => [wt[a], wt[b], wt[c]],
                (None, Some(wc), _) => order.map(|i| wc[k][i]),
                (None, None, Some(uv)) => [generate_tangent(pos, [uv[a], uv[b], uv[c]]); 3],
                (None, None, None) => [Vec4::ZERO; 3],
            });
        }
    }
    done
}

/// A per-triangle tangent from positions and UVs: dP/du, with w such that cross(N, T)·w follows
/// −dP/dv (image "up"), N the geometric (front) normal.
pub(crate) fn generate_tangent(p: [Vec3; 3], uv: [Vec2; 3]) -> Vec4 {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let n = e1.cross(e2);
    let fallback = || {
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO {
            Vec4::new(1.0, 0.0, 0.0, 1.0)
        } else {
            n.any_orthonormal_vector().extend(1.0)
        }
    };
    let det = d1.x * d2.y - d2.x * d1.y;
    if det == 0.0 || !det.is_finite() {
        return fallback();
    }
    let r = 1.0 / det;
    let dpdu = (e1 * d2.y - e2 * d1.y) * r;
    let dpdv = (e2 * d1.x - e1 * d2.x) * r;
    let t = dpdu.normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return fallback();
    }
    let w = if n.cross(t).dot(-dpdv) < 0.0 {
        -1.0
    } else {
        1.0
    };
    t.extend(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_follows_u_and_image_up() {
        // Triangle in the XY plane facing +Z; u along +X, v = 1 − y (image top at y = 1).
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let uv = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 0.0),
        ];
        let t = generate_tangent(p, uv);
        assert!(
            (t.truncate() - Vec3::X).length() < 1e-6 && t.w == 1.0,
            "{t}"
        );
        // Mirrored UVs (v = y) flip the handedness.
        let uv = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 1.0),
        ];
        assert_eq!(generate_tangent(p, uv).w, -1.0);
        // Degenerate UVs fall back to some unit tangent.
        let t = generate_tangent(p, [Vec2::ZERO; 3]);
        assert!((t.truncate().length() - 1.0).abs() < 1e-6);
    }
}
