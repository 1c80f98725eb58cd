//! Splits a job into tiles and progressive passes of tasks (pure; the store persists the plan).
//!
//! Pass 0 of a still gives every tile one sample, so a complete preview appears after one sample
//! per pixel; each later pass covers twice the samples of the one before, so the image sharpens
//! everywhere at once. A task's samples are capped so that it stays a few seconds of
//! single-thread work: long tasks would leave workers idle at the end of a job.
//!
//! Every other pass is long enough for its tasks of a full tile to take at least
//! [`TaskSizes::min`] samples: a still's pass 1, and a frame job's pass 0 (an animation's preview
//! is each frame's first pass, which comes early either way in the interleaved order). Each task
//! costs the farm a lease, an upload and a merge (about 14 ms, docs/benchmarks.md) whatever its
//! samples: passes of 2, 4 and 8 samples a pixel after the preview were 44 % of a 256-spp job's
//! tasks for 6 % of its samples, and an animation's small frames at one sample a pixel spent most
//! of the job on that. For the same reason a pass that would leave a last one shorter than half
//! its doubled length takes those samples itself (256 spp: 1, 16, 32, 64, then 143, not 128 and 15).
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
    /// Fewest samples in a task of a full tile, but for a still's one-sample preview pass
    /// ([`crate::ServerConfig::min_task_samples`]).
    pub min: u64,
}

/// How a plan's passes open: the samples per pixel of the first two, from which the later ones
/// double.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Opening {
    pub first: u32,
    pub second: u32,
    /// The first pass is a preview of its own (a still's one sample a pixel): the samples after
    /// it are never folded into it.
    pub preview: bool,
}

/// A still's first pass is one sample a pixel (a complete preview at once); every other pass is
/// long enough for [`TaskSizes::min`] samples in a full tile (and at least twice the one before).
pub fn opening_passes(tile_size: u32, sizes: TaskSizes, frame_job: bool) -> Opening {
    let tile_pixels = (tile_size.max(1) as u64).pow(2);
    let min = sizes.min.div_ceil(tile_pixels).clamp(1, u32::MAX as u64) as u32;
    if frame_job {
        Opening {
            first: min,
            second: min.saturating_mul(2),
            preview: false,
        }
    } else {
        Opening {
            first: 1,
            second: min.max(2),
            preview: true,
        }
    }
}

/// The passes of `spp` samples, one after the other.
struct Passes {
    spp: u32,
    max_per_pixel: u32,
    begin: u32,
    /// The nominal lengths of this pass and the next.
    len: u32,
    next: u32,
    /// This pass may take the samples after it (see [`Passes::end`]).
    may_fold: bool,
}

impl Passes {
    fn new(spp: u32, opening: Opening, max_per_pixel: u32) -> Passes {
        Passes {
            spp,
            max_per_pixel: max_per_pixel.max(1),
            begin: 0,
            len: opening.first.max(1),
            next: opening.second.max(1),
            may_fold: !opening.preview,
        }
    }

    /// The end of the current pass: at most `max_per_pixel` long, and taking the rest of the
    /// samples when they would make a last pass shorter than half its nominal length (and fit in
    /// one task with this pass's).
    fn end(&self) -> u32 {
        let (begin, spp, cap) = (self.begin, self.spp, self.max_per_pixel);
        let end = begin.saturating_add(self.len.min(cap)).min(spp);
        let rest = spp - end;
        let short = rest > 0 && rest < self.next.min(cap) / 2;
        if self.may_fold && short && spp - begin <= cap {
            spp
        } else {
            end
        }
    }
}

impl Iterator for Passes {
    type Item = (u32, u32);

    fn next(&mut self) -> Option<(u32, u32)> {
        if self.begin >= self.spp {
            return None;
        }
        let range = (self.begin, self.end());
        self.begin = range.1;
        (self.len, self.next) = (self.next, self.next.saturating_mul(2));
        self.may_fold = true;
        Some(range)
    }
}

/// The sample ranges of the passes: the [`opening_passes`], then each twice as long as the one
/// before ([0,1), [1,17), [17,49), … for a still in 64-pixel tiles), each at most
/// `max_per_pixel` long, the last folded into the one before when it would be short.
pub fn pass_ranges(spp: u32, opening: Opening, max_per_pixel: u32) -> Vec<(u32, u32)> {
    Passes::new(spp, opening, max_per_pixel).collect()
}

/// How many passes [`pass_ranges`] makes, computed without building them: the passes shorter
/// than `max_per_pixel` (at most 33 of them: they double), then the rest in steps of
/// `max_per_pixel` (no fold there: a rest within one step is one pass anyway).
pub fn pass_count(spp: u32, opening: Opening, max_per_pixel: u32) -> u64 {
    let mut passes = Passes::new(spp, opening, max_per_pixel);
    let mut n = 0u64;
    while passes.begin < spp && passes.len < passes.max_per_pixel {
        passes.next();
        n += 1;
    }
    n + ((spp - passes.begin) as u64).div_ceil(passes.max_per_pixel as u64)
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
        opening_passes(ts, sizes, frame_job),
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
    let opening = opening_passes(tile_size, sizes, frame_job);
    let mut tasks = Vec::new();
    for (pass, (b, e)) in pass_ranges(spp, opening, max_per_pixel)
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

    /// Tasks of at most `max` samples of a full tile, and at least 1 024 but in a still's first pass.
    fn sizes(max: u64) -> TaskSizes {
        TaskSizes { max, min: 1024 }
    }

    const fn opening(first: u32, second: u32, preview: bool) -> Opening {
        Opening {
            first,
            second,
            preview,
        }
    }
    const STILL: Opening = opening(1, 16, true);

    const OPENINGS: [Opening; 8] = [
        opening(1, 2, true),
        STILL,
        opening(1, 4096, true),
        opening(2, 4, false),
        opening(5, 10, false),
        opening(4096, 8192, false),
        opening(1, 16, false),
        opening(3, 64, false),
    ];

    #[test]
    fn passes_cover_every_sample_once() {
        for spp in [1, 2, 3, 7, 64, 100, 256, 1024] {
            for cap in [1, 3, 16, 1 << 20] {
                for opening in OPENINGS {
                    let r = pass_ranges(spp, opening, cap);
                    assert_eq!(r[0].0, 0);
                    assert!(r[0].1 >= opening.first.min(cap).min(spp));
                    if opening.preview {
                        assert_eq!(r[0], (0, 1));
                    }
                    assert_eq!(r.last().unwrap().1, spp);
                    for w in r.windows(2) {
                        assert_eq!(w[0].1, w[1].0);
                    }
                    assert!(r.iter().all(|(b, e)| b < e && e - b <= cap.max(1)));
                }
            }
        }
        // A still in 64-pixel tiles at the default sizes: one sample, then 16 and doubling; the
        // 15 left after 128 would be a pass of their own, so the fourth pass takes them.
        assert_eq!(
            pass_ranges(256, STILL, 1024),
            vec![(0, 1), (1, 17), (17, 49), (49, 113), (113, 256)]
        );
        assert_eq!(
            pass_ranges(10, opening(1, 2, true), 100),
            vec![(0, 1), (1, 3), (3, 10)]
        );
        assert_eq!(
            pass_ranges(40, opening(4, 8, false), 100),
            vec![(0, 4), (4, 12), (12, 40)]
        );
        // No fold past the cap: a short rest stays a pass of its own.
        assert_eq!(
            pass_ranges(100, STILL, 16),
            vec![
                (0, 1),
                (1, 17),
                (17, 33),
                (33, 49),
                (49, 65),
                (65, 81),
                (81, 97),
                (97, 100)
            ]
        );
        // Few samples: the preview, then one pass; a frame job's take one pass.
        assert_eq!(pass_ranges(3, STILL, 1024), vec![(0, 1), (1, 3)]);
        // 8² tiles: 1 024 samples a pixel would be the second pass, so it takes all 255.
        let small_tiles = opening(1, 1024, true);
        assert_eq!(
            pass_ranges(256, small_tiles, 1 << 16),
            vec![(0, 1), (1, 256)]
        );
        assert_eq!(pass_ranges(5, opening(1, 16, false), 1024), vec![(0, 5)]);
    }

    #[test]
    fn every_pass_but_a_stills_preview_fills_its_tasks() {
        let sizes = sizes(1 << 20);
        // Still jobs: one sample a pixel first, whatever the tile, then 1 024 samples a task.
        assert_eq!(opening_passes(64, sizes, false), opening(1, 2, true));
        assert_eq!(opening_passes(16, sizes, false), opening(1, 4, true));
        let default = TaskSizes {
            max: 1 << 20,
            min: 1 << 16,
        };
        assert_eq!(opening_passes(64, default, false), STILL);
        // 1,024 samples: 1 a pixel in a 32² tile, 4 in a 16² tile, 1 024 in a single pixel.
        assert_eq!(opening_passes(32, sizes, true), opening(1, 2, false));
        assert_eq!(opening_passes(16, sizes, true), opening(4, 8, false));
        assert_eq!(opening_passes(15, sizes, true), opening(5, 10, false));
        assert_eq!(opening_passes(1, sizes, true), opening(1024, 2048, false));
        // A 16² tile at 8 spp: passes [0,4) [4,8) for a frame, [0,1) [1,8) for a still.
        let ranges = |frame_job| {
            plan(16, 16, 16, 8, sizes, frame_job)
                .1
                .iter()
                .map(|t| (t.sample_begin, t.sample_end))
                .collect::<Vec<_>>()
        };
        assert_eq!(ranges(true), [(0, 4), (4, 8)]);
        assert_eq!(ranges(false), [(0, 1), (1, 8)]);
    }

    #[test]
    fn plan_tiles_and_tasks() {
        let (tiles, tasks) = plan(100, 50, 32, 8, sizes(1 << 20), false);
        assert_eq!(tiles.len(), 4 * 2);
        assert_eq!(tasks.len(), 8 * 3); // passes [0,1) [1,3) [3,8)
        let covered: u64 = tasks
            .iter()
            .map(|t| {
                tiles[t.tile_index as usize].pixel_count() * (t.sample_end - t.sample_begin) as u64
            })
            .sum();
        assert_eq!(covered, 100 * 50 * 8);
        // The first pass holds every tile before any tile gets a second sample.
        assert!(tasks[..tiles.len()].iter().all(|t| t.pass == 0));
        assert!(tasks[tiles.len()..].iter().all(|t| t.pass > 0));
    }

    #[test]
    fn frame_plans_keep_each_frames_tiles_and_order_their_tasks() {
        let frames = [5, 1, 9];
        // Tasks of at least one sample: 8 tiles, passes [0,1) [1,4).
        let sizes = TaskSizes {
            max: 1 << 20,
            min: 1,
        };
        let one = plan(64, 32, 16, 4, sizes, true);
        assert_eq!(one.1.len(), 8 * 2);
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
        for spp in [1, 2, 3, 7, 8, 64, 100, 256, 1023, 1024, 1025, 5000] {
            for cap in [1, 2, 3, 16, 1000, 1 << 20, u32::MAX] {
                for opening in OPENINGS
                    .into_iter()
                    .chain([opening(u32::MAX, u32::MAX, false)])
                {
                    assert_eq!(
                        pass_count(spp, opening, cap),
                        pass_ranges(spp, opening, cap).len() as u64,
                        "spp {spp}, opening {opening:?}, cap {cap}"
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
        // The review's case, computed without a single allocation: 67 million tiles, 11 passes
        // (one sample, then 1 024 doubling to 524 288, which takes the last 1 023 too).
        assert_eq!(
            plan_size(8192, 8192, 1, 1 << 20, sizes(4 << 20), false),
            (1 << 26, 11 << 26)
        );
        assert_eq!(
            pass_count(u32::MAX, opening(1, 1, true), 1),
            u32::MAX as u64
        );
    }
}
