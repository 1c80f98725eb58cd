//! The render API that workers call: `render_tile(scene, settings, tile, sample range) → accumulation`.
//!
//! A pixel's samples depend only on (seed, pixel, sample index), and accumulation is exact integer
//! arithmetic, so any tiling, any split of the sample range, and any number of threads give the same
//! bits.

mod tile;

pub use tile::{Tile, TileError};

use crate::accumulation::{Accumulation, InvalidSample, PixelAccum, MAX_RECORDED_INVALID};
use crate::integrator::{trace_path, PathResult, Wavefront};
use crate::sampler::{dims, PixelSampler};
use crate::scene::Scene;
use crate::settings::RenderSettings;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::ops::Range;

/// Renders samples `samples` of every pixel of `tile`. Rows are rendered in parallel on the current
/// rayon thread pool (install a pool to choose the thread count); the result does not depend on it.
pub fn render_tile(
    scene: &Scene,
    settings: &RenderSettings,
    tile: Tile,
    samples: Range<u32>,
) -> Accumulation {
    // The caustic guide is built (once per scene, on threads of its own) before the parallel
    // loop rather than in it, where the loop's threads would wait for it one by one.
    scene.caustic_guide();
    let rows: Vec<(Vec<PixelAccum>, u64, u64, Vec<InvalidSample>)> = (tile.y0
        ..tile.y0 + tile.height)
        .into_par_iter()
        .map(|y| {
            render_row(
                scene,
                settings,
                y,
                tile.x0..tile.x0 + tile.width,
                samples.clone(),
            )
        })
        .collect();
    // Rows arrive in order; their pixels are appended rather than written into a zeroed image.
    let mut acc = Accumulation::new(tile.x0, tile.y0, tile.width, 0);
    acc.height = tile.height;
    acc.pixels.reserve(tile.pixel_count() as usize);
    for (pixels, rays, invalid_count, invalid) in rows {
        acc.pixels.extend_from_slice(&pixels);
        acc.rays += rays;
        acc.invalid_count += invalid_count;
        if acc.invalid.len() < MAX_RECORDED_INVALID {
            acc.invalid.extend(invalid);
            acc.invalid.truncate(MAX_RECORDED_INVALID);
        }
    }
    acc
}

/// Renders samples `samples` of pixels `xs` of row `y`. Results may arrive out of order (see
/// [`render_samples`]): each is added to its pixel (exact integer sums, so the order does not
/// matter), and the invalid samples are recorded in (x, index) order, so that the record does not
/// depend on it either.
fn render_row(
    scene: &Scene,
    settings: &RenderSettings,
    y: u32,
    xs: Range<u32>,
    samples: Range<u32>,
) -> (Vec<PixelAccum>, u64, u64, Vec<InvalidSample>) {
    let x0 = xs.start;
    let mut pixels = vec![PixelAccum::default(); xs.len()];
    let mut rays = 0u64;
    let mut invalid_count = 0u64;
    let mut invalid = Vec::new();
    let work = xs.flat_map(|x| samples.clone().map(move |index| (x, y, index)));
    render_samples(scene, settings, work, |x, y, index, r| {
        rays += r.rays as u64;
        if !pixels[(x - x0) as usize].add_sample(r.radiance) {
            invalid_count += 1;
            invalid.push(InvalidSample { x, y, index });
            if invalid.len() >= 4 * MAX_RECORDED_INVALID {
                // Only the first ones in (x, index) order are kept: bound the list as it grows.
                invalid.sort_by_key(|s| (s.x, s.index));
                invalid.truncate(MAX_RECORDED_INVALID);
            }
            // Counted and recorded, not logged one by one: callers report the count and the
            // first examples once (a broken scene can make every sample invalid).
            tracing::trace!(x, y, index, radiance = ?r.radiance, "invalid sample dropped (NaN, infinite, negative or huge)");
        }
    });
    invalid.sort_by_key(|s| (s.x, s.index));
    invalid.truncate(MAX_RECORDED_INVALID);
    (pixels, rays, invalid_count, invalid)
}

/// Renders every `(x, y, sample index)` of `work` on the calling thread and hands each result to
/// `each`: the value [`render_sample`] gives it. Scenes and settings the wavefront integrator
/// models (`integrator/wavefront`) are rendered by it, several paths at a time, and their results
/// arrive in no particular order; the others are rendered one path at a time, in `work`'s order.
pub fn render_samples(
    scene: &Scene,
    settings: &RenderSettings,
    work: impl Iterator<Item = (u32, u32, u32)>,
    mut each: impl FnMut(u32, u32, u32, PathResult),
) {
    if let Some(wavefront) = Wavefront::new(scene, settings) {
        wavefront.render(work, each);
        return;
    }
    // The pixel's sampler is set up once for a run of samples of one pixel.
    let mut current: Option<(u32, u32, PixelSampler)> = None;
    for (x, y, index) in work {
        let sampler = match &mut current {
            Some((cx, cy, s)) if (*cx, *cy) == (x, y) => {
                s.set_index(index);
                *s
            }
            _ => {
                let s = PixelSampler::new(settings.sampler, settings.seed, x, y, index);
                current = Some((x, y, s));
                s
            }
        };
        each(x, y, index, render_with(scene, settings, &sampler, x, y));
    }
}

/// Renders one sample of one pixel, alone: the same value it has inside any tile or range. Use it to
/// re-render a sample reported as invalid.
#[inline]
pub fn render_sample(
    scene: &Scene,
    settings: &RenderSettings,
    x: u32,
    y: u32,
    index: u32,
) -> PathResult {
    let sampler = PixelSampler::new(settings.sampler, settings.seed, x, y, index);
    render_with(scene, settings, &sampler, x, y)
}

/// One sample of pixel (x, y), drawn from `sampler`.
#[inline]
fn render_with(
    scene: &Scene,
    settings: &RenderSettings,
    sampler: &PixelSampler,
    x: u32,
    y: u32,
) -> PathResult {
    let jitter = sampler.get2(dims::PIXEL);
    let film = Vec2::new(x as f32, y as f32) + jitter;
    let ray = scene
        .camera
        .generate_ray(film, settings.width, settings.height);
    if !ray.d.is_finite() {
        return PathResult {
            radiance: Vec3::splat(f32::NAN),
            rays: 0,
            vertices: 0,
        };
    }
    trace_path(scene, settings, sampler, ray)
}

/// Renders samples `samples` of the whole image, `tile_size` pixels square at a time, in parallel.
/// `progress` is called with the number of pixel-samples finished after each tile.
pub fn render_image(
    scene: &Scene,
    settings: &RenderSettings,
    tile_size: u32,
    samples: Range<u32>,
    progress: &(dyn Fn(u64) + Sync),
) -> Accumulation {
    let tiles = Tile::grid(settings.width, settings.height, tile_size.max(1));
    scene.caustic_guide(); // before the parallel loop (see `render_tile`)
    let done: Vec<Accumulation> = tiles
        .par_iter()
        .map(|&t| {
            let acc = render_tile(scene, settings, t, samples.clone());
            progress(t.pixel_count() * samples.len() as u64);
            acc
        })
        .collect();
    let mut image = Accumulation::new(0, 0, settings.width, settings.height);
    for acc in &done {
        // Tiles come from the image's own grid, so they always fit.
        let _ = image.merge(acc);
    }
    image
}
