//! Keyframe interpolation, as glTF 2.0 animation samplers define it (the specification's
//! "Animation" section and its appendix C, "Interpolation"):
//!
//! - `STEP`: the value of the last key at or before t.
//! - `LINEAR`: (1 − s)·v_k + s·v_{k+1}, s = (t − t_k) / (t_{k+1} − t_k); rotations by spherical
//!   linear interpolation along the shorter arc, the result normalised.
//! - `CUBICSPLINE`: each key stores an in-tangent a, a value v and an out-tangent b; between keys the
//!   cubic Hermite spline (2s³ − 3s² + 1)·v_k + t_d(s³ − 2s² + s)·b_k + (−2s³ + 3s²)·v_{k+1} +
//!   t_d(s³ − s²)·a_{k+1}, with t_d = t_{k+1} − t_k; rotations normalised after.
//!
//! Times before the first key take the first key's value, after the last the last's. Everything is
//! plain f32 arithmetic, and the slerp's arccosine and sines are [`crate::math::det`]'s, so a pose
//! has the same bits on every machine (the scene a frame renders depends on it).

use crate::math::det;

/// How a sampler interpolates between its keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Linear,
    Step,
    CubicSpline,
}

impl Interpolation {
    /// Output elements per key and per component: 3 for `CUBICSPLINE` (in-tangent, value,
    /// out-tangent), else 1.
    pub fn elements_per_key(self) -> usize {
        match self {
            Interpolation::CubicSpline => 3,
            _ => 1,
        }
    }
}

/// A sampler's keyframes: strictly increasing times, and for each key `width` values (a vector's
/// components, or one weight per morph target), three such groups per key for `CUBICSPLINE`.
#[derive(Clone, Debug)]
pub struct Keyframes {
    pub times: Vec<f32>,
    pub values: Vec<f32>,
    pub width: usize,
    pub interpolation: Interpolation,
}

/// Where a time falls among the keys.
enum Segment {
    /// At (or clamped to) key k.
    At(usize),
    /// Between key k and k + 1, at fraction s of the interval of length td.
    Between { k: usize, s: f32, td: f32 },
}

impl Keyframes {
    /// Checks the shape: at least one key, finite non-decreasing times, finite values, and
    /// `width` × keys (× 3 for `CUBICSPLINE`) values. Returns what is wrong.
    pub fn check(&self) -> Result<(), String> {
        if self.times.is_empty() {
            return Err("has no keyframes (the input accessor is empty)".into());
        }
        if let Some(k) = self.times.iter().position(|t| !t.is_finite()) {
            return Err(format!("key {k} has a non-finite time"));
        }
        if let Some(k) = self.times.windows(2).position(|w| w[1] < w[0]) {
            return Err(format!(
                "key times decrease at key {}: {} after {}",
                k + 1,
                self.times[k + 1],
                self.times[k]
            ));
        }
        let expected = self.times.len() * self.interpolation.elements_per_key() * self.width;
        if self.values.len() != expected {
            return Err(format!(
                "has {} output values for {} keys, expected {expected}",
                self.values.len(),
                self.times.len()
            ));
        }
        Ok(())
    }

    /// The first and last key times.
    pub fn span(&self) -> (f32, f32) {
        (
            self.times.first().copied().unwrap_or(0.0),
            self.times.last().copied().unwrap_or(0.0),
        )
    }

    fn locate(&self, t: f32) -> Segment {
        let n = self.times.len();
        // NaN goes to the first key too.
        if n < 2 || t.is_nan() || t <= self.times[0] {
            return Segment::At(0);
        }
        if t >= self.times[n - 1] {
            return Segment::At(n - 1);
        }
        // times[k] <= t < times[k + 1]: the interval is not empty.
        let k = self.times.partition_point(|&x| x <= t) - 1;
        let td = self.times[k + 1] - self.times[k];
        Segment::Between {
            k,
            s: (t - self.times[k]) / td,
            td,
        }
    }

    /// Group `g` (0: in-tangent, 1: value, 2: out-tangent for `CUBICSPLINE`) of key `k`.
    fn group(&self, k: usize, g: usize) -> &[f32] {
        let w = self.width;
        let start = match self.interpolation {
            Interpolation::CubicSpline => (3 * k + g) * w,
            _ => k * w,
        };
        &self.values[start..start + w]
    }

    fn value(&self, k: usize) -> &[f32] {
        self.group(k, 1)
    }

    /// The value at time `t` into `out` (`width` components), rotations not normalised.
    pub fn sample(&self, t: f32, out: &mut [f32]) {
        match self.locate(t) {
            Segment::At(k) => out.copy_from_slice(self.value(k)),
            Segment::Between { k, s, td } => match self.interpolation {
                Interpolation::Step => out.copy_from_slice(self.value(k)),
                Interpolation::Linear => {
                    let (a, b) = (self.value(k), self.value(k + 1));
                    for (o, (a, b)) in out.iter_mut().zip(a.iter().zip(b)) {
                        *o = (1.0 - s) * a + s * b;
                    }
                }
                Interpolation::CubicSpline => {
                    let (s2, s3) = (s * s, s * s * s);
                    let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
                    let h10 = td * (s3 - 2.0 * s2 + s);
                    let h01 = -2.0 * s3 + 3.0 * s2;
                    let h11 = td * (s3 - s2);
                    let (v0, b0) = (self.value(k), self.group(k, 2));
                    let (v1, a1) = (self.value(k + 1), self.group(k + 1, 0));
                    for (i, o) in out.iter_mut().enumerate() {
                        *o = h00 * v0[i] + h10 * b0[i] + h01 * v1[i] + h11 * a1[i];
                    }
                }
            },
        }
    }

    /// A rotation quaternion (x, y, z, w) at time `t`: slerp between `LINEAR` keys, the spline
    /// for `CUBICSPLINE`; normalised (a zero quaternion stays zero: the node reports it).
    pub fn sample_rotation(&self, t: f32) -> [f32; 4] {
        if self.width != 4 {
            return [0.0, 0.0, 0.0, 1.0];
        }
        if let (Interpolation::Linear, Segment::Between { k, s, .. }) =
            (self.interpolation, self.locate(t))
        {
            let a = to4(self.value(k));
            let b = to4(self.value(k + 1));
            return slerp(a, b, s);
        }
        let mut q = [0.0; 4];
        self.sample(t, &mut q);
        normalize(q)
    }
}

fn to4(v: &[f32]) -> [f32; 4] {
    [v[0], v[1], v[2], v[3]]
}

fn dot(a: [f32; 4], b: [f32; 4]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// `q` scaled to unit length (zero, or not finite, stays as it is).
pub fn normalize(q: [f32; 4]) -> [f32; 4] {
    let len = dot(q, q).sqrt();
    if len > 0.0 && len.is_finite() {
        q.map(|c| c / len)
    } else {
        q
    }
}

/// Spherical linear interpolation from `a` to `b` (normalised first) along the shorter arc, the
/// result normalised. Nearly parallel quaternions (cos θ > 0.9995) are interpolated linearly,
/// where sin θ would lose its precision.
pub fn slerp(a: [f32; 4], b: [f32; 4], s: f32) -> [f32; 4] {
    let a = normalize(a);
    let mut b = normalize(b);
    let mut cos = dot(a, b);
    if cos < 0.0 {
        b = b.map(|c| -c);
        cos = -cos;
    }
    let (wa, wb) = if cos > 0.9995 {
        (1.0 - s, s)
    } else {
        let theta = det::acos(cos.min(1.0));
        let sin = det::sin_cos(theta).0;
        (
            det::sin_cos((1.0 - s) * theta).0 / sin,
            det::sin_cos(s * theta).0 / sin,
        )
    };
    normalize([
        wa * a[0] + wb * b[0],
        wa * a[1] + wb * b[1],
        wa * a[2] + wb * b[2],
        wa * a[3] + wb * b[3],
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(times: &[f32], values: &[f32], width: usize, i: Interpolation) -> Keyframes {
        let k = Keyframes {
            times: times.to_vec(),
            values: values.to_vec(),
            width,
            interpolation: i,
        };
        k.check().unwrap();
        k
    }

    fn at(k: &Keyframes, t: f32) -> Vec<f32> {
        let mut out = vec![0.0; k.width];
        k.sample(t, &mut out);
        out
    }

    #[test]
    fn step_holds_each_key_until_the_next() {
        let k = keys(
            &[1.0, 2.0, 4.0],
            &[10.0, 20.0, 40.0],
            1,
            Interpolation::Step,
        );
        assert_eq!(at(&k, 0.0), [10.0]);
        assert_eq!(at(&k, 1.0), [10.0]);
        assert_eq!(at(&k, 1.999), [10.0]);
        assert_eq!(at(&k, 2.0), [20.0]);
        assert_eq!(at(&k, 3.9), [20.0]);
        assert_eq!(at(&k, 4.0), [40.0]);
        assert_eq!(at(&k, 100.0), [40.0]);
    }

    #[test]
    fn linear_interpolates_and_clamps() {
        let k = keys(
            &[1.0, 3.0],
            &[0.0, 10.0, -4.0, 2.0, 20.0, 4.0],
            3,
            Interpolation::Linear,
        );
        assert_eq!(at(&k, 2.0), [1.0, 15.0, 0.0]);
        assert_eq!(at(&k, 1.5), [0.5, 12.5, -2.0]);
        // Exactly the keys at the keys, and clamped outside.
        assert_eq!(at(&k, 1.0), [0.0, 10.0, -4.0]);
        assert_eq!(at(&k, 3.0), [2.0, 20.0, 4.0]);
        assert_eq!(at(&k, -5.0), [0.0, 10.0, -4.0]);
        assert_eq!(at(&k, 7.0), [2.0, 20.0, 4.0]);
        assert_eq!(at(&k, f32::NAN), [0.0, 10.0, -4.0]);
        // One key: that value everywhere.
        let one = keys(&[2.0], &[5.0], 1, Interpolation::Linear);
        assert_eq!(at(&one, 0.0), [5.0]);
        assert_eq!(at(&one, 9.0), [5.0]);
    }

    /// The Hermite spline of the specification's appendix, by hand: keys at t = 0 and 2
    /// (t_d = 2), v0 = 1 with out-tangent b0 = 0.5, v1 = 3 with in-tangent a1 = −1. At t = 0.5,
    /// s = 0.25: h00 = 0.84375, h10 = 0.140625, h01 = 0.15625, h11 = −0.046875, so
    /// 0.84375·1 + 2·0.140625·0.5 + 0.15625·3 + 2·(−0.046875)·(−1) = 1.546875 (every term exact).
    #[test]
    fn cubic_spline_follows_the_specification() {
        // Per key: in-tangent, value, out-tangent (key 0's in- and key 1's out-tangent unused).
        let k = keys(
            &[0.0, 2.0],
            &[99.0, 1.0, 0.5, -1.0, 3.0, 99.0],
            1,
            Interpolation::CubicSpline,
        );
        assert_eq!(at(&k, 0.5), [1.546875]);
        assert_eq!(at(&k, 0.0), [1.0]);
        assert_eq!(at(&k, 2.0), [3.0]);
        assert_eq!(at(&k, -1.0), [1.0]);
        assert_eq!(at(&k, 3.0), [3.0]);
        // At s = 0.5: h00 = h01 = 0.5, h10 = 0.125, h11 = −0.125:
        // 0.5 + 2·0.125·0.5 + 1.5 + 2·(−0.125)·(−1) = 2.375.
        assert_eq!(at(&k, 1.0), [2.375]);
        // The tangents are scaled by the interval: the same keys over [0, 4] at s = 0.25 give
        // 0.84375 + 4·0.140625·0.5 + 0.46875 + 4·0.046875 = 1.78125.
        let wide = keys(
            &[0.0, 4.0],
            &[99.0, 1.0, 0.5, -1.0, 3.0, 99.0],
            1,
            Interpolation::CubicSpline,
        );
        assert_eq!(at(&wide, 1.0), [1.78125]);
    }

    #[test]
    fn the_shape_is_checked() {
        let bad = |times: &[f32], values: &[f32], i| {
            Keyframes {
                times: times.to_vec(),
                values: values.to_vec(),
                width: 1,
                interpolation: i,
            }
            .check()
            .unwrap_err()
        };
        assert!(bad(&[], &[], Interpolation::Linear).contains("no keyframes"));
        assert!(bad(&[1.0, 0.5], &[0.0, 1.0], Interpolation::Step).contains("decrease at key 1"));
        assert!(bad(&[0.0, f32::NAN], &[0.0, 1.0], Interpolation::Step).contains("non-finite"));
        let e = bad(&[0.0, 1.0], &[0.0, 1.0], Interpolation::CubicSpline);
        assert!(e.contains("2 output values for 2 keys, expected 6"), "{e}");
    }

    fn close(a: [f32; 4], b: [f32; 4], tol: f32) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn slerp_is_spherical_and_takes_the_shorter_arc() {
        let id = [0.0, 0.0, 0.0, 1.0];
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let quarter_z = [0.0, 0.0, h, h]; // 90° about +Z
                                          // Half way: 45° about Z, (0, 0, sin 22.5°, cos 22.5°).
        let (s, c) = (22.5f32.to_radians().sin(), 22.5f32.to_radians().cos());
        assert!(close(slerp(id, quarter_z, 0.5), [0.0, 0.0, s, c], 1e-6));
        // A third of the way: 30°, which a normalised linear blend would miss (29.1°).
        let (s, c) = (15f32.to_radians().sin(), 15f32.to_radians().cos());
        assert!(close(
            slerp(id, quarter_z, 1.0 / 3.0),
            [0.0, 0.0, s, c],
            1e-6
        ));
        // The ends are the keys.
        assert!(close(slerp(id, quarter_z, 0.0), id, 1e-7));
        assert!(close(slerp(id, quarter_z, 1.0), quarter_z, 1e-7));
        // −q is the same rotation: the path goes the short way, to −(−q).
        let neg = quarter_z.map(|c| -c);
        assert!(close(slerp(id, neg, 0.5), slerp(id, quarter_z, 0.5), 1e-6));
        // Nearly equal keys: a normalised blend, still unit length.
        let tiny = normalize([0.0, 0.0, 1e-4, 1.0]);
        let q = slerp(id, tiny, 0.5);
        assert!((dot(q, q) - 1.0).abs() < 1e-6 && q[2] > 0.0 && q[2] < tiny[2]);
        // Through the sampler: LINEAR rotations slerp.
        let k = keys(
            &[0.0, 1.0],
            &[id, quarter_z].concat(),
            4,
            Interpolation::Linear,
        );
        assert_eq!(k.sample_rotation(0.5), slerp(id, quarter_z, 0.5));
    }

    #[test]
    fn cubic_rotations_are_normalised() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let zero = [0.0; 4];
        let values = [
            zero,
            [0.0, 0.0, 0.0, 1.0],
            zero,
            zero,
            [0.0, 0.0, h, h],
            zero,
        ]
        .concat();
        let k = keys(&[0.0, 1.0], &values, 4, Interpolation::CubicSpline);
        let q = k.sample_rotation(0.5);
        assert!((dot(q, q) - 1.0).abs() < 1e-6);
        // With zero tangents the spline blends the values by 0.5 each: normalised, 45° about Z.
        let (s, c) = (22.5f32.to_radians().sin(), 22.5f32.to_radians().cos());
        assert!(close(q, [0.0, 0.0, s, c], 1e-6), "{q:?}");
    }
}
