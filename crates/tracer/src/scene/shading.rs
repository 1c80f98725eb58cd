//! The BSDF at a surface point: a material's template moved there, or its textures shaded there.

use super::{Hit, Scene, SurfaceInteraction};
use crate::bsdf::Bsdf;
use glam::Vec3;

impl Scene {
    /// The shading normal and the BSDF of textured material `material` at `hit`, whose
    /// interpolated shading normal is `ns` and tangent `tangent`: what [`Scene::bsdf_at`] reads
    /// there, the BSDF in a frame of its own (`Bsdf::at` moves it to the normal), for a material
    /// without a clear coat (whose normal it leaves out).
    pub(crate) fn textured_bsdf(
        &self,
        material: u32,
        hit: &Hit,
        ns: Vec3,
        tangent: Option<glam::Vec4>,
    ) -> (Vec3, Bsdf) {
        let m = &self.materials[material as usize];
        let shading = m.shade(&self.textures, &self.hit_uv(hit), ns, tangent);
        let bsdf = Bsdf::new(shading.params, Vec3::Z, Vec3::Z, None);
        (shading.normal, bsdf)
    }

    /// The BSDF at a surface point: the material's textures evaluated there, or, for a material
    /// without them, its BSDF made once at build time and moved to the point (the same value).
    #[inline]
    pub fn bsdf_at(&self, si: &SurfaceInteraction) -> Bsdf {
        self.bsdf_of(si.material, si.ns, si.ng, si.tangent, || si.uv)
    }

    /// Material `material`'s BSDF template (`Bsdf::at` makes its BSDF at a point), where it has
    /// one (not textured).
    pub(crate) fn bsdf_template(&self, material: u32) -> Option<&Bsdf> {
        self.bsdf_templates.get(material as usize)?.as_ref()
    }

    /// [`Scene::bsdf_at`] at a hit whose normals (`ns`, `ng`) and tangent are known, its texture
    /// coordinates read only if the material is textured (the wavefront's lanes, which make the
    /// surface's parts in their own steps).
    #[inline]
    pub(crate) fn hit_bsdf(
        &self,
        material: u32,
        hit: &Hit,
        ns: Vec3,
        ng: Vec3,
        tangent: Option<glam::Vec4>,
    ) -> Bsdf {
        self.bsdf_of(material, ns, ng, tangent, || self.hit_uv(hit))
    }

    #[inline(always)]
    fn bsdf_of(
        &self,
        material: u32,
        ns: Vec3,
        ng: Vec3,
        tangent4: Option<glam::Vec4>,
        uv: impl FnOnce() -> [glam::Vec2; 2],
    ) -> Bsdf {
        let tangent = tangent4.map(|t| t.truncate());
        if let Some(Some(template)) = self.bsdf_templates.get(material as usize) {
            return template.at(ns, ng, tangent);
        }
        let m = &self.materials[material as usize];
        let shading = m.shade(&self.textures, &uv(), ns, tangent4);
        Bsdf::with_coat_normal(
            shading.params,
            shading.normal,
            ng,
            tangent,
            shading.coat_normal,
        )
    }
}
