use glam::{Vec2, Vec3};

/// A parallel projection. `ymag` is the half-height of the view; the half-width follows from the
/// image's aspect ratio (glTF's `xmag` is ignored because the image size comes from the settings).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orthographic {
    pub ymag: f32,
}

impl Orthographic {
    #[inline]
    pub fn local_ray(&self, ndc: Vec2, aspect: f32) -> (Vec3, Vec3) {
        (
            Vec3::new(ndc.x * self.ymag * aspect, ndc.y * self.ymag, 0.0),
            -Vec3::Z,
        )
    }
}
