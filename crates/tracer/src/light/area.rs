//! Area lights: the scene's emissive triangles, chosen in proportion to their power and sampled
//! uniformly over their area (pdf 1/A), converted to solid angle with cos θ' / r².

use crate::geometry::Mesh;
use crate::material::{Material, Texture};
use crate::math::luminance;
use crate::sampling::{sample_uniform_triangle, Distribution1D};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

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
}

/// Every emissive triangle of the scene.
#[derive(Clone, Debug, Default)]
pub struct AreaLights {
    /// Mesh triangle indices of the emissive triangles.
    pub triangles: Vec<u32>,
    /// Per emissive triangle, what sampling a point on it needs, copied out of the mesh once.
    sampled: Vec<LightTriangle>,
    distribution: Distribution1D,
    /// Per material: P(triangle) / area(triangle) for its triangles, which is the same for every
    /// triangle of a material because power ∝ average radiance × area. Lets a BSDF ray that hits an
    /// emitter find the light-sampling pdf without a per-triangle table.
    material_area_density: Vec<f32>,
}

impl AreaLights {
    /// Collects the emissive triangles of `mesh` (after any reordering) and their power.
    pub fn new(mesh: &Mesh, materials: &[Material], textures: &[Texture]) -> Self {
        let radiance: Vec<f32> = materials
            .iter()
            .map(|m| {
                luminance(m.average_emission(textures)) * if m.double_sided { 2.0 } else { 1.0 }
            })
            .collect();
        let mut triangles = Vec::new();
        let mut powers = Vec::new();
        for (i, &m) in mesh.material.iter().enumerate() {
            let le = radiance.get(m as usize).copied().unwrap_or(0.0);
            if le > 0.0 {
                let area = mesh.area(i);
                if area > 0.0 {
                    triangles.push(i as u32);
                    powers.push(le * area * PI);
                }
            }
        }
        let distribution = Distribution1D::new(&powers);
        let total = distribution.total();
        let sampled = triangles
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
                }
            })
            .collect();
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
            sampled,
            distribution,
            material_area_density,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.distribution.is_empty()
    }

    /// Total emitted power (the selection weights' sum).
    pub fn total_power(&self) -> f64 {
        self.distribution.total()
    }

    /// Chooses a triangle by power (`u_select`) and a uniform point on it (`u`).
    #[inline]
    pub fn sample(&self, u_select: f32, u: Vec2) -> Option<AreaLightSample> {
        if self.is_empty() {
            return None;
        }
        let (k, _) = self.distribution.sample_discrete(u_select);
        let t = &self.sampled[k];
        let bary = sample_uniform_triangle(u);
        Some(AreaLightSample {
            point: point_on(t.corners, bary),
            normal: t.normal,
            triangle: self.triangles[k],
            barycentrics: bary,
            pdf_area: t.pdf_area,
        })
    }

    /// The area-measure pdf with which [`AreaLights::sample`] picks a point on a triangle of
    /// material `material`.
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

    #[inline]
    pub fn pdf_area(&self, material: u32) -> f32 {
        self.material_area_density
            .get(material as usize)
            .copied()
            .unwrap_or(0.0)
    }
}
