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
        match &self.projection {
            Projection::Perspective(p) => {
                self.ray_through(film, width, height, |ndc, aspect| p.local_ray(ndc, aspect))
            }
            Projection::Orthographic(p) => {
                self.ray_through(film, width, height, |ndc, aspect| p.local_ray(ndc, aspect))
            }
        }
    }

    /// [`Camera::generate_ray`] with the projection's camera-space ray given as `local_ray` (the
    /// camera's own projection's). The wavefront's lanes call it in a loop over the lanes with the
    /// `match` on the projection outside, so that the loop is vectorised; both give the same bits.
    /// The transform is written out on the columns, as `Affine3A`'s is (the same operations in
    /// the same order, lane by lane).
    #[inline(always)]
    pub(crate) fn ray_through(
        &self,
        film: Vec2,
        width: u32,
        height: u32,
        local_ray: impl Fn(Vec2, f32) -> (Vec3, Vec3),
    ) -> Ray {
        // Normalized device coordinates in [-1, 1], y up.
        let ndc = Vec2::new(
            2.0 * film.x / width as f32 - 1.0,
            1.0 - 2.0 * film.y / height as f32,
        );
        let aspect = width as f32 / height as f32;
        let (o, d) = local_ray(ndc, aspect);
        let m = &self.to_world.matrix3;
        let (x_axis, y_axis, z_axis) = (
            Vec3::from(m.x_axis),
            Vec3::from(m.y_axis),
            Vec3::from(m.z_axis),
        );
        let linear = |v: Vec3| x_axis * v.x + y_axis * v.y + z_axis * v.z;
        let o = linear(o) + Vec3::from(self.to_world.translation);
        let d = linear(d).normalize();
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    /// `ray_through` writes the transform out on the columns; it must be `Affine3A`'s transform,
    /// followed by `normalize`, bit for bit (the images' bits depend on it), for both projections
    /// and transforms that turn, scale unevenly and move.
    #[test]
    fn rays_are_the_affine_transforms_bit_for_bit() {
        let mut rng = crate::testing::uniform_stream(0xca3e_7a11);
        let (width, height) = (37, 23);
        for case in 0..200 {
            let mut u = || rng();
            let to_world = Affine3A::from_scale_rotation_translation(
                Vec3::new(0.5 + u(), 0.5 + u(), 0.5 + u()),
                Quat::from_euler(glam::EulerRot::YXZ, 6.0 * u(), 6.0 * u(), 6.0 * u()),
                Vec3::new(u(), u(), u()) * 10.0 - 5.0,
            );
            let projection = if case % 2 == 0 {
                Projection::Perspective(Perspective::new(0.2 + 2.0 * u()))
            } else {
                Projection::Orthographic(Orthographic {
                    ymag: 0.1 + 3.0 * u(),
                })
            };
            let camera = Camera::new(projection, to_world);
            for _ in 0..50 {
                let film = Vec2::new(u() * width as f32, u() * height as f32);
                let ndc = Vec2::new(
                    2.0 * film.x / width as f32 - 1.0,
                    1.0 - 2.0 * film.y / height as f32,
                );
                let aspect = width as f32 / height as f32;
                let (o, d) = match &projection {
                    Projection::Perspective(p) => p.local_ray(ndc, aspect),
                    Projection::Orthographic(p) => p.local_ray(ndc, aspect),
                };
                let want = (
                    to_world.transform_point3(o),
                    to_world.transform_vector3(d).normalize(),
                );
                let got = camera.generate_ray(film, width, height);
                let bits = |v: Vec3| v.to_array().map(f32::to_bits);
                assert_eq!(
                    (bits(got.o), bits(got.d)),
                    (bits(want.0), bits(want.1)),
                    "case {case}, film {film}"
                );
            }
        }
    }
}
