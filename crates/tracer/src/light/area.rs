//! Area lights: the scene's emissive triangles, chosen in proportion to their power and sampled
//! uniformly over their area (pdf 1/A), converted to solid angle with cos θ' / r².

use crate::geometry::Mesh;
use crate::material::{Material, Texture};
use crate::math::luminance;
use crate::sampling::{sample_uniform_triangle, Distribution1D};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

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

/// Every emissive triangle of the scene.
#[derive(Clone, Debug, Default)]
pub struct AreaLights {
    /// Mesh triangle indices of the emissive triangles.
    pub triangles: Vec<u32>,
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
    pub fn sample(&self, mesh: &Mesh, u_select: f32, u: Vec2) -> Option<AreaLightSample> {
        if self.is_empty() {
            return None;
        }
        let (k, pmf, _) = self.distribution.sample(u_select);
        let tri = self.triangles[k];
        let [a, b, c] = mesh.positions[tri as usize];
        let bary = sample_uniform_triangle(u);
        let point = a * bary.x + b * bary.y + c * bary.z;
        let cross = (b - a).cross(c - a);
        let len = cross.length();
        if len <= 0.0 {
            return None;
        }
        Some(AreaLightSample {
            point,
            normal: cross / len,
            triangle: tri,
            barycentrics: bary,
            pdf_area: pmf / (0.5 * len),
        })
    }

    /// The area-measure pdf with which [`AreaLights::sample`] picks a point on a triangle of
    /// material `material`.
    #[inline]
    pub fn pdf_area(&self, material: u32) -> f32 {
        self.material_area_density
            .get(material as usize)
            .copied()
            .unwrap_or(0.0)
    }
}
