//! The server's memory: read from `/proc`, sampled through the run, and judged.

use super::{nap, MemoryReport, RssSample, Shared};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// The shortest window whose memory is judged. The server's resident set still climbs for the
/// first 30–60 s of this load (from ~20 MiB to ~65 MiB, most of it in 20 s), so in a shorter
/// window the quarters compare warm-up with warm-up: 20- and 30-second runs showed 6–15 MiB
/// between them, too close to the allowance to mean anything. Quick runs report the figures only.
pub const MIN_JUDGED_SECONDS: f64 = 60.0;

/// The rule for "memory stays flat", applied to the server's resident set sampled once a second
/// over a window of `window_s` seconds: **the largest sample of the last quarter may exceed the
/// largest sample of the second quarter by at most 10 % plus 16 MiB**.
///
/// - The first quarter is warm-up, ignored: connection pools, the SQLite page cache, the image
///   cache, malloc arenas for the runtime's threads and the 200 workers' rows grow to their
///   working size there.
/// - Maxima, not means: both quarters see job completions, image assemblies and EXR encodes, the
///   spikes of this load, so their peaks are like moments, and one statistic on both sides.
/// - The allowance covers what bounded caches and the allocator still do after warm-up (glibc
///   keeps freed memory in per-thread arenas and fragments; the image cache holds up to 32 jobs;
///   SQLite's page cache up to 2 MiB per connection; spikes of a few MiB come and go with image
///   assemblies). Measured on two cores, the last quarter's peak exceeded the second's by 3–8 MiB
///   in 2-minute runs (SQLite 67.5 → 71.9 MiB, PostgreSQL 45.7 → 53.4 MiB) and by 4.5 MiB in a
///   10-minute SQLite run (80.0 → 84.5 MiB; 101 jobs churned, flat for its last 5 minutes),
///   against an allowance of ~20–25 MiB at those sizes.
/// - A leak grows with the work done. A server of B MiB leaking r MiB/s over a window T is caught
///   when rT > (0.1 B + 16 MiB) / 0.45, ~50 MiB for B = 60 MiB. Tried on a server patched to
///   keep every uploaded slice (~5.4 KB each for a 16×16 tile), in the default 2-minute run on
///   SQLite: last quarter 307 MiB against a limit of 223, caught. Keeping half of every slice:
///   173 MiB against 140, caught, where the rule first suggested in issue 6 (25 % + 32 MiB)
///   allows 173 MiB and would have passed it. A leak of some hundred bytes per request is below
///   what two minutes can tell from the allocator; longer runs (`farm-bench soak
///   --seconds`) see proportionally more.
///
/// Windows shorter than [`MIN_JUDGED_SECONDS`] get no verdict. Returns `None` without samples.
pub fn judge_memory(samples: &[RssSample], window_s: f64) -> Option<MemoryReport> {
    const SLACK_KIB: u64 = 16 * 1024;
    let last = samples.last()?;
    let in_range = |from: f64, to: f64| {
        samples
            .iter()
            .filter(move |s| s.t_s >= from * window_s && s.t_s <= to * window_s)
    };
    let quarter_max = |from: f64, to: f64| in_range(from, to).map(|s| s.rss_kib).max();
    let second = quarter_max(0.25, 0.5).unwrap_or(0);
    // The last quarter always has the closing sample (taken as the window closes).
    let last_quarter = quarter_max(0.75, 1.0).unwrap_or(last.rss_kib);
    let start = in_range(0.25, 1.0).next().unwrap_or(last);
    let middle = samples
        .iter()
        .min_by(|a, b| {
            (a.t_s - window_s / 2.0)
                .abs()
                .total_cmp(&(b.t_s - window_s / 2.0).abs())
        })
        .unwrap_or(last);
    let limit = second + second / 10 + SLACK_KIB;
    Some(MemoryReport {
        start_kib: start.rss_kib,
        middle_kib: middle.rss_kib,
        end_kib: last.rss_kib,
        max_kib: samples.iter().map(|s| s.rss_kib).max().unwrap_or(0),
        hwm_kib: last.hwm_kib,
        second_quarter_max_kib: second,
        last_quarter_max_kib: last_quarter,
        limit_kib: limit,
        flat: (window_s >= MIN_JUDGED_SECONDS).then_some(second > 0 && last_quarter <= limit),
        samples: samples.to_vec(),
    })
}

/// `VmRSS` and `VmHWM` of `pid`, KiB.
pub(super) fn read_memory(pid: u32) -> std::io::Result<(u64, u64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let field = |name: &str| -> Option<u64> {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))?
            .split_whitespace()
            .next()?
            .parse()
            .ok()
    };
    match (field("VmRSS:"), field("VmHWM:")) {
        (Some(rss), Some(hwm)) => Ok((rss, hwm)),
        _ => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("/proc/{pid}/status has no VmRSS or VmHWM"),
        )),
    }
}

/// Samples the server's memory once a second until the run stops, and once more then.
pub(super) async fn sample_memory(
    pid: u32,
    t0: Instant,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) -> Vec<RssSample> {
    let mut out = Vec::new();
    loop {
        let stopped = *stop.borrow();
        match read_memory(pid) {
            Ok((rss_kib, hwm_kib)) => out.push(RssSample {
                t_s: t0.elapsed().as_secs_f64(),
                rss_kib,
                hwm_kib,
            }),
            Err(e) => {
                shared.rec.fault(format!("server memory (pid {pid}): {e}"));
                break;
            }
        }
        if stopped {
            break;
        }
        nap(&mut stop, Duration::from_secs(1)).await;
    }
    out
}

pub(super) fn mib(kib: u64) -> f64 {
    kib as f64 / 1024.0
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadgen::synthetic;
    use crate::soak::SoakConfig;

    fn series(seconds: u32, rss: impl Fn(f64) -> f64) -> Vec<RssSample> {
        (0..=seconds)
            .map(|t| {
                let kib = rss(t as f64) as u64;
                RssSample {
                    t_s: t as f64,
                    rss_kib: kib,
                    hwm_kib: kib,
                }
            })
            .collect()
    }

    #[test]
    fn flat_memory_with_noise_and_warm_up_passes() {
        // 30 MiB at start, 60 MiB after warm-up, ±6 MiB of sawtooth from allocations.
        let s = series(120, |t| {
            let base = if t < 20.0 { 30.0 + 1.5 * t } else { 60.0 };
            (base + 6.0 * ((t * 0.7).sin())) * 1024.0
        });
        let m = judge_memory(&s, 120.0).unwrap();
        assert_eq!(m.flat, Some(true), "{m:?}");
        assert_eq!(m.end_kib, s.last().unwrap().rss_kib);
    }

    #[test]
    fn retaining_every_upload_is_caught() {
        // The default job's upload, as encoded on the wire (what a leak of request bodies keeps).
        let j = SoakConfig::new("http://x", "sqlite", 1.0).job;
        let slice = synthetic(0, 0, j.tile_size, j.tile_size, 0, 1).len() as f64;
        assert!(slice > 4000.0, "{slice} bytes");
        // A 60 MiB server keeping every one of 300 uploads/s (the rate measured on two cores,
        // below the default's 400), over the default two minutes.
        let s = series(120, |t| 60.0 * 1024.0 + 300.0 * slice / 1024.0 * t);
        let m = judge_memory(&s, 120.0).unwrap();
        assert_eq!(m.flat, Some(false), "{m:?}");
        // Half that leak, in a 10-minute run, too.
        let s = series(600, |t| 60.0 * 1024.0 + 150.0 * slice / 1024.0 * t);
        assert_eq!(judge_memory(&s, 600.0).unwrap().flat, Some(false));
    }

    #[test]
    fn short_windows_are_not_judged() {
        assert!(judge_memory(&[], 10.0).is_none());
        let s = series(30, |t| (20.0 + t) * 1024.0);
        let m = judge_memory(&s, 30.0).unwrap();
        assert_eq!(m.flat, None);
        assert_eq!(m.end_kib, 50 * 1024);
    }
}
