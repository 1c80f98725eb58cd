//! The wavefront integrator: [`LANES`] camera paths of one thread traced side by side, their
//! shading done one step at a time for all of them in SIMD lanes.
//!
//! It is the path integrator of `path.rs`, not an approximation of it: every lane runs exactly the
//! scalar integrator's operations on its own path, in the same order, through the same functions
//! (the Lambertian lobe of `bsdf::lambert_at`, `light_sample_value`, `survival`, the Sobol values,
//! the ray-origin offset), so each sample's radiance has the same bits as
//! [`super::trace_path`]'s. The lanes are plain arrays and their loops plain Rust: the compiler
//! vectorises them, and IEEE arithmetic lane by lane rounds as it does one value at a time (Rust
//! never fuses a multiply and an add on its own). Tested sample by sample against `trace_path`.
//!
//! It takes every scene (see [`DiffuseScene`]) lit by emissive triangles, punctual lamps or the
//! environment, rendered with MIS and the Sobol sampler on an x86-64 processor with AVX2 or
//! AVX-512, unless the scene has a caustic guide (`crate::guide`), whose mixture only the scalar
//! integrator draws; everything else runs the scalar integrator, with the same result it always
//! had. Its vector code models pure Lambertian and glossy materials (a rough metal, a Lambertian
//! base under a rough specular layer, or a mix: `bsdf::GlossyLobes`, evaluated and sampled in the
//! lanes by the BSDF's own code), untextured or with textures that keep their kind (a base
//! colour, a metallic-roughness texture and a normal map: each hit's texels, tangent and mapped
//! normal read by `Lanes::shade_texels`); a purely specular material (a perfect mirror, smooth
//! glass: delta lobes only) is sampled lane by lane through `Bsdf::sample`, and any other (a
//! general material) has its BSDF made at each hit, evaluated and sampled lane by lane. Vertex
//! normals are interpolated as `Scene::surface` does, and instanced meshes moved to world space
//! as it moves them (`Scene::instance_triangle`). Ray queries stay scalar, one lane at a time
//! (two a walk), through the scene's BVH, each with its lane's alpha-coverage value where the
//! scene has alpha.
//!
//! A lane whose path ends takes the next (pixel, sample) of its thread's work at once, so lanes
//! do not idle while the longest path of a group finishes. Results therefore arrive out of index
//! order; the accumulation is exact integer arithmetic, so the order does not change its bits.

mod lanes;
mod lights;
#[cfg(test)]
mod tests;

use super::PathResult;
use crate::isa::Isa;
use crate::light::Lights;
use crate::material::Material;
use crate::scene::Scene;
use crate::settings::{DirectStrategy, RenderSettings, SamplerKind};
use glam::Vec3;
use lanes::Lanes;
use lights::LightTable;

/// Paths traced side by side: one AVX-512 register of `f32`, or two AVX2 registers.
pub(crate) const LANES: usize = 16;

/// A vector per lane, one array per coordinate.
#[derive(Clone, Copy, Debug)]
pub(crate) struct V3 {
    pub x: [f32; LANES],
    pub y: [f32; LANES],
    pub z: [f32; LANES],
}

impl V3 {
    pub const ZERO: V3 = V3 {
        x: [0.0; LANES],
        y: [0.0; LANES],
        z: [0.0; LANES],
    };

    #[inline(always)]
    pub fn get(&self, i: usize) -> Vec3 {
        Vec3::new(self.x[i], self.y[i], self.z[i])
    }

    #[inline(always)]
    pub fn set(&mut self, i: usize, v: Vec3) {
        self.x[i] = v.x;
        self.y[i] = v.y;
        self.z[i] = v.z;
    }
}

/// What a lane needs of a material, for a scene the wavefront can render.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct DiffuseMaterial {
    /// The sanitised base colour of the Lambertian lobe (zero for a specular or glossy material,
    /// so that the Lambertian code of `scatter` gives its lanes nothing).
    pub albedo: Vec3,
    /// A material of delta lobes only (a perfect mirror, smooth glass): its BSDF, sampled lane by
    /// lane after `scatter` (`Lanes::scatter_lane_by_lane`). None for the others.
    pub specular: Option<crate::bsdf::Bsdf>,
    /// A glossy material (a rough metal, a Lambertian base under a rough specular layer, or a
    /// mix: `bsdf::GlossyLobes`): its lobes, which the vector steps evaluate and sample beside the
    /// Lambertian's (`lanes/glossy.rs`). None for the others.
    pub glossy: Option<crate::bsdf::GlossyLobes>,
    /// The lobe is not black (`Bsdf::has_non_delta`): direct lighting is estimated.
    pub diffuse_on: bool,
    /// `Material::emission` towards the front side, and towards the back.
    pub emission_front: Vec3,
    pub emission_back: Vec3,
    /// Whether the material emits: a BSDF ray that hits it needs the light choice's density.
    pub emits: bool,
    /// It is textured (`Material::params_of_factors`): `Lanes::shade_texels` makes each hit's BSDF
    /// from its texels (`Scene::textured_bsdf`), and `albedo`, `glossy` and `diffuse_on` above
    /// are only its kind's (a Lambertian's or a glossy one's, which no texel changes).
    pub textured: bool,
    /// A material of none of the kinds above (a clear coat, a sheen, rough or partly smooth
    /// transmission, or textures that change its kind from texel to texel): each lane's BSDF is
    /// made at its hit as `Scene::bsdf_at` makes it (`Lanes::shade_general`), and evaluated and
    /// sampled lane by lane through the BSDF's own code (`lanes/general.rs`). Its `albedo` is
    /// zero, and `diffuse_on` only its factors' (a textured one's is its hit's).
    pub general: bool,
    /// It emits through an emissive texture: `emission_front` and `emission_back` are only its
    /// factor's, and the lanes read the texel where a ray meets it (`Lanes::trace_closest`) and
    /// where a light sample lands on it (`Lanes::take_light`).
    pub emissive_textured: bool,
}

/// A scene the wavefront integrator can render, and the per-material facts its lanes read. Built
/// with the scene; `None` for scenes that need more than the lanes model.
#[derive(Clone, Debug)]
pub(crate) struct DiffuseScene {
    pub materials: Vec<DiffuseMaterial>,
    /// The lights in the lanes' layout, for a scene that chooses its lights by power; None for
    /// one that chooses by the light tree, which each lane walks on its own, for one with an
    /// emissive texture, whose lanes sample on their own too (the texel depends on the point's
    /// barycentrics, which the table does not give), and for one without emissive triangles,
    /// where the walk finds none.
    pub lights: Option<Box<LightTable>>,
    /// Some mesh has tangents: each hit's BSDF frame is oriented by its tangent, as
    /// `Scene::bsdf_at` orients it (`Lanes::shade_texels`).
    pub tangents: bool,
    /// Some material's volume absorbs: the lanes track the medium each path is in
    /// (`lanes/volumes.rs`).
    pub absorbing: bool,
}

impl DiffuseScene {
    /// The lanes' view of a scene, if it has a light (emissive triangles, punctual lamps or an
    /// environment, one colour or an image). Each
    /// material is taken as the kind the vector steps model, if it is one: a pure Lambertian
    /// (emissive or not), glossy (`Bsdf::glossy_lobes`: rough, without transmission or layers)
    /// or made of delta lobes only (a perfect mirror, smooth glass, clear or absorbing: no light
    /// sample at its vertices), untextured or with textures that leave its kind as it is (base
    /// colour, normal map, metallic-roughness with the roughness above zero:
    /// `Material::params_of_factors`); any other is `general`. Emissive textures are read where
    /// rays meet them and light samples land.
    /// The one place that decides which scenes the lanes render.
    pub(crate) fn new(
        materials: &[Material],
        templates: &[Option<crate::bsdf::Bsdf>],
        textures: &[crate::material::Texture],
        mesh: &crate::geometry::Mesh,
        instances: &crate::geometry::Instances,
        lights: &Lights,
    ) -> Option<DiffuseScene> {
        let area = &lights.area;
        let tangents = std::iter::once(mesh)
            .chain(instances.prototypes.iter().map(|p| &p.mesh))
            .any(|m| m.tangents.is_some());
        // Without a light there is nothing for the lanes to speed up.
        if area.is_empty() && lights.punctual.is_empty() && lights.environment.is_none() {
            return None;
        }
        let mut out = Vec::with_capacity(materials.len());
        for (material, template) in materials.iter().zip(templates) {
            let vector_kind = |bsdf: &crate::bsdf::Bsdf| {
                bsdf.single_lobe() || bsdf.glossy_lobes().is_some() || !bsdf.has_non_delta()
            };
            // A textured material whose textures change only its lobes' colours and values
            // (`Material::params_of_factors`), Lambertian or glossy without transmission (whose
            // switch reads the base colour): its kind at every texel is its factors'.
            let of_factors = || {
                let p = material.params_of_factors(textures)?;
                let bsdf = crate::bsdf::Bsdf::new(p, Vec3::Z, Vec3::Z, None);
                let kind_fixed = bsdf.single_lobe() || bsdf.glossy_lobes().is_some();
                (kind_fixed && bsdf.params().transmission == 0.0).then_some(bsdf)
            };
            let (bsdf, textured) = match template {
                Some(bsdf) => (Some(*bsdf).filter(vector_kind), false),
                None => (of_factors(), true),
            };
            let no_uv = [glam::Vec2::ZERO; 2];
            let mut m = DiffuseMaterial {
                emission_front: material.emission(&[], &no_uv, true),
                emission_back: material.emission(&[], &no_uv, false),
                emits: material.is_emissive(),
                emissive_textured: material.is_emissive() && material.emissive_texture.is_some(),
                ..DiffuseMaterial::default()
            };
            match bsdf {
                Some(bsdf) => {
                    let specular = !bsdf.single_lobe() && !bsdf.has_non_delta();
                    m.albedo = match bsdf.single_lobe() {
                        true => bsdf.params().base_color,
                        false => Vec3::ZERO,
                    };
                    m.specular = specular.then_some(bsdf);
                    m.glossy = bsdf.glossy_lobes();
                    m.diffuse_on = bsdf.has_non_delta();
                    m.textured = textured;
                }
                None => {
                    m.general = true;
                    m.diffuse_on = template.is_none_or(|b| b.has_non_delta());
                }
            }
            out.push(m);
        }
        // Lights chosen by power are chosen in the lanes, from the table; by the tree, lane by lane.
        // Without area lights, the tree's path finds none (`AreaLights::sample`), as `trace_path`
        // samples none.
        let emissive_textures = out.iter().any(|m| m.emissive_textured);
        let lights = match area.has_tree() || area.is_empty() || emissive_textures {
            false => Some(LightTable::new(area, &out, &mesh.material)?),
            true => None,
        };
        // A volume that absorbs nothing changes no throughput's bits (× e⁻⁰ = × 1): only
        // absorbing ones are tracked.
        let absorbing = materials
            .iter()
            .any(|m| m.volume.is_some_and(|v| v.sigma_a != Vec3::ZERO));
        Some(DiffuseScene {
            materials: out,
            lights,
            tangents,
            absorbing,
        })
    }
}

/// The wavefront integrator for one render, when the scene and the settings are ones it models.
#[derive(Clone, Copy)]
pub(crate) struct Wavefront<'a> {
    scene: &'a Scene,
    diffuse: &'a DiffuseScene,
    settings: &'a RenderSettings,
    /// Proof that the processor runs the vector steps' build.
    isa: Isa,
}

impl<'a> Wavefront<'a> {
    /// The wavefront for this scene and these settings, or None when the scalar integrator must
    /// render them.
    pub(crate) fn new(scene: &'a Scene, settings: &'a RenderSettings) -> Option<Self> {
        let diffuse = scene.diffuse.as_ref()?;
        let supported =
            settings.direct == DirectStrategy::Mis && settings.sampler == SamplerKind::Sobol;
        if !supported {
            return None;
        }
        Some(Wavefront {
            scene,
            diffuse,
            settings,
            isa: Isa::detect()?,
        })
    }

    /// The same wavefront with the vector steps' build `isa`.
    #[cfg(test)]
    fn with_isa(self, isa: Isa) -> Self {
        Wavefront { isa, ..self }
    }

    /// Renders every `(x, y, sample index)` of `work` and hands each result to `each`, in no
    /// particular order. Each result is the one [`crate::render::render_sample`] gives.
    pub(crate) fn render(
        &self,
        work: impl Iterator<Item = (u32, u32, u32)>,
        each: impl FnMut(u32, u32, u32, PathResult),
    ) {
        let mut lanes = Lanes::new(self.scene, self.diffuse, self.settings);
        lanes.run(self.isa, work, each);
    }
}
