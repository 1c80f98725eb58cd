use glam::Vec3;

/// γ₇ = 7u / (1 − 7u) with u = 2⁻²⁴: the relative error bound of a point interpolated from three
/// vertices by barycentric weights (pbrt-v4, §6.8.5).
const GAMMA_7: f32 = 7.0 * (f32::EPSILON / 2.0) / (1.0 - 7.0 * (f32::EPSILON / 2.0));

/// How far a ray spawned at a hit on the triangle `corners` must start from the surface, beyond
/// the offset [`offset_ray_origin`] scales with the hit point, so that neither the hit point's
/// rounding (interpolated from the corners) nor the intersection test's (on the corners relative
/// to the new origin) can put its own triangle in front of it: both scale with the corners'
/// magnitudes, which can be thousands of times the hit point's (a ground plane scaled to the
/// horizon, seen from close by). γ₇ (pbrt-v4's bound for a point interpolated from three
/// vertices) times the sum of the corners' largest coordinates; on a triangle no larger than
/// its distance from the origin this is a small fraction of the ULP offset.
#[inline(always)]
pub fn spawn_clearance(corners: [Vec3; 3]) -> f32 {
    GAMMA_7 * (corners[0].abs() + corners[1].abs() + corners[2].abs()).max_element()
}

/// Moves a ray origin `p` off the surface with geometric normal `n`, to the side `n` points to:
/// first by `clearance` ([`spawn_clearance`]), then by an amount that scales with the magnitude
/// of `p` (Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection", Ray
/// Tracing Gems, 2019). Integer ULP steps keep the offset tiny near the origin and proportionate
/// far away, so secondary rays neither re-hit their own surface (acne) nor skip a nearby one
/// (light leaks).
#[inline]
pub fn offset_ray_origin(p: Vec3, n: Vec3, clearance: f32) -> Vec3 {
    let p = p + n * clearance;
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: SSE2 is part of the x86-64 baseline: every x86-64 processor has it.
        unsafe { offset_sse2(p, n) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        offset_scalar(p, n)
    }
}

const ORIGIN: f32 = 1.0 / 32.0;
const FLOAT_SCALE: f32 = 1.0 / 65536.0;
const INT_SCALE: f32 = 256.0;

/// The method as written in the paper, one coordinate at a time. The reference [`offset_sse2`] is
/// tested against, and the version used where SSE2 is not available.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline]
fn offset_scalar(p: Vec3, n: Vec3) -> Vec3 {
    let of_i = [
        (INT_SCALE * n.x) as i32,
        (INT_SCALE * n.y) as i32,
        (INT_SCALE * n.z) as i32,
    ];
    offset_by(p, n, of_i)
}

/// [`offset_ray_origin`] for a unit normal `n` (|component| ≤ 1), in the form the wavefront
/// integrator's lanes are vectorised from: the compiler vectorises no saturating float-to-integer
/// conversion (`as i32`), so the integer steps, whole numbers of at most 256 in magnitude, are
/// read off the bits of 1.5 · 2²³ + trunc(256 n), which holds them exactly. The same bits as
/// [`offset_ray_origin`] for every unit normal (tested).
#[inline(always)]
pub(crate) fn offset_unit_normal(p: Vec3, n: Vec3, clearance: f32) -> Vec3 {
    let p = p + n * clearance;
    const MAGIC: f32 = 12_582_912.0; // 1.5 · 2²³: the sum's low mantissa bits are the integer
    let int =
        |v: f32| ((MAGIC + (INT_SCALE * v).trunc()).to_bits() as i32).wrapping_sub(0x4b40_0000);
    offset_by(p, n, [int(n.x), int(n.y), int(n.z)])
}

/// The offset itself, given the integer steps `of_i` = 256 n truncated.
#[inline(always)]
fn offset_by(p: Vec3, n: Vec3, of_i: [i32; 3]) -> Vec3 {
    let step = |v: f32, o: i32| -> f32 {
        let bits = v.to_bits() as i32;
        f32::from_bits(bits.wrapping_add(if v < 0.0 { o.wrapping_neg() } else { o }) as u32)
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

/// [`offset_scalar`] on the three coordinates at once, with the same bits: the per-coordinate
/// choices (the sign of p, near the origin or not) are random along a path, and as branches they
/// were mispredicted; as lane masks they cost nothing. Every arithmetic step is the scalar one
/// (truncating conversion, integer add on the bits, a product then a sum, no fused multiply-add).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
#[inline]
fn offset_sse2(p: Vec3, n: Vec3) -> Vec3 {
    use glam::Vec3A;
    use std::arch::x86_64::*;
    let pv: __m128 = Vec3A::from(p).into();
    let nv: __m128 = Vec3A::from(n).into();
    let zero = _mm_setzero_ps();
    // `as i32` saturates and turns NaN into 0, where the SIMD conversion gives i32::MIN for
    // both: NaN lanes are masked to 0 and lanes at or above 2³¹ flipped to i32::MAX.
    let scaled = _mm_mul_ps(_mm_set1_ps(INT_SCALE), nv);
    let ordered = _mm_castps_si128(_mm_cmpord_ps(scaled, scaled));
    let too_big = _mm_castps_si128(_mm_cmpge_ps(scaled, _mm_set1_ps(2_147_483_648.0)));
    let of_i = _mm_and_si128(_mm_xor_si128(_mm_cvttps_epi32(scaled), too_big), ordered);
    // v < 0 ? −o : o, as (o ^ m) − m with m all ones where v < 0.
    let negative = _mm_castps_si128(_mm_cmplt_ps(pv, zero));
    let signed = _mm_sub_epi32(_mm_xor_si128(of_i, negative), negative);
    let p_i = _mm_castsi128_ps(_mm_add_epi32(_mm_castps_si128(pv), signed));
    let p_f = _mm_add_ps(pv, _mm_mul_ps(_mm_set1_ps(FLOAT_SCALE), nv));
    let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), pv);
    let near = _mm_cmplt_ps(abs, _mm_set1_ps(ORIGIN));
    let out = _mm_or_ps(_mm_and_ps(near, p_f), _mm_andnot_ps(near, p_i));
    Vec3::from(Vec3A::from(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lanewise_form_is_the_scalar_one_for_unit_normals() {
        let mut u = crate::testing::uniform_stream(0x9e37_79b9_7f4a_7c15);
        let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
        for case in 0..200_000 {
            let n = if case < 6 {
                axes[case]
            } else {
                crate::sampling::sample_uniform_sphere(glam::Vec2::new(u(), u()))
            };
            let scale = [1e-6, 0.01, 1.0, 100.0, 1e6][case % 5];
            let p = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5) * scale;
            let (a, b) = (offset_unit_normal(p, n, 0.0), offset_scalar(p, n));
            assert_eq!(
                [a.x.to_bits(), a.y.to_bits(), a.z.to_bits()],
                [b.x.to_bits(), b.y.to_bits(), b.z.to_bits()],
                "p {p:?} n {n:?}"
            );
        }
    }

    #[test]
    fn offset_moves_to_the_normal_side_at_all_scales() {
        for scale in [1e-3f32, 0.5, 3.0, 1e3, 1e5] {
            let p = Vec3::new(scale, -scale * 0.5, scale * 0.25);
            let n = Vec3::new(0.2, 0.9, -0.3).normalize();
            let q = offset_ray_origin(p, n, 0.0);
            assert!((q - p).dot(n) > 0.0, "scale {scale}");
            assert!(
                (q - p).length() < scale.max(1.0) * 1e-3,
                "offset too large at {scale}"
            );
        }
    }

    /// The SIMD version gives the scalar method's bits, on points near and far from the origin, of
    /// both signs, with normals of every orientation (and the non-finite values a broken scene could
    /// produce).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn simd_offset_matches_the_scalar_method_bit_for_bit() {
        let mut rng = crate::testing::uniform_stream(0x853c_49e6_748f_ea9bu64);
        let special = [
            0.0f32,
            -0.0,
            ORIGIN,
            -ORIGIN,
            1e-30,
            f32::INFINITY,
            f32::NAN,
            1e38,
        ];
        for case in 0..200_000 {
            let scale = [1e-4f32, 0.01, 0.03, 1.0, 100.0, 1e6][case % 6];
            let mut p = Vec3::new(rng() - 0.5, rng() - 0.5, rng() - 0.5) * 2.0 * scale;
            let mut n = (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize_or(Vec3::Z);
            if case % 97 == 0 {
                p.x = special[case / 97 % special.len()];
                n.y = special[(case / 97 + 3) % special.len()];
            }
            // SAFETY: SSE2 is part of the x86-64 baseline.
            let (a, b) = (unsafe { offset_sse2(p, n) }, offset_scalar(p, n));
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits),
                "p {p:?} n {n:?}"
            );
        }
    }
}
