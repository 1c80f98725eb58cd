use glam::Vec3;

/// Moves a ray origin `p` off the surface with geometric normal `n`, to the side `n` points to, by an
/// amount that scales with the magnitude of `p` (Wächter & Binder, "A Fast and Robust Method for
/// Avoiding Self-Intersection", Ray Tracing Gems, 2019). Integer ULP steps keep the offset tiny near the
/// origin and proportionate far away, so secondary rays neither re-hit their own surface (acne) nor
/// skip a nearby one (light leaks).
#[inline]
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let of_i = [
        (INT_SCALE * n.x) as i32,
        (INT_SCALE * n.y) as i32,
        (INT_SCALE * n.z) as i32,
    ];
    let step = |v: f32, o: i32| -> f32 {
        let bits = v.to_bits() as i32;
        f32::from_bits((bits + if v < 0.0 { -o } else { o }) as u32)
    };
    let p_i = Vec3::new(step(p.x, of_i[0]), step(p.y, of_i[1]), step(p.z, of_i[2]));
    Vec3::new(
        if p.x.abs() < ORIGIN {
            p.x + FLOAT_SCALE * n.x
        } else {
            p_i.x
        },
        if p.y.abs() < ORIGIN {
            p.y + FLOAT_SCALE * n.y
        } else {
            p_i.y
        },
        if p.z.abs() < ORIGIN {
            p.z + FLOAT_SCALE * n.z
        } else {
            p_i.z
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_moves_to_the_normal_side_at_all_scales() {
        for scale in [1e-3f32, 0.5, 3.0, 1e3, 1e5] {
            let p = Vec3::new(scale, -scale * 0.5, scale * 0.25);
            let n = Vec3::new(0.2, 0.9, -0.3).normalize();
            let q = offset_ray_origin(p, n);
            assert!((q - p).dot(n) > 0.0, "scale {scale}");
            assert!(
                (q - p).length() < scale.max(1.0) * 1e-3,
                "offset too large at {scale}"
            );
        }
    }
}
