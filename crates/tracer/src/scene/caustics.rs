//! The scene's caustic guide (`crate::guide`): built on first use, by whichever render needs it
//! first (its photons are part of rendering, not of loading), and then shared by every render of
//! the scene.

use super::Scene;
use crate::guide::CausticGuide;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

impl Scene {
    /// The caustic guide, built now if it has not been: None for a scene without one (no
    /// specular object that a light reaches, or one made [`Scene::without_caustic_guide`]).
    pub fn caustic_guide(&self) -> Option<&CausticGuide> {
        self.caustics
            .get_or_init(|| {
                let start = Instant::now();
                let guide = CausticGuide::build(self)?;
                tracing::info!(
                    photons = guide.photons,
                    landed = guide.landed,
                    cells = guide.cells(),
                    bytes = guide.bytes(),
                    seconds = start.elapsed().as_secs_f64(),
                    "caustic guide built"
                );
                Some(Arc::new(guide))
            })
            .as_deref()
    }

    /// The same scene rendered without a caustic guide: every continuation drawn from the BSDF
    /// alone (for comparisons).
    pub fn without_caustic_guide(mut self) -> Self {
        self.caustics = OnceLock::from(None);
        self
    }

    /// Whether material `material` has delta lobes only (a perfect mirror, smooth glass) at every
    /// point: the guide's casters. (A textured one is not counted.)
    pub(crate) fn is_specular_material(&self, material: u32) -> bool {
        self.bsdf_template(material)
            .is_some_and(|bsdf| !bsdf.has_non_delta())
    }
}
