//! Splits a job into tiles and progressive passes of tasks (pure; the store persists the plan).
//!
//! Pass 0 gives every tile one sample, so a complete preview appears after one sample per pixel;
//! each later pass covers twice the samples of the one before, so the image sharpens everywhere at
//! once. A task's samples are capped so that it stays a few seconds of single-thread work: long
//! tasks would leave workers idle at the end of a job.

use pathfarm_tracer::Tile;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlannedTask {
    pub tile_index: u32,
    pub pass: u32,
    pub sample_begin: u32,
    pub sample_end: u32,
}

/// The sample ranges of the passes: [0,1), [1,3), [3,7), … each at most `max_per_pixel` long.
pub fn pass_ranges(spp: u32, max_per_pixel: u32) -> Vec<(u32, u32)> {
    let max_per_pixel = max_per_pixel.max(1);
    let mut out = Vec::new();
    let mut begin = 0u32;
    let mut len = 1u32;
    while begin < spp {
        let end = begin.saturating_add(len.min(max_per_pixel)).min(spp);
        out.push((begin, end));
        begin = end;
        len = len.saturating_mul(2);
    }
    out
}

/// How many passes [`pass_ranges`] makes, computed without building them: the passes that double
/// (at most 32 of them), then the rest in steps of `max_per_pixel`.
pub fn pass_count(spp: u32, max_per_pixel: u32) -> u64 {
    let (spp, cap) = (spp as u64, max_per_pixel.max(1) as u64);
    let (mut begin, mut len, mut n) = (0u64, 1u64, 0u64);
    while begin < spp && len < cap {
        begin = (begin + len).min(spp);
        len *= 2;
        n += 1;
    }
    n + (spp - begin).div_ceil(cap)
}

/// The samples per pixel of a task at most, so that a task of a full tile stays within
/// `max_task_samples` samples.
pub fn max_per_pixel(tile_size: u32, max_task_samples: u64) -> u32 {
    let tile_pixels = (tile_size.max(1) as u64).pow(2);
    (max_task_samples / tile_pixels).clamp(1, u32::MAX as u64) as u32
}

/// The number of tiles and of tasks [`plan`] makes for these settings, computed without planning
/// (so that a submission can be checked against the limits before anything is allocated). The
/// task count saturates at `u64::MAX`.
pub fn plan_size(
    width: u32,
    height: u32,
    tile_size: u32,
    spp: u32,
    max_task_samples: u64,
) -> (u64, u64) {
    let ts = tile_size.max(1);
    let tiles = width.div_ceil(ts) as u64 * height.div_ceil(ts) as u64;
    let passes = pass_count(spp, max_per_pixel(ts, max_task_samples));
    (tiles, tiles.saturating_mul(passes))
}

/// Tiles in row-major order and the tasks of every pass, pass by pass. The caller checks
/// [`plan_size`] against its limits first: this allocates every task.
pub fn plan(
    width: u32,
    height: u32,
    tile_size: u32,
    spp: u32,
    max_task_samples: u64,
) -> (Vec<Tile>, Vec<PlannedTask>) {
    let tiles = Tile::grid(width, height, tile_size.max(1));
    let max_per_pixel = max_per_pixel(tile_size, max_task_samples);
    let mut tasks = Vec::new();
    for (pass, (b, e)) in pass_ranges(spp, max_per_pixel).into_iter().enumerate() {
        for tile_index in 0..tiles.len() as u32 {
            tasks.push(PlannedTask {
                tile_index,
                pass: pass as u32,
                sample_begin: b,
                sample_end: e,
            });
        }
    }
    (tiles, tasks)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_cover_every_sample_once() {
        for spp in [1, 2, 3, 7, 64, 100, 1024] {
            for cap in [1, 3, 16, 1 << 20] {
                let r = pass_ranges(spp, cap);
                assert_eq!(r[0], (0, 1));
                assert_eq!(r.last().unwrap().1, spp);
                for w in r.windows(2) {
                    assert_eq!(w[0].1, w[1].0);
                    assert!(w[1].1 - w[1].0 <= cap.max(1));
                }
            }
        }
        assert_eq!(pass_ranges(10, 100), vec![(0, 1), (1, 3), (3, 7), (7, 10)]);
    }

    #[test]
    fn plan_tiles_and_tasks() {
        let (tiles, tasks) = plan(100, 50, 32, 8, 1 << 20);
        assert_eq!(tiles.len(), 4 * 2);
        assert_eq!(tasks.len(), 8 * 4); // passes [0,1) [1,3) [3,7) [7,8)
        let covered: u64 = tasks
            .iter()
            .map(|t| {
                tiles[t.tile_index as usize].pixel_count() * (t.sample_end - t.sample_begin) as u64
            })
            .sum();
        assert_eq!(covered, 100 * 50 * 8);
        // The first pass holds every tile before any tile gets a second sample.
        assert!(tasks[..tiles.len()].iter().all(|t| t.pass == 0));
    }

    #[test]
    fn plan_size_matches_the_plan() {
        for spp in [1, 2, 3, 7, 8, 64, 100, 1023, 1024, 1025, 5000] {
            for cap in [1, 2, 3, 16, 1000, 1 << 20, u32::MAX] {
                assert_eq!(
                    pass_count(spp, cap),
                    pass_ranges(spp, cap).len() as u64,
                    "spp {spp}, cap {cap}"
                );
            }
        }
        for (w, h, ts, spp, max) in [
            (100, 50, 32, 8, 1 << 20),
            (1, 1, 4096, 1, 1),
            (65, 64, 64, 300, 4096 * 10),
            (17, 9, 1, 5, 3),
            (512, 300, 7, 40, 1000),
        ] {
            let (tiles, tasks) = plan(w, h, ts, spp, max);
            assert_eq!(
                plan_size(w, h, ts, spp, max),
                (tiles.len() as u64, tasks.len() as u64),
                "{w}x{h} tile {ts} spp {spp} max {max}"
            );
        }
        // The review's case, computed without a single allocation: 67 million tiles, 21 passes.
        assert_eq!(
            plan_size(8192, 8192, 1, 1 << 20, 4 << 20),
            (1 << 26, 21 << 26)
        );
        assert_eq!(pass_count(u32::MAX, 1), u32::MAX as u64);
    }
}
