//! Histogram bins over the sphere of directions for the BSDF chi-square tests
//! (`bsdf_distributions/`, `layer_lobes/`).

use glam::{DVec3, Vec3};
use pathfarm_tracer::stats::SphereBins;
use std::f64::consts::PI;

/// One axis of a histogram on [lo, hi] whose bins are half uniform and half concentrated (Cauchy)
/// around `c` with scale `w`: the cumulative map F(x) = ½ (x − lo)/(hi − lo) + ½ Cauchy CDF, bins
/// uniform in F. This resolves narrow lobes without starving the rest of the range.
#[derive(Clone, Debug)]
pub struct Axis {
    lo: f64,
    hi: f64,
    c: f64,
    w: f64,
    n: usize,
    a0: f64,
    da: f64,
    edges: Vec<f64>,
}

impl Axis {
    pub fn new(lo: f64, hi: f64, c: f64, w: f64, n: usize) -> Self {
        let a0 = ((lo - c) / w).atan();
        let da = ((hi - c) / w).atan() - a0;
        let mut axis = Axis {
            lo,
            hi,
            c,
            w,
            n,
            a0,
            da,
            edges: Vec::new(),
        };
        let mut edges = vec![lo];
        for k in 1..n {
            let target = k as f64 / n as f64;
            let (mut a, mut b) = (lo, hi);
            for _ in 0..200 {
                let m = 0.5 * (a + b);
                if axis.cdf(m) < target {
                    a = m;
                } else {
                    b = m;
                }
            }
            edges.push(0.5 * (a + b));
        }
        edges.push(hi);
        axis.edges = edges;
        axis
    }

    pub fn cdf(&self, x: f64) -> f64 {
        0.5 * (x - self.lo) / (self.hi - self.lo)
            + 0.5 * ((((x - self.c) / self.w).atan() - self.a0) / self.da)
    }

    pub fn index(&self, x: f64) -> Option<usize> {
        if !(self.lo..=self.hi).contains(&x) {
            return None;
        }
        // Exact against the stored edges (the CDF only gives the starting guess).
        let mut k = ((self.cdf(x) * self.n as f64) as usize).min(self.n - 1);
        while k > 0 && x < self.edges[k] {
            k -= 1;
        }
        while k + 1 < self.n && x >= self.edges[k + 1] {
            k += 1;
        }
        Some(k)
    }
}

/// A histogram over one hemisphere in (h, φ), h = 1 − |z| ∈ [0, 1] (so dω = dh dφ), with bins
/// concentrated around a lobe centre. Its h range ends at the horizon, where the pdfs are
/// discontinuous, so the midpoint rule inside a bin only sees smooth densities. h is computed as
/// (x² + y²) / (1 + |z|), which stays accurate for the f32 directions near the pole.
#[derive(Clone, Debug)]
pub struct HemiGrid {
    upper: bool,
    z: Axis,
    /// φ relative to the lobe centre's azimuth, in [−π, π].
    phi: Axis,
    phi_c: f64,
}

impl HemiGrid {
    /// `center`: lobe axis in this hemisphere; `spread`: its angular half-width (radians).
    pub fn new(upper: bool, center: DVec3, spread: f64, n_z: usize, n_phi: usize) -> Self {
        let sin_c = (1.0 - center.z * center.z).max(0.0).sqrt();
        let wz = (sin_c * spread + 0.5 * spread * spread).max(1e-9);
        let wphi = if sin_c > spread {
            (spread / sin_c).min(PI)
        } else {
            PI
        };
        let h_c = if (center.z >= 0.0) == upper {
            1.0 - center.z.abs()
        } else {
            1.0
        };
        HemiGrid {
            upper,
            z: Axis::new(0.0, 1.0, h_c, wz, n_z),
            phi: Axis::new(-PI, PI, 0.0, wphi, n_phi),
            phi_c: center.y.atan2(center.x),
        }
    }

    pub fn len(&self) -> usize {
        self.z.n * self.phi.n
    }

    pub fn rel_phi(&self, phi: f64) -> f64 {
        let mut d = phi - self.phi_c;
        while d > PI {
            d -= 2.0 * PI;
        }
        while d < -PI {
            d += 2.0 * PI;
        }
        d
    }

    pub fn bin(&self, w: DVec3) -> Option<usize> {
        if (w.z >= 0.0) != self.upper {
            return None;
        }
        let kz = self.z.index((w.x * w.x + w.y * w.y) / (1.0 + w.z.abs()))?;
        let kp = self.phi.index(self.rel_phi(w.y.atan2(w.x)))?;
        Some(kz * self.phi.n + kp)
    }

    /// ∫ pdf over every bin by the midpoint rule on `sub × sub` cells, refined adaptively: the cell
    /// count is doubled until two successive estimates agree to 2·10⁻⁴ (or 320 × 320 cells), which
    /// also resolves bins straddling the edge of the pdf's support. A bin holding samples where every
    /// cell was zero is integrated on the finest grid before being called impossible.
    pub fn integrate(&self, pdf: &impl Fn(Vec3) -> f64, sub: usize, observed: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.len()];
        for kz in 0..self.z.n {
            for kp in 0..self.phi.n {
                let k = kz * self.phi.n + kp;
                let (mut prev, zeros) = self.integrate_bin(pdf, kz, kp, sub);
                if zeros == sub * sub {
                    out[k] = if observed[k] > 0.0 {
                        self.integrate_bin(pdf, kz, kp, 320).0
                    } else {
                        0.0
                    };
                    continue;
                }
                let mut s = sub;
                loop {
                    s *= 2;
                    let (cur, _) = self.integrate_bin(pdf, kz, kp, s);
                    if (cur - prev).abs() <= 2e-4 * cur.abs() + 1e-10 || s >= 320 {
                        out[k] = cur;
                        break;
                    }
                    prev = cur;
                }
            }
        }
        out
    }

    pub fn integrate_bin(
        &self,
        pdf: &impl Fn(Vec3) -> f64,
        kz: usize,
        kp: usize,
        sub: usize,
    ) -> (f64, usize) {
        let (z0, z1) = (self.z.edges[kz], self.z.edges[kz + 1]);
        let dz = (z1 - z0) / sub as f64;
        let (p0, p1) = (self.phi.edges[kp], self.phi.edges[kp + 1]);
        let dp = (p1 - p0) / sub as f64;
        let (mut acc, mut zeros) = (0.0, 0usize);
        for i in 0..sub {
            let h = z0 + (i as f64 + 0.5) * dz;
            let r = (h * (2.0 - h)).max(0.0).sqrt();
            let z = if self.upper { 1.0 - h } else { h - 1.0 };
            for j in 0..sub {
                let phi = self.phi_c + p0 + (j as f64 + 0.5) * dp;
                let v = pdf(Vec3::new(
                    (r * phi.cos()) as f32,
                    (r * phi.sin()) as f32,
                    z as f32,
                ));
                if v == 0.0 {
                    zeros += 1;
                }
                acc += v;
            }
        }
        (acc * dz * dp, zeros)
    }
}

/// Bins over the whole sphere: either the library's `SphereBins` (uniform in cos θ and φ; with an even
/// `n_theta` the horizon is a bin edge) or a zoomed grid per hemisphere.
pub enum Binning {
    Sphere(SphereBins),
    Zoom(Box<(HemiGrid, HemiGrid)>),
}

impl Binning {
    pub fn len(&self) -> usize {
        match self {
            Binning::Sphere(b) => b.len(),
            Binning::Zoom(g) => g.0.len() + g.1.len(),
        }
    }

    pub fn bin(&self, w: Vec3) -> Option<usize> {
        match self {
            Binning::Sphere(b) => Some(b.bin(w)),
            Binning::Zoom(g) => {
                let (u, l) = &**g;
                let w = w.as_dvec3().normalize();
                u.bin(w).or_else(|| l.bin(w).map(|k| k + u.len()))
            }
        }
    }

    pub fn integrate(&self, pdf: impl Fn(Vec3) -> f64, observed: &[f64]) -> Vec<f64> {
        match self {
            Binning::Sphere(b) => b.integrate(pdf, 12),
            Binning::Zoom(g) => {
                let (u, l) = &**g;
                let mut v = u.integrate(&pdf, 10, &observed[..u.len()]);
                v.extend(l.integrate(&pdf, 10, &observed[u.len()..]));
                v
            }
        }
    }
}
