//! The reference an image is measured against: the exact value where one is known, otherwise a
//! long render of the project's own, rendered once and cached as an EXR (its per-pixel variance
//! included, so that its own noise can be taken out of the measured error).

use crate::error::BenchError;
use crate::render::render_range;
use crate::scenes::{BenchScene, LoadedScene};
use pathfarm_tracer::output::{decode_exr, encode_exr, ExrChannels};
use pathfarm_tracer::{Accumulation, RenderSettings};
use std::path::{Path, PathBuf};

/// Per-pixel reference luminance and the variance of each value (zero where exact).
#[derive(Clone, Debug)]
pub struct Reference {
    pub luminance: Vec<f64>,
    /// Estimated variance of each reference pixel (of its mean), to subtract from measured MSE.
    pub variance: Vec<f64>,
    /// Exact (analytic) rather than rendered.
    pub exact: bool,
    /// Samples per pixel of the rendered reference (0 when exact).
    pub spp: u32,
    /// Seconds spent rendering it in this run (0 when exact or read from the cache).
    pub render_seconds: f64,
    /// Read from the cache.
    pub cached: bool,
    pub width: u32,
    pub height: u32,
}

impl Reference {
    pub fn mean(&self) -> f64 {
        self.luminance.iter().sum::<f64>() / self.luminance.len().max(1) as f64
    }

    /// Standard error of [`Reference::mean`] from its per-pixel variances.
    pub fn mean_standard_error(&self) -> f64 {
        self.variance.iter().sum::<f64>().sqrt() / self.luminance.len().max(1) as f64
    }

    /// Mean per-pixel variance: the MSE the reference's own noise adds to every measurement.
    pub fn noise_mse(&self) -> f64 {
        self.variance.iter().sum::<f64>() / self.variance.len().max(1) as f64
    }

    fn from_accumulation(acc: &Accumulation, spp: u32) -> Reference {
        Reference {
            luminance: acc.pixels.iter().map(|p| luminance(p.mean())).collect(),
            variance: acc
                .pixels
                .iter()
                .map(|p| p.variance_of_mean().unwrap_or(0.0))
                .collect(),
            exact: false,
            spp,
            render_seconds: 0.0,
            cached: false,
            width: acc.width,
            height: acc.height,
        }
    }
}

/// Rec. 709 luminance, as the tracer computes it.
pub fn luminance(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// The cache file of a rendered reference.
fn cache_path(
    dir: &Path,
    scene: &BenchScene,
    loaded: &LoadedScene,
    s: &RenderSettings,
    spp: u32,
) -> PathBuf {
    dir.join(format!(
        "{}-{:016x}-{}x{}-{}spp-seed{}-{}-{}-{}.exr",
        scene.name,
        loaded.content_hash,
        s.width,
        s.height,
        spp,
        s.seed,
        s.direct,
        s.sampler,
        env!("CARGO_PKG_VERSION")
    ))
}

/// The reference for `scene` at the size of `settings`: exact, cached, or rendered now with
/// `settings` (which should be the strategy trusted most: MIS) at `spp` samples per pixel.
pub fn reference(
    scene: &BenchScene,
    loaded: &LoadedScene,
    settings: &RenderSettings,
    spp: u32,
    cache_dir: &Path,
) -> Result<Reference, BenchError> {
    let pixels = (settings.width * settings.height) as usize;
    if let Some(v) = scene.exact {
        return Ok(Reference {
            luminance: vec![v; pixels],
            variance: vec![0.0; pixels],
            exact: true,
            spp: 0,
            render_seconds: 0.0,
            cached: false,
            width: settings.width,
            height: settings.height,
        });
    }
    let path = cache_path(cache_dir, scene, loaded, settings, spp);
    if let Ok(bytes) = std::fs::read(&path) {
        match decode_cached(&bytes, settings, spp) {
            Ok(r) => return Ok(r),
            Err(message) => {
                tracing::warn!(path = %path.display(), %message, "ignoring a bad cached reference")
            }
        }
    }
    tracing::info!(
        scene = scene.name,
        spp,
        "rendering the reference (cached for later runs)"
    );
    // In chunks, so the log shows progress on a long reference.
    let mut acc: Option<Accumulation> = None;
    let mut seconds = 0.0;
    let chunk = (spp / 8).max(1);
    let mut begin = 0;
    while begin < spp {
        let end = (begin + chunk).min(spp);
        let r = render_range(&loaded.scene, settings, begin..end);
        seconds += r.seconds;
        match &mut acc {
            None => acc = Some(r.acc),
            Some(a) => a
                .merge(&r.acc)
                .map_err(|e| BenchError::Invalid(e.to_string()))?,
        }
        begin = end;
        tracing::info!(scene = scene.name, done = end, spp, "reference pass");
    }
    let acc = acc.ok_or_else(|| BenchError::Invalid("reference of 0 samples per pixel".into()))?;
    let bytes = encode_exr(
        &acc,
        ExrChannels {
            variance: true,
            samples: false,
        },
    )
    .map_err(|e| BenchError::Cache {
        path: path.clone(),
        message: e.to_string(),
    })?;
    crate::error::write_file(&path, &bytes)?;
    let mut r = Reference::from_accumulation(&acc, spp);
    r.render_seconds = seconds;
    Ok(r)
}

fn decode_cached(bytes: &[u8], settings: &RenderSettings, spp: u32) -> Result<Reference, String> {
    let img = decode_exr(bytes).map_err(|e| e.to_string())?;
    if img.width != settings.width as usize || img.height != settings.height as usize {
        return Err(format!("size {}×{}", img.width, img.height));
    }
    let (r, g, b) = (
        img.channel("R").map_err(|e| e.to_string())?,
        img.channel("G").map_err(|e| e.to_string())?,
        img.channel("B").map_err(|e| e.to_string())?,
    );
    let var = img.channel("variance").map_err(|e| e.to_string())?;
    Ok(Reference {
        luminance: (0..r.len())
            .map(|i| luminance([r[i] as f64, g[i] as f64, b[i] as f64]))
            .collect(),
        variance: var.iter().map(|&v| v as f64).collect(),
        exact: false,
        spp,
        render_seconds: 0.0,
        cached: true,
        width: settings.width,
        height: settings.height,
    })
}
