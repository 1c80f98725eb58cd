use glam::Vec2;
use std::f32::consts::FRAC_PI_4;

/// Uniform point on the unit disk by the polar map r = √ξ₁, φ = 2πξ₂ (density 1/π).
///
/// The square root is what makes it uniform: the area within radius r grows as r², so the radius's CDF
/// is r² and its inverse is √ξ.
#[inline]
pub fn sample_uniform_disk(u: Vec2) -> Vec2 {
    let r = u.x.sqrt();
    let (s, c) = crate::math::det::sin_cos_turns(u.y);
    Vec2::new(r * c, r * s)
}

/// Uniform point on the unit disk by Shirley–Chiu's concentric map (density 1/π). Same law as
/// [`sample_uniform_disk`], but it keeps strata compact, which low-discrepancy points reward.
#[inline]
pub fn sample_concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    // Which wedge the point is in is a coin flip for random points, which a branch would
    // mispredict half the time: the operands are selected first (cheap selects), then the one
    // division is done. The result is the same as the textbook form's, operation for operation.
    // In the y wedge the textbook angle is π/2 − q; (cos, sin) of it are (sin q, cos q), so both
    // wedges need only the angle q ∈ [−π/4, π/4], whose sine and cosine are two short polynomials
    // with no argument reduction.
    let x_wedge = o.x.abs() > o.y.abs();
    let (r, other) = if x_wedge { (o.x, o.y) } else { (o.y, o.x) };
    let (s, c) = crate::math::det::sin_cos_quarter(FRAC_PI_4 * (other / r));
    let (along_x, along_y) = if x_wedge { (c, s) } else { (s, c) };
    Vec2::new(r * along_x, r * along_y)
}
