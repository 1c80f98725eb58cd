//! The light triangles of a wavefront scene laid out for the lanes, so that choosing a light and a
//! point on it is one more vectorised loop rather than a search per lane.

use super::{DiffuseMaterial, LANES, V3};
use crate::isa::{Isa, Kind};
use crate::light::{near_plane, point_on, solid_angle_sample_lane, AreaLights};
use crate::sampling::sample_uniform_triangle;
use glam::{Vec2, Vec3};

/// The most light triangles the lanes choose from: every light of a scene that chooses its lights
/// by power (a power of two: a lane's choice, masked by it, is an index the compiler knows to be in
/// bounds). Each lane counts the CDF values at or below its sample, one comparison per light;
/// scenes with more lights choose by the light tree, each lane walking it on its own.
pub(crate) const MAX_LIGHTS: usize = crate::light::MAX_POWER_CHOSEN;
const _: () = assert!(MAX_LIGHTS.is_power_of_two());

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
    /// P(light), and the square of its longest edge (`light::by_solid_angle`).
    pmf: [f32; MAX_LIGHTS],
    longest_edge2: [f32; MAX_LIGHTS],
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
            pmf: [0.0; MAX_LIGHTS],
            longest_edge2: [0.0; MAX_LIGHTS],
            front: [[0.0; MAX_LIGHTS]; 3],
            back: [[0.0; MAX_LIGHTS]; 3],
        });
        t.upper[..n].copy_from_slice(&d.cdf()[1..]);
        let set = |xyz: &mut Xyz, j: usize, v: Vec3| {
            for (axis, value) in v.to_array().into_iter().enumerate() {
                xyz[axis][j] = value;
            }
        };
        for (j, (light, tri)) in area.sampled().enumerate() {
            for (c, &corner) in light.corners.iter().enumerate() {
                set(&mut t.corners[c], j, corner);
            }
            set(&mut t.normal, j, light.normal);
            t.pdf_area[j] = light.pdf_area;
            t.pmf[j] = light.pmf;
            t.longest_edge2[j] = light.longest_edge2;
            let m = materials.get(*mesh_material.get(tri as usize)? as usize)?;
            set(&mut t.front, j, m.emission_front);
            set(&mut t.back, j, m.emission_back);
        }
        Some(t)
    }

    /// `AreaLights::sample(p[i], _, u_select[i], (u0[i], u1[i]))` for every lane i that `wants`
    /// one, the same bits: the light whose CDF interval holds u, a point on it (uniform in area, or
    /// uniform in solid angle where `light::by_solid_angle` says so; both in the lanes), its
    /// normal and area density (zero where no point could be made), and its material's emission.
    /// `isa`: the build this is compiled into (a constant there), whose instructions read the
    /// table (see [`LightTable::entries`]).
    #[inline(always)]
    pub(crate) fn sample(
        &self,
        u_select: &[f32; LANES],
        u: &[[f32; LANES]; 2],
        p: &V3,
        wants: &[bool; LANES],
        isa: Option<Isa>,
    ) -> LightSamples {
        let mut k = [0u32; LANES];
        for &c in &self.upper[..self.n.min(MAX_LIGHTS)] {
            for i in 0..LANES {
                k[i] += u32::from(c <= u_select[i]);
            }
        }
        let last = self.n.saturating_sub(1) as u32;
        let mut j = [0u32; LANES];
        for (j, &k) in j.iter_mut().zip(&k) {
            *j = k.min(last) & (MAX_LIGHTS as u32 - 1);
        }
        let (mut out, picked) = self.entries(&j, isa);
        let corners = &picked.corners;
        for (i, (&u0, &u1)) in u[0].iter().zip(&u[1]).enumerate() {
            let bary = sample_uniform_triangle(Vec2::new(u0, u1));
            let at = [corners[0].get(i), corners[1].get(i), corners[2].get(i)];
            out.point.set(i, point_on(at, bary));
        }
        // Solid-angle samples where `light::by_solid_angle` says so: in every lane at once, the
        // spherical map run branch-free side by side (vectorised), when the cheap half of the test
        // lets any lane in.
        let mut near = [false; LANES];
        for i in 0..LANES {
            let at0 = corners[0].get(i);
            near[i] =
                wants[i] & near_plane(at0, out.normal.get(i), picked.longest_edge2[i], p.get(i));
        }
        if !near.contains(&true) {
            return out;
        }
        for i in 0..LANES {
            let at = [corners[0].get(i), corners[1].get(i), corners[2].get(i)];
            let u = Vec2::new(u[0][i], u[1][i]);
            let (normal, pmf, le2) = (out.normal.get(i), picked.pmf[i], picked.longest_edge2[i]);
            let (chosen, point, pdf_area) =
                solid_angle_sample_lane(at, normal, le2, pmf, p.get(i), u);
            let take = chosen & near[i];
            let keep_point = !take | (pdf_area == 0.0);
            out.point
                .set(i, if keep_point { out.point.get(i) } else { point });
            out.pdf_area[i] = if take { pdf_area } else { out.pdf_area[i] };
        }
        out
    }

    /// Lane i's light `j[i]` (below [`MAX_LIGHTS`]): its normal, density and emissions (the point
    /// left at zero) and its corners. With AVX-512 each field is one two-register permute of the
    /// table's 32 entries (`vpermt2ps`); otherwise the lanes read them one at a time (AVX2 has no
    /// fast gather, and the compiler would not vectorise a loop holding one; with AVX-512 it made
    /// 19 gathers, the most expensive instructions of `shade_hit` in `perf annotate` on a Zen 4).
    #[inline(always)]
    fn entries(&self, j: &[u32; LANES], isa: Option<Isa>) -> (LightSamples, Picked) {
        let mut out = LightSamples {
            point: V3::ZERO,
            normal: V3::ZERO,
            pdf_area: [0.0; LANES],
            front: V3::ZERO,
            back: V3::ZERO,
        };
        let mut picked = Picked {
            corners: [V3::ZERO; 3],
            pmf: [0.0; LANES],
            longest_edge2: [0.0; LANES],
        };
        #[cfg(target_arch = "x86_64")]
        if let Some(Isa(Kind::Avx512)) = isa {
            // SAFETY: an `Isa` of AVX-512 exists only where the processor has AVX-512F.
            let pick = |table: &[f32; MAX_LIGHTS]| unsafe { permute_avx512(table, j) };
            let pick3 = |xyz: &Xyz| V3 {
                x: pick(&xyz[0]),
                y: pick(&xyz[1]),
                z: pick(&xyz[2]),
            };
            for (corner, table) in picked.corners.iter_mut().zip(&self.corners) {
                *corner = pick3(table);
            }
            (out.normal, out.pdf_area) = (pick3(&self.normal), pick(&self.pdf_area));
            (out.front, out.back) = (pick3(&self.front), pick3(&self.back));
            (picked.pmf, picked.longest_edge2) = (pick(&self.pmf), pick(&self.longest_edge2));
            return (out, picked);
        }
        let _ = isa;
        let get = |xyz: &Xyz, j: usize| Vec3::new(xyz[0][j], xyz[1][j], xyz[2][j]);
        for (i, &j) in j.iter().enumerate() {
            let j = j as usize & (MAX_LIGHTS - 1);
            for (c, corner) in picked.corners.iter_mut().enumerate() {
                corner.set(i, get(&self.corners[c], j));
            }
            out.normal.set(i, get(&self.normal, j));
            out.pdf_area[i] = self.pdf_area[j];
            out.front.set(i, get(&self.front, j));
            out.back.set(i, get(&self.back, j));
            (picked.pmf[i], picked.longest_edge2[i]) = (self.pmf[j], self.longest_edge2[j]);
        }
        (out, picked)
    }
}

/// Lane i's light's corners, P(light) and longest edge squared, which `LightTable::sample` reads
/// besides what it returns.
struct Picked {
    corners: [V3; 3],
    pmf: [f32; LANES],
    longest_edge2: [f32; LANES],
}

/// Lane i: `table[j[i]]` (j[i] below 32), one `vpermt2ps` across the table's two halves.
///
/// # Safety
/// The processor must have AVX-512F.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn permute_avx512(table: &[f32; MAX_LIGHTS], j: &[u32; LANES]) -> [f32; LANES] {
    use std::arch::x86_64::*;
    const { assert!(MAX_LIGHTS == 32 && LANES == 16) };
    let mut out = [0.0f32; LANES];
    // SAFETY: the loads read table[0..16], table[16..32] and j[0..16], the store out[0..16]; the
    // unaligned forms accept any address.
    unsafe {
        let lo = _mm512_loadu_ps(table.as_ptr());
        let hi = _mm512_loadu_ps(table.as_ptr().add(16));
        let idx = _mm512_loadu_si512(j.as_ptr().cast());
        _mm512_storeu_ps(out.as_mut_ptr(), _mm512_permutex2var_ps(lo, idx, hi));
    }
    out
}
