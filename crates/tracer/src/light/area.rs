//! Area lights: the scene's emissive triangles. A point on the chosen triangle is sampled
//! uniformly over its area (pdf 1/A, converted to solid angle with cos θ' / r²), or, where the
//! shading point is close to the triangle against its size, uniformly over the solid angle it
//! subtends ([`by_solid_angle`], the one place that decides). Which triangle is chosen depends on
//! how many there are ([`AreaLights::uses_tree`], the one place that decides): a few are chosen in
//! proportion to their power alone, the same choice at every point (a table the wavefront
//! integrator holds in its lanes); more are chosen by a [`LightTree`], in proportion to what each
//! may send to the shading point.

use crate::geometry::Mesh;
use crate::material::{Material, Texture};
use crate::math::luminance;
use crate::sampling::{
    barycentrics_along_unchecked, sample_uniform_triangle, Distribution1D, SphericalTriangle,
};
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

/// The smallest and largest solid angle, in steradians, that a triangle is sampled by
/// ([`by_solid_angle`]): pbrt-v4's bounds (`MinSphericalSampleArea`, `MaxSphericalSampleArea`),
/// outside which the spherical map loses precision in single precision. Below the first, a light
/// looks small enough that sampling it by area is as good.
const SOLID_ANGLE_RANGE: std::ops::RangeInclusive<f32> = 3e-4..=6.22;

/// A light triangle is sampled by solid angle from points closer to its plane than its longest
/// edge over this ratio. Cycles uses 1; on the peer scenes whose lamp panel hangs 2 cm under the
/// ceiling, 4 kept all of the variance gain at less cost (Cornell −15 % samples/s against −22 %;
/// docs/benchmarks.md, December 6): the gain is where the distances across the triangle differ by
/// a large factor (here at least 17 in r²), the cost wherever the test lets the spherical map in.
const NEAR_RATIO: f32 = 4.0;

/// Whether a light triangle is sampled by the solid angle it subtends from the shading point `p`,
/// rather than by area: the one place that decides, from the triangle and the point alone, so that
/// the light sample and a BSDF ray that hits the light weigh it with the same density. Returns the
/// spherical triangle to sample when so.
///
/// Cycles' kind of test: `p` lies close to the triangle's plane against the triangle's size
/// ([`near_plane`]; farther off, the distances across the triangle differ little and sampling by
/// area is as good and cheaper), and the solid angle lies in [`SOLID_ANGLE_RANGE`].
#[inline(always)]
pub(crate) fn by_solid_angle(
    corners: [Vec3; 3],
    normal: Vec3,
    longest_edge2: f32,
    p: Vec3,
) -> Option<SphericalTriangle> {
    if !near_plane(corners[0], normal, longest_edge2, p) {
        return None;
    }
    let (s, valid) = SphericalTriangle::subtended(corners, p);
    in_range(&s, valid).then_some(s)
}

/// The first half of [`by_solid_angle`]'s test, the cheap one: `p` lies closer to the plane of
/// the triangle (through `corner`, unit normal `normal`) than its longest edge over
/// [`NEAR_RATIO`]. Lanes code asks it first and skips the spherical map when no lane passes.
#[inline(always)]
pub(crate) fn near_plane(corner: Vec3, normal: Vec3, longest_edge2: f32, p: Vec3) -> bool {
    let h = normal.dot(p - corner);
    h * h * (NEAR_RATIO * NEAR_RATIO) < longest_edge2
}

/// The second half of [`by_solid_angle`]'s test: `s` is a spherical triangle (`valid`) and its
/// solid angle lies in [`SOLID_ANGLE_RANGE`].
#[inline(always)]
fn in_range(s: &SphericalTriangle, valid: bool) -> bool {
    valid & SOLID_ANGLE_RANGE.contains(&s.solid_angle())
}

/// A point on the light triangle `corners` (unit normal `normal`, chosen with probability `pmf`)
/// sampled uniformly in the solid angle `s` it subtends from `p`, drawn from `u`: the point, its
/// barycentrics, its density in area measure, pmf · cos θ' / (r² Ω) (which the integrator's
/// conversion r² / cos θ' takes back to pmf / Ω), and whether they are valid (false where rounding
/// leaves no valid point). Without a branch, so that the lanes run it side by side.
#[inline(always)]
fn sample_by_solid_angle(
    s: &SphericalTriangle,
    corners: [Vec3; 3],
    normal: Vec3,
    pmf: f32,
    p: Vec3,
    u: Vec2,
) -> (Vec3, Vec3, f32, bool) {
    let (bary, hits) = barycentrics_along_unchecked(corners, p, s.sample(u));
    let point = point_on(corners, bary);
    let d = point - p;
    let dist2 = d.length_squared();
    let pdf_area = solid_angle_area_density(s, pmf, d.dot(normal).abs() / dist2.sqrt(), dist2);
    let valid = hits & (pdf_area > 0.0) & pdf_area.is_finite();
    (point, bary, pdf_area, valid)
}

/// [`by_solid_angle`] and then [`sample_by_solid_angle`] with no branch, the same bits, for the
/// lanes to run side by side: whether the triangle is sampled by solid angle from `p`, and if so
/// the point and its area density (0 where the sampler would give none).
#[inline(always)]
pub(crate) fn solid_angle_sample_lane(
    corners: [Vec3; 3],
    normal: Vec3,
    longest_edge2: f32,
    pmf: f32,
    p: Vec3,
    u: Vec2,
) -> (bool, Vec3, f32) {
    let near = near_plane(corners[0], normal, longest_edge2, p);
    let (s, valid) = SphericalTriangle::subtended(corners, p);
    let (point, _, pdf_area, sampled) = sample_by_solid_angle(&s, corners, normal, pmf, p, u);
    let pdf_area = if sampled { pdf_area } else { 0.0 };
    (near & in_range(&s, valid), point, pdf_area)
}

/// The area density pmf · cos θ' / (r² Ω) of a point at squared distance `dist2` and cosine `cos_l`
/// on a triangle sampled by solid angle (`s`) and chosen with probability `pmf`.
#[inline(always)]
fn solid_angle_area_density(s: &SphericalTriangle, pmf: f32, cos_l: f32, dist2: f32) -> f32 {
    pmf * cos_l / (dist2 * s.solid_angle())
}

/// One emissive triangle as light sampling sees it, all fixed by the scene.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LightTriangle {
    pub corners: [Vec3; 3],
    /// The unit normal (front side = counter-clockwise).
    pub normal: Vec3,
    /// The area-measure pdf of its points when chosen by power: P(triangle) / area.
    pub pdf_area: f32,
    /// P(triangle) when chosen by power.
    pub pmf: f32,
    /// 1 / area: the tree's choice probability times this is the area density.
    pub inv_area: f32,
    /// The square of its longest edge's length (for [`by_solid_angle`]).
    pub longest_edge2: f32,
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
                    pmf: distribution.pmf(k),
                    inv_area: 1.0 / (0.5 * len),
                    longest_edge2: [b - a, c - b, a - c]
                        .map(Vec3::length_squared)
                        .into_iter()
                        .fold(0.0, f32::max),
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
    /// by the tree) and a point on it (`u`): uniform in area, or in the solid angle the triangle
    /// subtends where [`by_solid_angle`] says so. None when no light can reach `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, n: Vec3, u_select: f32, u: Vec2) -> Option<AreaLightSample> {
        if self.is_empty() {
            return None;
        }
        let (k, pmf) = match &self.tree {
            Some(tree) => tree.sample(p, n, u_select)?,
            None => {
                let (k, _) = self.distribution.sample_discrete(u_select);
                (k, self.sampled[k].pmf)
            }
        };
        self.sample_chosen(k, pmf, p, u)
    }

    /// [`AreaLights::sample`] at `M` points, the same answers, their lights chosen by the tree's
    /// walks side by side ([`LightTree::sample_many`]).
    #[inline]
    pub fn sample_many<const M: usize>(
        &self,
        queries: [(Vec3, Vec3, f32, Vec2); M],
    ) -> [Option<AreaLightSample>; M] {
        let Some(tree) = &self.tree else {
            return queries.map(|(p, n, u_select, u)| self.sample(p, n, u_select, u));
        };
        let chosen = tree.sample_many(queries.map(|(p, n, u_select, _)| (p, n, u_select)));
        std::array::from_fn(|w| {
            let (p, _, _, u) = queries[w];
            chosen[w].and_then(|(k, pmf)| self.sample_chosen(k, pmf, p, u))
        })
    }

    /// A point on sampled light `k`, chosen with probability `pmf`, for the point `p` (see
    /// [`AreaLights::sample`]).
    #[inline(always)]
    fn sample_chosen(&self, k: usize, pmf: f32, p: Vec3, u: Vec2) -> Option<AreaLightSample> {
        let t = &self.sampled[k];
        let triangle = self.triangles[k];
        if let Some(s) = by_solid_angle(t.corners, t.normal, t.longest_edge2, p) {
            let (point, barycentrics, pdf_area, valid) =
                sample_by_solid_angle(&s, t.corners, t.normal, pmf, p, u);
            return valid.then_some(AreaLightSample {
                point,
                normal: t.normal,
                triangle,
                barycentrics,
                pdf_area,
            });
        }
        let pdf_area = match &self.tree {
            Some(_) => pmf * t.inv_area,
            None => t.pdf_area,
        };
        let bary = sample_uniform_triangle(u);
        Some(AreaLightSample {
            point: point_on(t.corners, bary),
            normal: t.normal,
            triangle,
            barycentrics: bary,
            pdf_area,
        })
    }

    /// The area-measure density with which [`AreaLights::sample`], at a point `p` with normal `n`,
    /// picks the point of mesh triangle `triangle` (of material `material`) that a ray from `p`
    /// hit at distance `t`, meeting it at cosine `cos_l`: what that ray's MIS weight needs.
    #[inline]
    pub fn pdf(&self, p: Vec3, n: Vec3, triangle: u32, material: u32, t: f32, cos_l: f32) -> f32 {
        let Ok(i) = self
            .by_triangle
            .binary_search_by_key(&triangle, |&(tri, _)| tri)
        else {
            return 0.0;
        };
        let k = self.by_triangle[i].1 as usize;
        let light = &self.sampled[k];
        let by_solid_angle = by_solid_angle(light.corners, light.normal, light.longest_edge2, p);
        match (&self.tree, by_solid_angle) {
            (Some(tree), Some(s)) => solid_angle_area_density(&s, tree.pmf(p, n, k), cos_l, t * t),
            (Some(tree), None) => tree.pmf(p, n, k) * light.inv_area,
            (None, Some(s)) => solid_angle_area_density(&s, light.pmf, cos_l, t * t),
            (None, None) => self.power_density(material),
        }
    }

    /// Every light triangle as [`AreaLights::sample`] sees it, in the order of its distribution,
    /// with its triangle index in the mesh.
    pub(crate) fn sampled(&self) -> impl Iterator<Item = (&LightTriangle, u32)> + '_ {
        self.sampled.iter().zip(self.triangles.iter().copied())
    }

    /// Light `i` of [`AreaLights::sampled`], with its triangle index in the mesh.
    pub(crate) fn sampled_light(&self, i: usize) -> Option<(&LightTriangle, u32)> {
        Some((self.sampled.get(i)?, *self.triangles.get(i)?))
    }

    /// The distribution light triangles are chosen from (in proportion to power).
    pub(crate) fn distribution(&self) -> &Distribution1D {
        &self.distribution
    }

    /// Without a tree: the area-measure pdf with which [`AreaLights::sample`] picks a point on a
    /// triangle of material `material` where it samples by area, the same at every such point.
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
