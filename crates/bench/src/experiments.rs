//! The lecture experiments the project rests on, reproduced on the Cornell box at equal sample
//! counts: uniform hemisphere against light-area sampling, cosine against uniform hemisphere,
//! Russian roulette settings against time and noise, and 1, 32 and 1024 samples per pixel.

use crate::error::{write_file, BenchError};
use crate::metrics::measure;
use crate::reference::Reference;
use crate::render::render_range;
use crate::scenes::LoadedScene;
use crate::study::Config;
use pathfarm_tracer::output::encode_png;
use pathfarm_tracer::{Accumulation, DirectStrategy, RussianRoulette, SamplerKind};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One image of an experiment.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Entry {
    pub label: String,
    pub spp: u32,
    /// Rendering time of this image alone (for the spp ladder: of all its samples).
    pub seconds: f64,
    pub rays_per_sample: f64,
    pub rmse: f64,
    pub rel_rmse: f64,
    /// 1 / (MSE × seconds); `None` when the error is below the reference's noise.
    pub efficiency: Option<f64>,
    /// The PNG, relative to the report.
    pub image: String,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Experiments {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub equal_spp: u32,
    pub hemisphere_vs_light: Vec<Entry>,
    pub cosine_vs_hemisphere: Vec<Entry>,
    pub roulette_spp: u32,
    pub roulette: Vec<Entry>,
    pub spp_ladder: Vec<Entry>,
}

/// Sizes of the experiments.
#[derive(Clone, Copy, Debug)]
pub struct ExperimentOptions {
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    /// Samples per pixel of the strategy comparisons (the lecture's 100).
    pub equal_spp: u32,
    /// Samples per pixel of the roulette table.
    pub roulette_spp: u32,
    /// The side-by-side sample counts (1, 32, 1024).
    pub ladder: [u32; 3],
    pub exposure: f32,
}

/// The roulette settings of the table, in the lecture's words.
pub fn roulette_table_settings() -> Vec<(RussianRoulette, &'static str)> {
    vec![
        (RussianRoulette::Off, "no RR"),
        (
            RussianRoulette::Max,
            "survive with max throughput after the 4th vertex (the default until November 26)",
        ),
        (
            RussianRoulette::Threshold {
                terminate: 0.9,
                below: 0.1,
            },
            "terminate 90% below luminance 0.1",
        ),
        (
            RussianRoulette::Fixed(0.8),
            "survive 80% after the 2nd vertex",
        ),
        (
            RussianRoulette::Fixed(0.5),
            "survive 50% after the 2nd vertex",
        ),
        (
            RussianRoulette::Auto,
            "auto (the default): terminate 50% below luminance 0.25",
        ),
    ]
}

fn entry(
    label: String,
    acc: &Accumulation,
    seconds: f64,
    reference: &Reference,
    file: &str,
    out_dir: &Path,
    exposure: f32,
) -> Result<Entry, BenchError> {
    let m = measure(acc, reference);
    let rel = format!("images/{file}.png");
    let path = out_dir.join(&rel);
    let png = encode_png(acc, exposure).map_err(|e| BenchError::Image {
        path: path.clone(),
        message: e.to_string(),
    })?;
    write_file(&path, &png)?;
    let samples = acc.total_samples().max(1) as f64;
    let spp = (acc.total_samples() / acc.pixels.len().max(1) as u64) as u32;
    Ok(Entry {
        label,
        spp,
        seconds,
        rays_per_sample: acc.rays as f64 / samples,
        rmse: m.rmse,
        rel_rmse: m.rel_rmse,
        efficiency: (m.mse > 0.0).then(|| 1.0 / (m.mse * seconds.max(1e-9))),
        image: rel,
    })
}

/// Runs every experiment on `scene` (the Cornell box) and writes its images under
/// `out_dir/images/`.
pub fn run(
    scene_name: &str,
    scene: &LoadedScene,
    reference: &Reference,
    o: ExperimentOptions,
    out_dir: &Path,
) -> Result<Experiments, BenchError> {
    let config = |direct, rr| Config {
        direct,
        sampler: SamplerKind::Sobol,
        rr,
    };
    let equal = |direct: DirectStrategy| -> Result<Entry, BenchError> {
        let settings = config(direct, RussianRoulette::Auto).settings(o.width, o.height, o.seed);
        let r = render_range(&scene.scene, &settings, 0..o.equal_spp);
        tracing::info!(experiment = "equal spp", %direct, seconds = r.seconds, "rendered");
        entry(
            format!("{direct}, {} spp", o.equal_spp),
            &r.acc,
            r.seconds,
            reference,
            &format!("equal-spp-{direct}"),
            out_dir,
            o.exposure,
        )
    };
    let hemisphere = equal(DirectStrategy::Hemisphere)?;
    let light = equal(DirectStrategy::Light)?;
    let cosine = equal(DirectStrategy::Cosine)?;

    let mut roulette = Vec::new();
    for (i, (rr, words)) in roulette_table_settings().into_iter().enumerate() {
        let settings = config(DirectStrategy::Mis, rr).settings(o.width, o.height, o.seed);
        let r = render_range(&scene.scene, &settings, 0..o.roulette_spp);
        tracing::info!(experiment = "roulette", %rr, seconds = r.seconds, "rendered");
        roulette.push(entry(
            format!("{words} (`--rr {rr}`)"),
            &r.acc,
            r.seconds,
            reference,
            &format!("roulette-{i}"),
            out_dir,
            o.exposure,
        )?);
    }

    let mut ladder = Vec::new();
    let settings =
        config(DirectStrategy::Mis, RussianRoulette::Auto).settings(o.width, o.height, o.seed);
    let mut acc = Accumulation::new(0, 0, o.width, o.height);
    let (mut begin, mut seconds) = (0u32, 0.0);
    for spp in o.ladder {
        let r = render_range(&scene.scene, &settings, begin..spp.max(begin));
        seconds += r.seconds;
        let _ = acc.merge(&r.acc);
        begin = spp.max(begin);
        tracing::info!(experiment = "spp ladder", spp, seconds, "rendered");
        ladder.push(entry(
            format!("{spp} spp"),
            &acc,
            seconds,
            reference,
            &format!("spp-{spp}"),
            out_dir,
            o.exposure,
        )?);
    }

    Ok(Experiments {
        scene: scene_name.to_string(),
        width: o.width,
        height: o.height,
        equal_spp: o.equal_spp,
        hemisphere_vs_light: vec![hemisphere.clone(), light],
        cosine_vs_hemisphere: vec![cosine, hemisphere],
        roulette_spp: o.roulette_spp,
        roulette,
        spp_ladder: ladder,
    })
}
