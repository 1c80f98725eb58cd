//! Area lights: the scene's emissive triangles, each sampled uniformly over its area (pdf 1/A,
//! converted to solid angle with cos θ' / r²). Which triangle is chosen depends on how many there
//! are ([`AreaLights::uses_tree`], the one place that decides): a few are chosen in proportion to
//! their power alone, the same choice at every point (a table the wavefront integrator holds in
//! its lanes); more are chosen by a [`LightTree`], in proportion to what each may send to the
//! shading point.

use crate::geometry::Mesh;
use crate::material::{Material, Texture};
use crate::math::luminance;
use crate::sampling::{sample_uniform_triangle, Distribution1D};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

use super::tree::{LightBounds, LightTree};

/// The most lights of a family (emissive triangles; point and spot lamps) chosen by power alone;
/// scenes with more choose by a [`LightTree`] ([`super::chooses_by_tree`]).
/// With a few lights the tree's per-point choice gains little (a Cornell box's light is two
/// triangles of one quad) and costs a walk per sample; with many, lights that face away or lie far
/// off take most power-chosen samples (docs/benchmarks.md, "A light tree"). The wavefront
/// integrator's light table holds exactly these scenes' lights.
pub const MAX_POWER_CHOSEN: usize = 32;

/// The point of a triangle with corners `c` at barycentrics `b` (one per corner).
#[inline(always)]
pub(crate) fn point_on(c: [Vec3; 3], b: Vec3) -> Vec3 {
    c[0] * b.x + c[1] * b.y + c[2] * b.z
}

/// A point sampled on an area light.
#[derive(Clone, Copy, Debug)]
pub struct AreaLightSample {
    pub point: Vec3,
    /// Unit geometric normal of the light triangle (front side = counter-clockwise).
    pub normal: Vec3,
    /// Mesh triangle index.
    pub triangle: u32,
    pub barycentrics: Vec3,
    /// Probability (area measure) of having sampled this point: P(triangle) / area.
    pub pdf_area: f32,
}

/// One emissive triangle as light sampling sees it: corners, unit normal and the area-measure pdf
/// of its points, P(triangle) / area, all fixed by the scene.
#[derive(Clone, Copy, Debug)]
struct LightTriangle {
    corners: [Vec3; 3],
    normal: Vec3,
    pdf_area: f32,
    /// 1 / area: the tree's choice probability times this is the area density.
    inv_area: f32,
}

/// Every emissive triangle of the scene.
///
/// The lights are listed in an order of their own, by their corners' bits, not in the mesh's
/// triangle order: that order is the BVH builder's, and a scene must choose the same light from the
/// same random number however its geometry is stored (instanced or flattened, whichever builder).
#[derive(Clone, Debug, Default)]
pub struct AreaLights {
    /// Mesh triangle indices of the emissive triangles, in the lights' order.
    pub triangles: Vec<u32>,
    /// (mesh triangle, light index) for every light, sorted by mesh triangle: finds the light a
    /// BSDF ray hit.
    by_triangle: Vec<(u32, u32)>,
    /// Per emissive triangle, what sampling a point on it needs, copied out of the mesh once.
    sampled: Vec<LightTriangle>,
    distribution: Distribution1D,
    /// Per material: P(triangle) / area(triangle) for its triangles, which is the same for every
    /// triangle of a material because power ∝ average radiance × area. Lets a BSDF ray that hits an
    /// emitter find the light-sampling pdf without a per-triangle table. (Without a tree.)
    material_area_density: Vec<f32>,
    /// The light tree, over `sampled` in its order, for scenes of more than [`MAX_POWER_CHOSEN`]
    /// lights.
    tree: Option<LightTree>,
}

impl AreaLights {
    /// Collects the emissive triangles of `mesh` and their power.
    pub fn new(mesh: &Mesh, materials: &[Material], textures: &[Texture]) -> Self {
        let radiance: Vec<f32> = materials
            .iter()
            .map(|m| {
                luminance(m.average_emission(textures)) * if m.double_sided { 2.0 } else { 1.0 }
            })
            .collect();
        let mut triangles: Vec<u32> = (0..mesh.material.len() as u32)
            .filter(|&i| {
                let m = mesh.material[i as usize];
                radiance.get(m as usize).copied().unwrap_or(0.0) > 0.0
                    && mesh.area(i as usize) > 0.0
            })
            .collect();
        triangles.sort_by_key(|&i| light_order_key(mesh, i));
        let powers: Vec<f32> = triangles
            .iter()
            .map(|&i| {
                let le = radiance[mesh.material[i as usize] as usize];
                le * mesh.area(i as usize) * PI
            })
            .collect();
        let mut by_triangle: Vec<(u32, u32)> = triangles
            .iter()
            .enumerate()
            .map(|(k, &tri)| (tri, k as u32))
            .collect();
        by_triangle.sort_unstable();
        let distribution = Distribution1D::new(&powers);
        let total = distribution.total();
        let sampled: Vec<LightTriangle> = triangles
            .iter()
            .enumerate()
            .map(|(k, &tri)| {
                let [a, b, c] = mesh.positions[tri as usize];
                let cross = (b - a).cross(c - a);
                let len = cross.length();
                LightTriangle {
                    corners: [a, b, c],
                    normal: cross / len,
                    pdf_area: distribution.pmf(k) / (0.5 * len),
                    inv_area: 1.0 / (0.5 * len),
                }
            })
            .collect();
        let tree = Self::uses_tree(sampled.len()).then(|| {
            let bounds: Vec<LightBounds> = sampled
                .iter()
                .zip(&triangles)
                .enumerate()
                .map(|(k, (t, &tri))| {
                    let two_sided = materials
                        .get(mesh.material[tri as usize] as usize)
                        .is_some_and(|m| m.double_sided);
                    let phi = (distribution.weights()[k] as f64 / total) as f32;
                    LightBounds::triangle(t.corners, t.normal, phi, two_sided)
                })
                .collect();
            LightTree::new(&bounds)
        });
        let material_area_density = radiance
            .iter()
            .map(|&le| {
                if total > 0.0 {
                    (le as f64 * PI as f64 / total) as f32
                } else {
                    0.0
                }
            })
            .collect();
        AreaLights {
            triangles,
            by_triangle,
            sampled,
            distribution,
            material_area_density,
            tree,
        }
    }

    /// Whether a scene with `lights` emissive triangles chooses them by a light tree (rather than
    /// by power alone): the one place that decides, from the count alone.
    pub fn uses_tree(lights: usize) -> bool {
        super::chooses_by_tree(lights)
    }

    /// Whether these lights are chosen by a light tree.
    pub fn has_tree(&self) -> bool {
        self.tree.is_some()
    }

    /// Chooses these lights by power alone even where [`AreaLights::uses_tree`] says otherwise:
    /// the same expected image, for tests and benchmarks that compare the two choices.
    pub fn choose_by_power(&mut self) {
        self.tree = None;
    }

    pub fn is_empty(&self) -> bool {
        self.distribution.is_empty()
    }

    /// Total emitted power (the selection weights' sum).
    pub fn total_power(&self) -> f64 {
        self.distribution.total()
    }

    /// Chooses a triangle for a shading point `p` with unit normal `n` (`u_select`: by power, or
    /// by the tree) and a uniform point on it (`u`). None when no light can reach `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, n: Vec3, u_select: f32, u: Vec2) -> Option<AreaLightSample> {
        if self.is_empty() {
            return None;
        }
        let (k, pdf_area) = match &self.tree {
            Some(tree) => {
                let (k, pmf) = tree.sample(p, n, u_select)?;
                (k, pmf * self.sampled[k].inv_area)
            }
            None => {
                let (k, _) = self.distribution.sample_discrete(u_select);
                (k, self.sampled[k].pdf_area)
            }
        };
        let t = &self.sampled[k];
        let bary = sample_uniform_triangle(u);
        Some(AreaLightSample {
            point: point_on(t.corners, bary),
            normal: t.normal,
            triangle: self.triangles[k],
            barycentrics: bary,
            pdf_area,
        })
    }

    /// The area-measure density with which [`AreaLights::sample`], at a point `p` with normal `n`,
    /// picks the point of mesh triangle `triangle` (of material `material`) that a ray from `p`
    /// hit: what that ray's MIS weight needs.
    #[inline]
    pub fn pdf(&self, p: Vec3, n: Vec3, triangle: u32, material: u32) -> f32 {
        match &self.tree {
            Some(tree) => match self
                .by_triangle
                .binary_search_by_key(&triangle, |&(tri, _)| tri)
            {
                Ok(i) => {
                    let k = self.by_triangle[i].1 as usize;
                    tree.pmf(p, n, k) * self.sampled[k].inv_area
                }
                Err(_) => 0.0,
            },
            None => self.power_density(material),
        }
    }

    /// Every light triangle as [`AreaLights::sample`] sees it, in the order of its distribution:
    /// (corners, unit normal, area density of the sample, triangle index in the mesh).
    pub(crate) fn sampled(&self) -> impl Iterator<Item = ([Vec3; 3], Vec3, f32, u32)> + '_ {
        self.sampled
            .iter()
            .zip(&self.triangles)
            .map(|(t, &tri)| (t.corners, t.normal, t.pdf_area, tri))
    }

    /// The distribution light triangles are chosen from (in proportion to power).
    pub(crate) fn distribution(&self) -> &Distribution1D {
        &self.distribution
    }

    /// Without a tree: the area-measure pdf with which [`AreaLights::sample`] picks a point on a
    /// triangle of material `material`, the same at every shading point.
    #[inline]
    pub fn power_density(&self, material: u32) -> f32 {
        debug_assert!(self.tree.is_none());
        self.material_area_density
            .get(material as usize)
            .copied()
            .unwrap_or(0.0)
    }
}

/// The key that orders the lights: the bits of a triangle's corners, then its material, which
/// are the same however the scene's geometry is stored. Triangles with equal keys are the same
/// light and keep the mesh's order between them.
fn light_order_key(mesh: &Mesh, triangle: u32) -> ([u32; 9], u32) {
    let c = mesh.positions[triangle as usize];
    let mut bits = [0u32; 9];
    for (k, v) in c.iter().flat_map(|v| v.to_array()).enumerate() {
        bits[k] = v.to_bits();
    }
    (bits, mesh.material[triangle as usize])
}
