use glam::Vec3;

/// An orthonormal basis whose `z` axis is a given unit normal. BSDFs work in this local frame, where
/// `cos θ = w.z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub x: Vec3,
    pub y: Vec3,
    pub z: Vec3,
}

impl Frame {
    /// Builds a frame around the unit vector `n` (Duff et al. 2017, "Building an Orthonormal Basis,
    /// Revisited": branchless and continuous except at one point).
    #[inline]
    pub fn from_z(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let x = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let y = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { x, y, z: n }
    }

    /// Builds a frame with `z = n` and `x` as close as possible to the tangent `t` (Gram–Schmidt).
    /// Falls back to [`Frame::from_z`] when `t` is parallel to `n`.
    #[inline]
    pub fn from_zx(n: Vec3, t: Vec3) -> Self {
        let x = t - n * n.dot(t);
        let len2 = x.length_squared();
        if len2 < 1e-12 || !len2.is_finite() {
            return Self::from_z(n);
        }
        let x = x / len2.sqrt();
        Frame {
            x,
            y: n.cross(x),
            z: n,
        }
    }

    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.x), v.dot(self.y), v.dot(self.z))
    }

    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.x * v.x + self.y * v.y + self.z * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal_and_round_trip() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.4, 0.5).normalize(),
            Vec3::new(1e-7, 0.0, -1.0).normalize(),
        ] {
            let f = Frame::from_z(n);
            assert!((f.x.length() - 1.0).abs() < 1e-5);
            assert!((f.y.length() - 1.0).abs() < 1e-5);
            assert!(
                f.x.dot(f.y).abs() < 1e-5 && f.x.dot(f.z).abs() < 1e-5 && f.y.dot(f.z).abs() < 1e-5
            );
            let v = Vec3::new(0.2, 0.7, -0.1);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
            assert!((f.x.cross(f.y) - f.z).length() < 1e-5, "right-handed");
        }
    }
}
