//! The isotropic GGX (Trowbridge–Reitz) microfacet distribution with the height-correlated Smith
//! masking-shadowing function, and sampling of its distribution of *visible* normals.
//!
//! Everything works in the local shading frame (z = macro normal) with the outgoing direction `wo`
//! in the upper hemisphere (`wo.z > 0`); the BSDF mirrors its directions there before calling in.
//!
//! With α the GGX roughness and, for a unit vector w, `a(w) = √(w.z² + α² (w.x² + w.y²))`:
//! - D(m) = α² / (π (m.x² + m.y² + α² m.z²)²) for m.z > 0 — written without `1 − cos²θ` so that it
//!   stays accurate for tiny α;
//! - Λ(w) = (a(w)/|w.z| − 1) / 2, G1(w) = 1 / (1 + Λ(w)) = 2|w.z| / (|w.z| + a(w));
//! - height-correlated G2(o, i) = 1 / (1 + Λ(o) + Λ(i)) (also used for transmission, as pbrt-v4 does);
//! - V(o, i) = G2 / (4 |o.z| |i.z|) = 1 / (2 (|i.z| a(o) + |o.z| a(i)));
//! - visible normals: D_o(m) = G1(o) max(0, o·m) D(m) / o.z, sampled exactly with Dupuy & Benyoub's
//!   spherical caps (2023), an equivalent and shorter form of Heitz's 2018 method.

use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// The GGX distribution of roughness α (α = perceptual roughness²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    pub alpha: f32,
}

impl Ggx {
    /// Smallest α used for a non-zero roughness; below it the lobe is numerically a delta.
    pub const MIN_ALPHA: f32 = 1e-4;

    /// GGX of perceptual roughness `roughness` (α = roughness², clamped to [`Ggx::MIN_ALPHA`, 1]).
    #[inline]
    pub fn from_roughness(roughness: f32) -> Self {
        Ggx {
            alpha: (roughness * roughness).clamp(Self::MIN_ALPHA, 1.0),
        }
    }

    /// Normal distribution D(m) for a unit microfacet normal `m` (zero below the surface).
    #[inline(always)]
    pub fn d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let t = m.x * m.x + m.y * m.y + a2 * m.z * m.z;
        a2 * FRAC_1_PI / (t * t)
    }

    /// a(w) = |w.z| √(1 + α² tan²θ), the common factor of Λ and G1.
    #[inline(always)]
    fn a(&self, w: Vec3) -> f32 {
        let a2 = self.alpha * self.alpha;
        (w.z * w.z + a2 * (w.x * w.x + w.y * w.y)).sqrt()
    }

    /// Smith's Λ(w) for a unit direction `w` (either hemisphere).
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        let z = w.z.abs();
        if z == 0.0 {
            return f32::INFINITY;
        }
        0.5 * (self.a(w) / z - 1.0)
    }

    /// Masking G1(w) = 1 / (1 + Λ(w)).
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        let z = w.z.abs();
        2.0 * z / (z + self.a(w))
    }

    /// Height-correlated masking-shadowing G2(o, i) = 1 / (1 + Λ(o) + Λ(i)).
    #[inline(always)]
    pub fn g2(&self, o: Vec3, i: Vec3) -> f32 {
        let (zo, zi) = (o.z.abs(), i.z.abs());
        let den = zi * self.a(o) + zo * self.a(i);
        if den <= 0.0 {
            return 0.0;
        }
        2.0 * zo * zi / den
    }

    /// Visibility term V = G2 / (4 |o.z| |i.z|), in its cancellation-free form.
    #[inline(always)]
    pub fn vis(&self, o: Vec3, i: Vec3) -> f32 {
        let den = i.z.abs() * self.a(o) + o.z.abs() * self.a(i);
        if den <= 0.0 {
            return 0.0;
        }
        0.5 / den
    }

    /// Samples a visible microfacet normal for `o` (`o.z > 0`) with density
    /// [`Ggx::visible_normal_pdf`] (Dupuy & Benyoub 2023: a spherical cap in the stretched space).
    #[inline(always)]
    pub fn sample_visible_normal(&self, o: Vec3, u: Vec2) -> Vec3 {
        let a = self.alpha;
        // Stretch the view direction to the configuration where the distribution is a hemisphere.
        let s = Vec3::new(o.x * a, o.y * a, o.z).normalize();
        // Uniform point on the spherical cap z ∈ (−s.z, 1].
        let z = (1.0 - u.y) * (1.0 + s.z) - s.z;
        let sin_theta = (1.0 - z * z).max(0.0).sqrt();
        let (sp, cp) = crate::math::det::sin_cos_turns(u.x);
        let h = Vec3::new(sin_theta * cp + s.x, sin_theta * sp + s.y, z + s.z);
        // Unstretch.
        let m = Vec3::new(h.x * a, h.y * a, h.z.max(0.0));
        let len2 = m.length_squared();
        if len2 > 0.0 && len2.is_finite() {
            m / len2.sqrt()
        } else {
            Vec3::Z
        }
    }

    /// Density of [`Ggx::sample_visible_normal`] over microfacet normals:
    /// D_o(m) = G1(o) max(0, o·m) D(m) / o.z.
    #[inline(always)]
    pub fn visible_normal_pdf(&self, o: Vec3, m: Vec3) -> f32 {
        let om = o.dot(m);
        if om <= 0.0 || o.z <= 0.0 {
            return 0.0;
        }
        2.0 * om * self.d(m) / (o.z + self.a(o))
    }

    /// Solid-angle density of `i = reflect(o, h)` when `h` is a sampled visible normal:
    /// D_o(h) / (4 o·h) = G1(o) D(h) / (4 o.z).
    #[inline(always)]
    pub fn reflection_pdf(&self, o: Vec3, h: Vec3) -> f32 {
        if o.z <= 0.0 {
            return 0.0;
        }
        0.5 * self.d(h) / (o.z + self.a(o))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn d_is_normalised_over_projected_area() {
        // ∫ D(m) cos θm dm = 1, by the midpoint rule in (cos θ, φ); D is isotropic so φ drops out.
        for alpha in [0.05f32, 0.3, 1.0] {
            let g = Ggx { alpha };
            let n = 200_000;
            let mut acc = 0.0f64;
            for k in 0..n {
                let z = (k as f64 + 0.5) / n as f64;
                let m = Vec3::new((1.0 - z * z).sqrt() as f32, 0.0, z as f32);
                acc += g.d(m) as f64 * z;
            }
            let total = acc * 2.0 * std::f64::consts::PI / n as f64;
            assert!((total - 1.0).abs() < 2e-3, "α = {alpha}: ∫ D cos = {total}");
        }
    }

    #[test]
    fn g1_and_g2_limits() {
        let g = Ggx { alpha: 0.5 };
        assert!((g.g1(Vec3::Z) - 1.0).abs() < 1e-6);
        let o = Vec3::new(0.6, 0.0, 0.8);
        let i = Vec3::new(0.0, 0.6, 0.8);
        assert!((g.g1(o) - 1.0 / (1.0 + g.lambda(o))).abs() < 1e-6);
        assert!((g.g2(o, i) - 1.0 / (1.0 + g.lambda(o) + g.lambda(i))).abs() < 1e-6);
        assert!((g.vis(o, i) - g.g2(o, i) / (4.0 * o.z * i.z)).abs() < 1e-5);
        assert!(g.g2(o, i) <= g.g1(o).min(g.g1(i)) + 1e-6);
    }
}
