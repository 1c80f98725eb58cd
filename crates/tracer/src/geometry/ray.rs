use glam::Vec3;

/// A ray `o + t·d`, t ∈ (0, t_max). `d` need not be normalized, but the renderer always passes unit
/// directions so that t is a distance.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub o: Vec3,
    pub d: Vec3,
}

impl Ray {
    #[inline]
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Ray { o, d }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}
