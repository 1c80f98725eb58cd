//! Helpers shared by the crate's unit tests.

use crate::geometry::Mesh;
use glam::Vec3;

/// A deterministic stream of uniform values in [0, 1) (xorshift64, top 24 bits): reproducible
/// random cases without a dependency, the same on every run.
pub(crate) fn uniform_stream(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// `count` small triangles (corners within ±0.5 of the first), each first corner drawn by `corner`,
/// every `duplicate_every`-th one added twice so that hits tie: a random soup for BVH tests.
pub(crate) fn triangle_soup(
    rng: &mut impl FnMut() -> f32,
    count: usize,
    duplicate_every: usize,
    mut corner: impl FnMut(&mut dyn FnMut() -> f32) -> Vec3,
) -> Mesh {
    let mut mesh = Mesh::default();
    for k in 0..count {
        let a = corner(rng);
        let b = a + Vec3::new(rng(), rng(), rng()) - 0.5;
        let c = a + Vec3::new(rng(), rng(), rng()) - 0.5;
        mesh.positions.push([a, b, c]);
        mesh.material.push(0);
        if k % duplicate_every == 0 {
            mesh.positions.push([a, b, c]);
            mesh.material.push(0);
        }
    }
    mesh
}

/// A [`triangle_soup`] whose first corners are drawn from `vertices` random points in ±5 (drawn
/// first from `rng`): many triangles share a corner, as a mesh's do.
pub(crate) fn shared_corner_soup(
    rng: &mut impl FnMut() -> f32,
    vertices: usize,
    count: usize,
    duplicate_every: usize,
) -> Mesh {
    let verts: Vec<Vec3> = (0..vertices)
        .map(|_| Vec3::new(rng(), rng(), rng()) * 10.0 - 5.0)
        .collect();
    triangle_soup(rng, count, duplicate_every, |rng| {
        let i = |r: f32| ((r * verts.len() as f32) as usize).min(verts.len() - 1);
        verts[i(rng())]
    })
}
