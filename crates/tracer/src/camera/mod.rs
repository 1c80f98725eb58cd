//! Cameras: a closed set of projections ([`Projection`]), each in its own file, placed in the world
//! by the camera node's transform. The camera looks down its local −Z with +Y up (glTF convention).
//! The image size (and so the aspect ratio) comes from the render settings, never from the file.

mod orthographic;
mod perspective;

pub use orthographic::Orthographic;
pub use perspective::Perspective;

use crate::geometry::Ray;
use glam::{Affine3A, Vec2, Vec3};

/// The projection of a camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    Perspective(Perspective),
    Orthographic(Orthographic),
}

/// A camera in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub projection: Projection,
    /// Camera-to-world transform (rigid part used: rotation and translation; scale is ignored).
    pub to_world: Affine3A,
}

impl Camera {
    pub fn new(projection: Projection, to_world: Affine3A) -> Self {
        Camera {
            projection,
            to_world,
        }
    }

    /// The primary ray through `film` (pixel coordinates, (0,0) the top-left corner of the image,
    /// (width, height) the bottom-right) of a `width × height` image.
    #[inline]
    pub fn generate_ray(&self, film: Vec2, width: u32, height: u32) -> Ray {
        // Normalized device coordinates in [-1, 1], y up.
        let ndc = Vec2::new(
            2.0 * film.x / width as f32 - 1.0,
            1.0 - 2.0 * film.y / height as f32,
        );
        let aspect = width as f32 / height as f32;
        let (o, d) = match &self.projection {
            Projection::Perspective(p) => p.local_ray(ndc, aspect),
            Projection::Orthographic(p) => p.local_ray(ndc, aspect),
        };
        let o = self.to_world.transform_point3(o);
        let d = self.to_world.transform_vector3(d).normalize();
        Ray::new(o, d)
    }

    /// A default camera for scenes without one: perspective, 45° vertical field of view, looking at
    /// `center` from +Z at a distance that frames a sphere of `radius`.
    pub fn framing(center: Vec3, radius: f32) -> Self {
        let yfov = 45f32.to_radians();
        let dist = radius / crate::math::det::sin_cos(0.5 * yfov).0 * 1.1;
        Camera::new(
            Projection::Perspective(Perspective::new(yfov)),
            Affine3A::from_translation(center + Vec3::Z * dist),
        )
    }
}
