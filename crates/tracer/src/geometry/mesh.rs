use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;

/// The scene's triangles, flattened to world space, one entry per triangle (structure of arrays).
///
/// Only what the scene uses is stored: a scene without normals, texture coordinates or tangents has
/// `None` for them and pays no memory per triangle for them.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Corner positions in world space, in counter-clockwise (front-face) order: the loader swaps two
    /// corners of triangles whose node transform has a negative determinant.
    pub positions: Vec<[Vec3; 3]>,
    /// Index into `Scene::materials`.
    pub material: Vec<u32>,
    /// World-space vertex normals (unnormalized interpolation is normalized at the hit).
    pub normals: Option<Vec<[Vec3; 3]>>,
    pub uv0: Option<Vec<[Vec2; 3]>>,
    pub uv1: Option<Vec<[Vec2; 3]>>,
    /// World-space tangents (xyz) with the bitangent sign in w.
    pub tangents: Option<Vec<[Vec4; 3]>>,
}

/// A mesh whose attribute arrays disagree in length.
#[derive(Debug, thiserror::Error)]
#[error("mesh attribute {attribute} has {got} entries for {triangles} triangles")]
pub struct MeshError {
    pub attribute: &'static str,
    pub got: usize,
    pub triangles: usize,
}

/// True if a triangle with these corners has a positive, finite area and finite corners. Others
/// (zero-area, NaN or infinite) cannot be hit, sampled or shaded; loaders drop them as they read
/// them, and [`crate::scene::Scene::build`] drops any that are left.
#[inline]
pub fn renderable(p: &[Vec3; 3]) -> bool {
    let [a, b, c] = *p;
    let area = 0.5 * (b - a).cross(c - a).length();
    area > 0.0 && area.is_finite() && p.iter().all(|v| v.is_finite())
}

impl Mesh {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks that every present attribute has one entry per triangle.
    pub fn validate(&self) -> Result<(), MeshError> {
        let n = self.positions.len();
        let check = |attribute: &'static str, got: Option<usize>| match got {
            Some(got) if got != n => Err(MeshError {
                attribute,
                got,
                triangles: n,
            }),
            _ => Ok(()),
        };
        check("material", Some(self.material.len()))?;
        check("normals", self.normals.as_ref().map(Vec::len))?;
        check("uv0", self.uv0.as_ref().map(Vec::len))?;
        check("uv1", self.uv1.as_ref().map(Vec::len))?;
        check("tangents", self.tangents.as_ref().map(Vec::len))?;
        Ok(())
    }

    /// Twice the area vector of triangle `i` (e1 × e2, pointing to the front side).
    #[inline]
    pub fn cross(&self, i: usize) -> Vec3 {
        let [a, b, c] = self.positions[i];
        (b - a).cross(c - a)
    }

    #[inline]
    pub fn area(&self, i: usize) -> f32 {
        0.5 * self.cross(i).length()
    }

    /// True if triangle `i` can be hit, sampled and shaded: see [`renderable`].
    #[inline]
    pub fn is_renderable(&self, i: usize) -> bool {
        renderable(&self.positions[i])
    }

    /// Rebuilds every array in a new order (`order[k]` is the old index of new triangle k); triangles
    /// not named in `order` are dropped.
    pub fn reorder(&mut self, order: &[u32]) {
        // In parallel: a gather of ten million triangles' attributes is most of a second alone.
        fn pick<T: Copy + Send + Sync>(v: &[T], order: &[u32]) -> Vec<T> {
            order.par_iter().map(|&i| v[i as usize]).collect()
        }
        self.positions = pick(&self.positions, order);
        self.material = pick(&self.material, order);
        if let Some(n) = &self.normals {
            self.normals = Some(pick(n, order));
        }
        if let Some(t) = &self.uv0 {
            self.uv0 = Some(pick(t, order));
        }
        if let Some(t) = &self.uv1 {
            self.uv1 = Some(pick(t, order));
        }
        if let Some(t) = &self.tangents {
            self.tangents = Some(pick(t, order));
        }
    }

    /// The box of every corner (lower, upper); inverted (+∞, −∞) for an empty mesh. In parallel
    /// (min and max: the same in any order).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let empty = || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        self.positions
            .par_iter()
            .fold(empty, |(lo, hi), t| {
                (
                    lo.min(t[0]).min(t[1]).min(t[2]),
                    hi.max(t[0]).max(t[1]).max(t[2]),
                )
            })
            .reduce(empty, |(a, b), (c, d)| (a.min(c), b.max(d)))
    }

    /// Approximate bytes per triangle, for memory reports.
    pub fn bytes(&self) -> usize {
        let n = self.len();
        n * (36 + 4)
            + self.normals.as_ref().map_or(0, |_| n * 36)
            + self.uv0.as_ref().map_or(0, |_| n * 24)
            + self.uv1.as_ref().map_or(0, |_| n * 24)
            + self.tangents.as_ref().map_or(0, |_| n * 48)
    }
}
