//! Fresnel reflectance: Schlick's approximation (metals and the glTF specular layer) and the exact
//! unpolarised reflectance of a dielectric interface (transmission), with total internal reflection.

use glam::Vec3;

/// (1 − cos θ)⁵, the shape of Schlick's approximation.
#[inline]
pub fn schlick_weight(cos_theta: f32) -> f32 {
    let m = (1.0 - cos_theta).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

/// Schlick's approximation F = f0 + (1 − f0)(1 − cos θ)⁵, per channel.
#[inline]
pub fn schlick(f0: Vec3, cos_theta: f32) -> Vec3 {
    f0 + (Vec3::ONE - f0) * schlick_weight(cos_theta)
}

/// Normal-incidence reflectance of an interface with relative index of refraction `ior`:
/// ((ior − 1) / (ior + 1))².
#[inline]
pub fn f0_from_ior(ior: f32) -> f32 {
    let r = (ior - 1.0) / (ior + 1.0);
    r * r
}

/// Exact unpolarised Fresnel reflectance of a smooth dielectric interface.
///
/// `cos_i` is the cosine between the incident direction and the normal on the incident side
/// (≥ 0), `eta` = n_transmitted / n_incident. Returns 1 under total internal reflection.
#[inline]
pub fn dielectric(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_parl * r_parl + r_perp * r_perp)
}

/// Refracts `w` (pointing away from the surface, on the side `n` points to, `w·n = cos_i ≥ 0`)
/// through the interface with normal `n` and relative index `eta` = n_t / n_i. The result points
/// away from the surface on the other side. `None` under total internal reflection.
#[inline]
pub fn refract(w: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = w.dot(n);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-w / eta + (cos_i / eta - cos_t) * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_limits() {
        // Normal incidence matches f0, grazing incidence reflects everything.
        assert!((dielectric(1.0, 1.5) - f0_from_ior(1.5)).abs() < 1e-6);
        assert!((dielectric(0.0, 1.5) - 1.0).abs() < 1e-6);
        // Reciprocity of the interface: F(θi, η) = F(θt, 1/η).
        let cos_i = 0.7f32;
        let sin_t = (1.0 - cos_i * cos_i).sqrt() / 1.5;
        let cos_t = (1.0 - sin_t * sin_t).sqrt();
        assert!((dielectric(cos_i, 1.5) - dielectric(cos_t, 1.0 / 1.5)).abs() < 1e-6);
        // Total internal reflection beyond the critical angle from inside.
        let cos_crit = (1.0f32 - 1.0 / (1.5 * 1.5)).sqrt();
        assert_eq!(dielectric(cos_crit - 1e-3, 1.0 / 1.5), 1.0);
        assert!(dielectric(cos_crit + 1e-3, 1.0 / 1.5) < 1.0);
    }

    #[test]
    fn refraction_obeys_snell() {
        let w = Vec3::new(0.6, 0.0, 0.8);
        let t = refract(w, Vec3::Z, 1.5).unwrap();
        assert!((t.length() - 1.0).abs() < 1e-6);
        assert!(t.z < 0.0);
        assert!((w.x - 1.5 * -t.x).abs() < 1e-6, "sin θi = η sin θt");
        assert!(refract(w, Vec3::Z, 1.0 / 1.5).is_some());
        assert!(refract(
            Vec3::new(0.9, 0.0, (1.0f32 - 0.81).sqrt()),
            Vec3::Z,
            1.0 / 1.5
        )
        .is_none());
    }
}
