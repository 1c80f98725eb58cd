use glam::{Vec2, Vec3};

/// A pinhole camera with a vertical field of view (glTF `perspective.yfov`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Perspective {
    pub yfov: f32,
    tan_half: f32,
}

impl Perspective {
    pub fn new(yfov: f32) -> Self {
        Perspective {
            yfov,
            tan_half: crate::math::det::tan(0.5 * yfov),
        }
    }

    /// Camera-space ray through normalized device coordinates `ndc` ∈ [-1, 1]².
    #[inline]
    pub fn local_ray(&self, ndc: Vec2, aspect: f32) -> (Vec3, Vec3) {
        let d = Vec3::new(ndc.x * self.tan_half * aspect, ndc.y * self.tan_half, -1.0);
        (Vec3::ZERO, d)
    }
}
