//! The light triangles of a wavefront scene laid out for the lanes, so that choosing a light and a
//! point on it is one more vectorised loop rather than a search per lane.

use super::{DiffuseMaterial, LANES, V3};
use crate::light::{point_on, AreaLights};
use crate::sampling::sample_uniform_triangle;
use glam::{Vec2, Vec3};

/// The most light triangles the lanes choose from (a power of two: a lane's choice, masked by it,
/// is an index the compiler knows to be in bounds). Each lane counts the CDF values at or below
/// its sample, one comparison per light; scenes with more lights are sampled one lane at a time.
pub(crate) const MAX_LIGHTS: usize = 32;

/// `[axis][light]`.
type Xyz = [[f32; MAX_LIGHTS]; 3];

/// Every light triangle in structure-of-arrays form, in the order of the light distribution.
#[derive(Clone, Debug)]
pub(crate) struct LightTable {
    n: usize,
    /// The distribution's CDF without its leading 0: light j is chosen for u in
    /// [upper[j − 1], upper[j]).
    upper: [f32; MAX_LIGHTS],
    corners: [Xyz; 3],
    normal: Xyz,
    pdf_area: [f32; MAX_LIGHTS],
    /// The emission of the light's material towards its front and its back.
    front: Xyz,
    back: Xyz,
}

/// Every lane's light sample, as `AreaLights::sample` gives it.
pub(crate) struct LightSamples {
    pub point: V3,
    pub normal: V3,
    pub pdf_area: [f32; LANES],
    /// The emission of the light's material towards its front and its back.
    pub front: V3,
    pub back: V3,
}

impl LightTable {
    /// The table of `area`'s lights, if there are at most [`MAX_LIGHTS`], all of positive weight
    /// (so that the choice is the count of CDF values at or below u, as `Distribution1D` makes it).
    pub(crate) fn new(
        area: &AreaLights,
        materials: &[DiffuseMaterial],
        mesh_material: &[u32],
    ) -> Option<Box<LightTable>> {
        let d = area.distribution();
        let n = d.len();
        if n == 0 || n > MAX_LIGHTS || d.weights().iter().any(|&w| w <= 0.0) {
            return None;
        }
        let mut t = Box::new(LightTable {
            n,
            upper: [0.0; MAX_LIGHTS],
            corners: [[[0.0; MAX_LIGHTS]; 3]; 3],
            normal: [[0.0; MAX_LIGHTS]; 3],
            pdf_area: [0.0; MAX_LIGHTS],
            front: [[0.0; MAX_LIGHTS]; 3],
            back: [[0.0; MAX_LIGHTS]; 3],
        });
        t.upper[..n].copy_from_slice(&d.cdf()[1..]);
        let set = |xyz: &mut Xyz, j: usize, v: Vec3| {
            for (axis, value) in v.to_array().into_iter().enumerate() {
                xyz[axis][j] = value;
            }
        };
        for (j, (corners, normal, pdf_area, tri)) in area.sampled().enumerate() {
            for (c, corner) in corners.into_iter().enumerate() {
                set(&mut t.corners[c], j, corner);
            }
            set(&mut t.normal, j, normal);
            t.pdf_area[j] = pdf_area;
            let m = materials.get(*mesh_material.get(tri as usize)? as usize)?;
            set(&mut t.front, j, m.emission_front);
            set(&mut t.back, j, m.emission_back);
        }
        Some(t)
    }

    /// `AreaLights::sample(u_select[i], (u0[i], u1[i]))` for every lane i, the same bits: the
    /// light whose CDF interval holds u, a uniform point on it, its normal and area density, and
    /// its material's emission.
    #[inline(always)]
    pub(crate) fn sample(&self, u_select: &[f32; LANES], u: &[[f32; LANES]; 2]) -> LightSamples {
        let mut k = [0u32; LANES];
        for &c in &self.upper[..self.n.min(MAX_LIGHTS)] {
            for i in 0..LANES {
                k[i] += u32::from(c <= u_select[i]);
            }
        }
        let last = self.n.saturating_sub(1) as u32;
        let get = |xyz: &Xyz, j: usize| Vec3::new(xyz[0][j], xyz[1][j], xyz[2][j]);
        let mut out = LightSamples {
            point: V3::ZERO,
            normal: V3::ZERO,
            pdf_area: [0.0; LANES],
            front: V3::ZERO,
            back: V3::ZERO,
        };
        // The table's entries first, one lane at a time (AVX2 has no fast gather, and the
        // compiler would not vectorise a loop holding one), then the point, in the lanes.
        let mut corners = [V3::ZERO; 3];
        for (i, &ki) in k.iter().enumerate() {
            let j = ki.min(last) as usize & (MAX_LIGHTS - 1);
            for (c, corner) in corners.iter_mut().enumerate() {
                corner.set(i, get(&self.corners[c], j));
            }
            out.normal.set(i, get(&self.normal, j));
            out.pdf_area[i] = self.pdf_area[j];
            out.front.set(i, get(&self.front, j));
            out.back.set(i, get(&self.back, j));
        }
        for (i, (&u0, &u1)) in u[0].iter().zip(&u[1]).enumerate() {
            let bary = sample_uniform_triangle(Vec2::new(u0, u1));
            let at = [corners[0].get(i), corners[1].get(i), corners[2].get(i)];
            out.point.set(i, point_on(at, bary));
        }
        out
    }
}
