//! MikkTSpace tangents for primitives that have a normal map and no TANGENT attribute.
//!
//! glTF says a renderer SHOULD compute MikkTSpace tangents when a file has none, and most
//! exporters (Blender's by default) write none: their normal maps are baked against MikkTSpace, so
//! anything else shades them wrong across smooth edges. The algorithm is `bevy_mikktspace` (a safe
//! Rust port of Mikkelsen's reference implementation, maintained by Bevy), run once per primitive
//! on its local vertices, before any instance transforms them; the results then go through the
//! instance's transform exactly like a file's TANGENT.
//!
//! # Same bits on every machine
//! The reference weights each face's tangent by the angle of its corner, `acos`, from the C
//! library: a different function on every platform (glibc even picks FMA or non-FMA code at run
//! time). `bevy_mikktspace` takes its `sqrt` and `acos` from an [`Ops`] type: [`DetOps`] gives it
//! `f32::sqrt` (correctly rounded by IEEE 754, one instruction everywhere) and
//! [`det::acos`](crate::math::det::acos) (fdlibm's method in plain IEEE operations, computed in
//! double precision as the reference does; measured: the same bits as the platform's on all 2²⁰
//! arguments of its test, within 1 ulp anywhere). Everything else in the crate is `f32` adds,
//! multiplies and divides, which Rust never contracts into FMA, integer sorts and a `BTreeMap`: the
//! tangents are the same bits on every machine. `tests/tangents.rs` compares them with an
//! independent port of the reference (the `mikktspace` crate, libm `acos`) on real meshes.
//!
//! # Where it departs from the reference, and why
//! The crate is built with its `corrected-edge-sorting` and `corrected-vertex-welding` features.
//! The reference sorts edges with a quicksort whose pivots follow a fixed seed (so a crafted file
//! can drive its recursion as deep as it has edges: a stack overflow, which aborts the process
//! rather than panicking), and welds vertices by splitting space until a cell cannot be split, then
//! compares every pair in it (quadratic in the vertices a crafted file puts within one float step
//! on the widest axis: hours). The corrected forms sort and use a `BTreeMap`. Measured against the
//! reference (`tests/tangents.rs`, and a comparison of the crate's builds): the same tangents within
//! 1e-7 on the UV sphere, the mirrored grid and the seamed cylinder with normals, degenerate UVs
//! included; the sorting alone changes nothing there. The weld keeps the lowest index of identical
//! vertices where the reference keeps another, and that reorders the one order-dependent step of
//! MikkTSpace (which group first claims a triangle that is degenerate in UV): on a faceted mesh
//! without NORMAL whose UVs collapse, 17 of 576 corners beside the collapsed triangles got a
//! tangent where the reference gives none (or another neighbour's). Those triangles have no
//! meaningful UV direction to begin with.
//!
//! # Conventions
//! MikkTSpace is fed v' = 1 − v, the UVs the way Blender and most bakers hold them (v up, the
//! image's bottom row at v' = 0), which is what the exporters computed their tangents on before
//! flipping v for glTF. So w is +1 where cross(N, T)·w points to decreasing glTF v, "up" in the
//! image, as glTF specifies (and as the per-triangle tangents of `mesh.rs` do). Normals are the
//! primitive's NORMAL, normalized, or the face's own where it has none.
//!
//! # Costs and limits
//! The crate's working memory is a few hundred bytes a triangle, so a primitive over
//! [`MAX_TRIANGLES`] keeps per-triangle tangents (with a warning naming it) rather than double
//! the load's peak memory. The crate's grouping of faces around a vertex recurses once per face
//! sharing it and compares every pair of those faces: a crafted fan of a million triangles around
//! one point would overflow the stack (an abort, not a catchable panic) or run for hours. So the
//! corners at each position are counted first (a position's corners bound every group the crate
//! makes there), and a primitive with more than [`MAX_SHARED_CORNERS`] at one position, or whose
//! pairs (Σ corners² per position) exceed [`PAIR_BUDGET_PER_CORNER`] × its corners +
//! [`PAIR_BUDGET_BASE`], keeps per-triangle tangents too. Ordinary meshes are far inside both
//! (about 6 pairs a corner; a UV sphere's pole of 256 segments is 65,536 pairs).
//!
//! Output: one tangent per vertex when every corner of a vertex got the same tangent (the common
//! case: 16 bytes a vertex, transformed once per vertex and instance), else one per corner
//! (MikkTSpace may split a vertex, e.g. where mirrored UVs meet).

use super::emit::generate_tangent;
use crate::math::det;
use bevy_mikktspace::{Geometry, Ops, TangentSpace};
use glam::{Vec2, Vec3, Vec4};
use std::collections::HashMap;
use std::rc::Rc;

/// Most triangles a primitive may have for MikkTSpace tangents (beyond: per-triangle tangents).
pub(crate) const MAX_TRIANGLES: usize = 2_000_000;
/// Most triangle corners at one position (the deepest recursion the crate may make).
pub(crate) const MAX_SHARED_CORNERS: u32 = 2048;
/// Pairs of corners at the same position allowed per corner of the primitive, …
pub(crate) const PAIR_BUDGET_PER_CORNER: u64 = 64;
/// … plus this many (a few high-valence vertices, such as the poles of a fine UV sphere).
pub(crate) const PAIR_BUDGET_BASE: u64 = 1 << 22;

/// `sqrt` and `acos` for `bevy_mikktspace` that give the same bits on every machine.
pub struct DetOps;

impl Ops for DetOps {
    #[inline]
    fn sqrt(x: f32) -> f32 {
        // IEEE 754 requires sqrt correctly rounded: the same bits everywhere, unlike acos.
        x.sqrt()
    }

    #[inline]
    fn acos(x: f32) -> f32 {
        det::acos(x)
    }
}

/// A primitive's tangents in its local space, bitangent sign in w.
#[derive(Debug)]
pub(crate) enum Tangents {
    /// One per vertex (a file's TANGENT, or MikkTSpace's where no vertex was split).
    Vertex(Rc<[Vec4]>),
    /// One per triangle corner, in the order of the primitive's triangles.
    Corner(Rc<[[Vec4; 3]]>),
}

/// MikkTSpace tangents of `triangles` (indices into the other slices, all checked by the loader),
/// or why they were not computed (a limit above; the caller then uses per-triangle tangents).
pub(crate) fn mikktspace(
    triangles: &[[u32; 3]],
    positions: &[Vec3],
    normals: Option<&[Vec3]>,
    uv: &[Vec2],
) -> Result<Tangents, String> {
    check_limits(triangles, positions)?;
    let mut input = Input {
        triangles,
        positions,
        normals,
        uv,
        out: vec![[None; 3]; triangles.len()],
    };
    // The crate's error type has no variants: it cannot fail.
    if let Err(e) = bevy_mikktspace::generate_tangents::<_, DetOps>(&mut input) {
        return Err(format!("MikkTSpace failed ({e})"));
    }
    let corners: Vec<[Vec4; 3]> = input
        .out
        .iter()
        .zip(triangles)
        .map(|(got, t)| {
            // A corner the crate left without a tangent (a degenerate triangle with no healthy
            // neighbour) or with a zero one: the triangle's own, as without MikkTSpace.
            let fallback = || {
                let p = t.map(|i| positions[i as usize]);
                generate_tangent(p, t.map(|i| uv[i as usize]))
            };
            got.map(|g| match g {
                Some(g) if g.truncate().length_squared() > 0.0 && g.is_finite() => g,
                _ => fallback(),
            })
        })
        .collect();
    Ok(per_vertex(triangles, positions.len(), &corners)
        .map_or_else(|| Tangents::Corner(corners.into()), Tangents::Vertex))
}

/// glTF v → the v' = 1 − v that MikkTSpace is fed.
fn flip_v(t: Vec2) -> Vec2 {
    Vec2::new(t.x, 1.0 - t.y)
}

fn check_limits(triangles: &[[u32; 3]], positions: &[Vec3]) -> Result<(), String> {
    if triangles.len() > MAX_TRIANGLES {
        return Err(format!(
            "{} triangles, over the {MAX_TRIANGLES} MikkTSpace tangents are computed for",
            triangles.len()
        ));
    }
    // The crate welds by value, so corners count by position bits (−0 and +0 apart, as its
    // total-order weld keeps them).
    let mut at: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    for &i in triangles.iter().flatten() {
        let p = positions[i as usize];
        let n = at.entry(p.to_array().map(f32::to_bits)).or_insert(0);
        *n += 1;
        if *n > MAX_SHARED_CORNERS {
            return Err(format!(
                "more than {MAX_SHARED_CORNERS} triangle corners at the point {p}, over what \
                 MikkTSpace tangents are computed for"
            ));
        }
    }
    let pairs: u64 = at.values().map(|&n| u64::from(n) * u64::from(n)).sum();
    let corners = 3 * triangles.len() as u64;
    let budget = PAIR_BUDGET_PER_CORNER * corners + PAIR_BUDGET_BASE;
    if pairs > budget {
        return Err(format!(
            "{pairs} pairs of triangle corners sharing a point, over the {budget} MikkTSpace \
             tangents are computed for"
        ));
    }
    Ok(())
}

/// One tangent per vertex if every corner of each vertex has the same bits (and every vertex has a
/// corner, as a compacted primitive's do).
fn per_vertex(triangles: &[[u32; 3]], n: usize, corners: &[[Vec4; 3]]) -> Option<Rc<[Vec4]>> {
    let mut vertex: Vec<Option<Vec4>> = vec![None; n];
    for (t, c) in triangles.iter().zip(corners) {
        for (&i, &tangent) in t.iter().zip(c) {
            let slot = &mut vertex[i as usize];
            match slot {
                None => *slot = Some(tangent),
                Some(s) if bits(*s) == bits(tangent) => {}
                Some(_) => return None,
            }
        }
    }
    vertex.into_iter().collect()
}

fn bits(v: Vec4) -> [u32; 4] {
    v.to_array().map(f32::to_bits)
}

/// The primitive as the crate reads it, and the tangents it writes back.
struct Input<'a> {
    triangles: &'a [[u32; 3]],
    positions: &'a [Vec3],
    normals: Option<&'a [Vec3]>,
    uv: &'a [Vec2],
    out: Vec<[Option<Vec4>; 3]>,
}

impl Input<'_> {
    fn vertex(&self, face: usize, vert: usize) -> usize {
        self.triangles[face][vert] as usize
    }
}

impl Geometry<DetOps> for Input<'_> {
    fn num_faces(&self) -> usize {
        self.triangles.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.vertex(face, vert)].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        let n = self.normals.map_or(Vec3::ZERO, |n| {
            n[self.vertex(face, vert)].normalize_or_zero()
        });
        if n != Vec3::ZERO {
            return n.to_array();
        }
        // No NORMAL (or a zero one): the face's, as the renderer shades it.
        let [a, b, c] = self.triangles[face].map(|i| self.positions[i as usize]);
        (b - a).cross(c - a).normalize_or_zero().to_array()
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        flip_v(self.uv[self.vertex(face, vert)]).to_array()
    }

    fn set_tangent(&mut self, tangent_space: Option<TangentSpace>, face: usize, vert: usize) {
        if let Some(slot) = self.out.get_mut(face).and_then(|f| f.get_mut(vert)) {
            *slot = tangent_space.map(|t| Vec4::from_array(t.tangent_encoded()));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit quad in the XY plane facing +Z, glTF UVs with the image's top at y = 1.
    fn quad(mirror_u: bool) -> (Vec<[u32; 3]>, Vec<Vec3>, Vec<Vec2>) {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let uv = p
            .iter()
            .map(|p| Vec2::new(if mirror_u { 1.0 - p.x } else { p.x }, 1.0 - p.y))
            .collect();
        (vec![[0, 1, 2], [0, 2, 3]], p, uv)
    }

    #[test]
    fn a_plane_gets_u_as_tangent_and_the_sign_of_its_mapping() {
        let (t, p, uv) = quad(false);
        let Ok(Tangents::Vertex(got)) = mikktspace(&t, &p, None, &uv) else {
            panic!("expected one tangent per vertex");
        };
        assert!(
            got.iter().all(|t| *t == Vec4::new(1.0, 0.0, 0.0, 1.0)),
            "{got:?}"
        );
        // u mirrored: the tangent follows u (−X) and the bitangent keeps pointing to image up,
        // so the sign flips.
        let (t, p, uv) = quad(true);
        let Ok(Tangents::Vertex(got)) = mikktspace(&t, &p, None, &uv) else {
            panic!("expected one tangent per vertex");
        };
        assert!(
            got.iter().all(|t| *t == Vec4::new(-1.0, 0.0, 0.0, -1.0)),
            "{got:?}"
        );
    }

    #[test]
    fn crafted_fans_are_refused_before_the_crate_recurses() {
        // A fan of MAX_SHARED_CORNERS triangles around the origin runs (on a test thread's stack,
        // in a debug build); one more corner is refused.
        let fan = |n: u32| {
            let mut p = vec![Vec3::ZERO];
            let mut uv = vec![Vec2::ZERO];
            let mut t = Vec::new();
            for i in 0..=n {
                let (s, c) = det::sin_cos(i as f32 / n as f32 * 6.0);
                p.push(Vec3::new(c, s, 0.0));
                uv.push(Vec2::new(c, s));
                if i > 0 {
                    t.push([0, i, i + 1]);
                }
            }
            (t, p, uv)
        };
        let (t, p, uv) = fan(MAX_SHARED_CORNERS);
        assert!(mikktspace(&t, &p, None, &uv).is_ok());
        let (t, p, uv) = fan(MAX_SHARED_CORNERS + 1);
        let e = mikktspace(&t, &p, None, &uv).expect_err("refused");
        assert!(e.contains("corners at the point"), "{e}");
        // Many points each shared by MAX_SHARED_CORNERS corners: within the limit per point, over
        // the budget of pairs.
        let k = 100u32;
        let mut p = Vec::new();
        let mut t = Vec::new();
        for j in 0..k {
            let base = p.len() as u32;
            p.extend([Vec3::new(j as f32, 0.0, 0.0), Vec3::new(j as f32, 1.0, 0.0)]);
            p.extend((0..MAX_SHARED_CORNERS).map(|i| Vec3::new(j as f32, i as f32, 1.0)));
            for i in 0..MAX_SHARED_CORNERS - 1 {
                t.push([base, base + 2 + i, base + 3 + i]);
            }
        }
        let uv = vec![Vec2::ZERO; p.len()];
        let e = mikktspace(&t, &p, None, &uv).expect_err("refused");
        assert!(e.contains("pairs of triangle corners"), "{e}");
    }
}
