//! Rendering for measurement: the tracer's own function for a run of samples (`render_samples`, what
//! `render_tile` runs), driven here so that the largest single sample value and the invalid samples
//! can be observed on the way. The pixels are accumulated exactly as `pathfarm_tracer::render_tile`
//! does, so the images are the same bits.

use pathfarm_tracer::math::luminance;
use pathfarm_tracer::{render_samples, Accumulation, PixelAccum, RenderSettings, Scene};
use rayon::prelude::*;
use std::ops::Range;
use std::time::Instant;

/// One rendered sample range of the whole image, with what was observed while rendering it.
pub struct Rendered {
    pub acc: Accumulation,
    /// The largest luminance of a single valid sample.
    pub max_sample: f64,
    /// Samples dropped as NaN, infinite, negative or absurdly large.
    pub invalid: u64,
    pub seconds: f64,
}

/// Renders `samples` of every pixel on the current rayon pool.
pub fn render_range(scene: &Scene, settings: &RenderSettings, samples: Range<u32>) -> Rendered {
    let started = Instant::now();
    let (w, h) = (settings.width, settings.height);
    let rows: Vec<(Vec<PixelAccum>, u64, f64, u64)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut pixels = vec![PixelAccum::default(); w as usize];
            let (mut rays, mut max_sample, mut invalid) = (0u64, 0f64, 0u64);
            let work = (0..w).flat_map(|x| samples.clone().map(move |index| (x, y, index)));
            render_samples(scene, settings, work, |x, _, _, r| {
                rays += r.rays as u64;
                if pixels[x as usize].add_sample(r.radiance) {
                    max_sample = max_sample.max(luminance(r.radiance) as f64);
                } else {
                    invalid += 1;
                }
            });
            (pixels, rays, max_sample, invalid)
        })
        .collect();
    let mut acc = Accumulation::new(0, 0, w, 0);
    acc.height = h;
    acc.pixels.reserve((w * h) as usize);
    let (mut max_sample, mut invalid) = (0f64, 0u64);
    for (pixels, rays, m, inv) in rows {
        acc.pixels.extend_from_slice(&pixels);
        acc.rays += rays;
        acc.invalid_count += inv;
        max_sample = max_sample.max(m);
        invalid += inv;
    }
    Rendered {
        acc,
        max_sample,
        invalid,
        seconds: started.elapsed().as_secs_f64(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};

    #[test]
    fn matches_the_tracer_bit_for_bit_in_any_split() {
        let bytes = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cornell.gltf"
        ))
        .expect("scenes/cornell.gltf");
        let scene = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
        let settings = RenderSettings {
            seed: 7,
            ..RenderSettings::new(12, 9)
        };
        let whole = pathfarm_tracer::render_image(&scene, &settings, 5, 0..6, &|_| {});
        let mut parts = render_range(&scene, &settings, 0..2).acc;
        parts
            .merge(&render_range(&scene, &settings, 2..6).acc)
            .unwrap();
        assert_eq!(parts.pixels, whole.pixels);
        assert_eq!(parts.rays, whole.rays);
        let r = render_range(&scene, &settings, 0..6);
        assert!(r.max_sample > 0.0 && r.invalid == 0);
    }
}
