//! Splits a job into tiles and progressive passes of tasks (pure; the store persists the plan).
//!
//! Pass 0 gives every tile one sample, so a complete preview appears after one sample per pixel;
//! each later pass covers twice the samples of the one before, so the image sharpens everywhere at
//! once. A task's samples are capped so that it stays a few seconds of single-thread work: long
//! tasks would leave workers idle at the end of a job.
//!
//! A frame job's first pass is longer: its tasks of a full tile take at least
//! [`TaskSizes::min_frame`] samples. Each task costs the farm a lease, an upload and a merge
//! (about 14 ms, docs/benchmarks.md) whatever its samples, and an animation's small frames at one
//! sample a pixel would spend most of the job on that; a frame job's preview is each frame's first
//! pass, which comes early either way in the interleaved order.

//!
//! A frame job (an animation) plans each frame's tiles apart: tile `slot × tiles_per_frame + i`
//! is tile `i` of the frame in slot `slot` of the job's frame list. Its tasks are frame × tile ×
//! sample range, ordered by a rank the lease follows (`tasks.pass`): interleaved, the rank is the
//! pass, so every frame gets each pass before any frame gets the next; sequential, it is
//! `slot × passes + pass`, so each frame is finished before the next starts.

use pathfarm_tracer::Tile;
use pathfarm_wire::api::FrameOrder;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlannedTask {
    /// The tile's index in the job (for a frame job, counting every frame's tiles).
    pub tile_index: u32,
    /// The lease order's rank (the pass, for a still or an interleaved frame job).
    pub pass: u32,
    pub sample_begin: u32,
    pub sample_end: u32,
}

/// A tile of a job's plan: its rectangle, and for a frame job the frame it belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlannedTile {
    pub tile: Tile,
    pub frame: Option<i64>,
}

/// How many samples a plan's tasks take (the server's settings).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TaskSizes {
    /// Most samples in a task of a full tile ([`crate::ServerConfig::max_task_samples`]).
    pub max: u64,
    /// Fewest samples in a frame job's first-pass task of a full tile
    /// ([`crate::ServerConfig::min_frame_task_samples`]).
    pub min_frame: u64,
}

/// The samples per pixel of the first pass: one for a still job (a complete preview at one sample
/// a pixel), enough for [`TaskSizes::min_frame`] samples in a full tile for a frame job.
pub fn first_pass(tile_size: u32, sizes: TaskSizes, frame_job: bool) -> u32 {
    if !frame_job {
        return 1;
    }
    let tile_pixels = (tile_size.max(1) as u64).pow(2);
    sizes
        .min_frame
        .div_ceil(tile_pixels)
        .clamp(1, u32::MAX as u64) as u32
}

/// The sample ranges of the passes: [0,first), then each twice as long as the one before
/// ([0,1), [1,3), [3,7), … for `first` 1), each at most `max_per_pixel` long.
pub fn pass_ranges(spp: u32, first: u32, max_per_pixel: u32) -> Vec<(u32, u32)> {
    let max_per_pixel = max_per_pixel.max(1);
    let mut out = Vec::new();
    let mut begin = 0u32;
    let mut len = first.max(1);
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
pub fn pass_count(spp: u32, first: u32, max_per_pixel: u32) -> u64 {
    let (spp, cap) = (spp as u64, max_per_pixel.max(1) as u64);
    let (mut begin, mut len, mut n) = (0u64, first.max(1) as u64, 0u64);
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

/// The number of tiles and of tasks [`plan`] makes for these settings (of one frame, for a frame
/// job), computed without planning (so that a submission can be checked against the limits
/// before anything is allocated). The task count saturates at `u64::MAX`.
pub fn plan_size(
    width: u32,
    height: u32,
    tile_size: u32,
    spp: u32,
    sizes: TaskSizes,
    frame_job: bool,
) -> (u64, u64) {
    let ts = tile_size.max(1);
    let tiles = width.div_ceil(ts) as u64 * height.div_ceil(ts) as u64;
    let passes = pass_count(
        spp,
        first_pass(ts, sizes, frame_job),
        max_per_pixel(ts, sizes.max),
    );
    (tiles, tiles.saturating_mul(passes))
}

/// The plan of a frame job over `frames` (in their order), or of a still job (`frames` `None`):
/// [`plan`]'s tiles once per frame and its tasks in the order of `order` (see the module's
/// documentation). The caller checks [`plan_size`] times the frames against its limits first.
pub fn plan_frames(
    (width, height, tile_size, spp): (u32, u32, u32, u32),
    sizes: TaskSizes,
    frames: Option<&[i64]>,
    order: FrameOrder,
) -> (Vec<PlannedTile>, Vec<PlannedTask>) {
    let (tiles, tasks) = plan(width, height, tile_size, spp, sizes, frames.is_some());
    let Some(frames) = frames else {
        let tiles = tiles
            .into_iter()
            .map(|tile| PlannedTile { tile, frame: None })
            .collect();
        return (tiles, tasks);
    };
    let per_frame = tiles.len() as u32;
    let passes = tasks.last().map_or(0, |t| t.pass + 1);
    let all_tiles = frames
        .iter()
        .flat_map(|&f| {
            tiles.iter().map(move |&tile| PlannedTile {
                tile,
                frame: Some(f),
            })
        })
        .collect();
    let frame_task = |slot: u32, t: &PlannedTask| PlannedTask {
        tile_index: slot * per_frame + t.tile_index,
        pass: match order {
            FrameOrder::Interleaved => t.pass,
            FrameOrder::Sequential => slot * passes + t.pass,
        },
        ..t.clone()
    };
    let slots = 0..frames.len() as u32;
    let all_tasks = match order {
        // Pass by pass, each pass frame by frame.
        FrameOrder::Interleaved => (0..passes)
            .flat_map(|p| {
                let pass: Vec<&PlannedTask> = tasks.iter().filter(|t| t.pass == p).collect();
                slots
                    .clone()
                    .flat_map(move |slot| pass.clone().into_iter().map(move |t| (slot, t)))
            })
            .map(|(slot, t)| frame_task(slot, t))
            .collect(),
        FrameOrder::Sequential => slots
            .flat_map(|slot| tasks.iter().map(move |t| (slot, t)))
            .map(|(slot, t)| frame_task(slot, t))
            .collect(),
    };
    (all_tiles, all_tasks)
}

/// Tiles in row-major order and the tasks of every pass, pass by pass (of one frame, for a frame
/// job). The caller checks [`plan_size`] against its limits first: this allocates every task.
pub fn plan(
    width: u32,
    height: u32,
    tile_size: u32,
    spp: u32,
    sizes: TaskSizes,
    frame_job: bool,
) -> (Vec<Tile>, Vec<PlannedTask>) {
    let tiles = Tile::grid(width, height, tile_size.max(1));
    let max_per_pixel = max_per_pixel(tile_size, sizes.max);
    let first = first_pass(tile_size, sizes, frame_job);
    let mut tasks = Vec::new();
    for (pass, (b, e)) in pass_ranges(spp, first, max_per_pixel)
        .into_iter()
        .enumerate()
    {
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

    /// Tasks of at most `max` samples of a full tile; a frame job's first pass at least 1 024.
    fn sizes(max: u64) -> TaskSizes {
        TaskSizes {
            max,
            min_frame: 1024,
        }
    }

    #[test]
    fn passes_cover_every_sample_once() {
        for spp in [1, 2, 3, 7, 64, 100, 1024] {
            for cap in [1, 3, 16, 1 << 20] {
                for first in [1, 2, 5, 4096] {
                    let r = pass_ranges(spp, first, cap);
                    assert_eq!(r[0], (0, first.min(cap).min(spp)));
                    assert_eq!(r.last().unwrap().1, spp);
                    for w in r.windows(2) {
                        assert_eq!(w[0].1, w[1].0);
                        assert!(w[1].1 - w[1].0 <= cap.max(1));
                    }
                }
            }
        }
        assert_eq!(
            pass_ranges(10, 1, 100),
            vec![(0, 1), (1, 3), (3, 7), (7, 10)]
        );
        assert_eq!(
            pass_ranges(40, 4, 100),
            vec![(0, 4), (4, 12), (12, 28), (28, 40)]
        );
    }

    #[test]
    fn a_frame_jobs_first_pass_fills_its_tasks() {
        let sizes = sizes(1 << 20);
        // Still jobs: one sample a pixel first, whatever the tile.
        assert_eq!(first_pass(64, sizes, false), 1);
        // 1,024 samples: 1 a pixel in a 32² tile, 4 in a 16² tile, 1 024 in a single pixel.
        assert_eq!(first_pass(32, sizes, true), 1);
        assert_eq!(first_pass(16, sizes, true), 4);
        assert_eq!(first_pass(15, sizes, true), 5);
        assert_eq!(first_pass(1, sizes, true), 1024);
        // A 16² tile at 8 spp: passes [0,4) [4,8) for a frame, four passes for a still.
        let (_, frame) = plan(16, 16, 16, 8, sizes, true);
        let ranges: Vec<(u32, u32)> = frame
            .iter()
            .map(|t| (t.sample_begin, t.sample_end))
            .collect();
        assert_eq!(ranges, [(0, 4), (4, 8)]);
        assert_eq!(plan(16, 16, 16, 8, sizes, false).1.len(), 4);
    }

    #[test]
    fn plan_tiles_and_tasks() {
        let (tiles, tasks) = plan(100, 50, 32, 8, sizes(1 << 20), false);
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
    fn frame_plans_keep_each_frames_tiles_and_order_their_tasks() {
        let frames = [5, 1, 9];
        // Frame tasks of at least one sample: 8 tiles, passes [0,1) [1,3) [3,4).
        let sizes = TaskSizes {
            max: 1 << 20,
            min_frame: 1,
        };
        let one = plan(64, 32, 16, 4, sizes, true);
        assert_eq!(one.1.len(), 8 * 3);
        let (still_tiles, still_tasks) =
            plan_frames((64, 32, 16, 4), sizes, None, FrameOrder::Interleaved);
        assert_eq!(still_tasks, plan(64, 32, 16, 4, sizes, false).1);
        assert!(still_tiles.iter().all(|t| t.frame.is_none()));
        for order in [FrameOrder::Interleaved, FrameOrder::Sequential] {
            let (tiles, tasks) = plan_frames((64, 32, 16, 4), sizes, Some(&frames), order);
            assert_eq!(tiles.len(), 3 * 8);
            assert_eq!(tasks.len(), 3 * one.1.len());
            for (i, t) in tiles.iter().enumerate() {
                assert_eq!(t.frame, Some(frames[i / 8]));
                assert_eq!(t.tile, one.0[i % 8]);
            }
            // Every (tile, sample) of every frame once.
            let mut covered = vec![0u32; tiles.len()];
            for t in &tasks {
                covered[t.tile_index as usize] += t.sample_end - t.sample_begin;
            }
            assert!(covered.iter().all(|&c| c == 4), "{order:?}");
            // The lease takes tasks by (rank, insertion): ranks never fall in insertion order.
            assert!(
                tasks.windows(2).all(|w| w[0].pass <= w[1].pass),
                "{order:?}"
            );
            let slot = |t: &PlannedTask| t.tile_index / 8;
            match order {
                FrameOrder::Interleaved => {
                    // Every frame's first pass before any second pass.
                    assert!(tasks[..24].iter().all(|t| t.sample_begin == 0));
                    assert_eq!(tasks[..24].iter().map(slot).max(), Some(2));
                }
                FrameOrder::Sequential => {
                    assert!(tasks[..one.1.len()].iter().all(|t| slot(t) == 0));
                    assert!(tasks.windows(2).all(|w| slot(&w[0]) <= slot(&w[1])));
                }
            }
        }
    }

    #[test]
    fn plan_size_matches_the_plan() {
        for spp in [1, 2, 3, 7, 8, 64, 100, 1023, 1024, 1025, 5000] {
            for cap in [1, 2, 3, 16, 1000, 1 << 20, u32::MAX] {
                for first in [1, 3, 64, 4096, u32::MAX] {
                    assert_eq!(
                        pass_count(spp, first, cap),
                        pass_ranges(spp, first, cap).len() as u64,
                        "spp {spp}, first {first}, cap {cap}"
                    );
                }
            }
        }
        for (w, h, ts, spp, max) in [
            (100, 50, 32, 8, 1 << 20),
            (1, 1, 4096, 1, 1),
            (65, 64, 64, 300, 4096 * 10),
            (17, 9, 1, 5, 3),
            (512, 300, 7, 40, 1000),
        ] {
            for frame_job in [false, true] {
                let (tiles, tasks) = plan(w, h, ts, spp, sizes(max), frame_job);
                assert_eq!(
                    plan_size(w, h, ts, spp, sizes(max), frame_job),
                    (tiles.len() as u64, tasks.len() as u64),
                    "{w}x{h} tile {ts} spp {spp} max {max} frames {frame_job}"
                );
            }
        }
        // The review's case, computed without a single allocation: 67 million tiles, 21 passes.
        assert_eq!(
            plan_size(8192, 8192, 1, 1 << 20, sizes(4 << 20), false),
            (1 << 26, 21 << 26)
        );
        assert_eq!(pass_count(u32::MAX, 1, 1), u32::MAX as u64);
    }
}
