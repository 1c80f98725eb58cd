//! Back-pressure: how long the workers' slices should be, so that the farm's writes (slice merges
//! and leases) stay under what this server's store can take however many workers there are.
//!
//! Each active worker uploads a slice every `S` seconds and leases a task every so many uploads
//! (`r` leases per upload, measured), so `N` active workers write `N (1 + r) / S` times a second.
//! The store takes `C` writes a second, measured here rather than configured: writes completed per
//! second during which at least one write was under way (below saturation this reads low, so the
//! slices it asks for err long). The server asks for
//!
//! `S = N (1 + r) / (u C)`, with `u` = [`crate::ServerConfig::target_write_load`],
//!
//! and hands it to every worker with each lease and upload acknowledgement
//! ([`pathfarm_wire::api::Lease::slice_seconds`]); a worker renders slices of the longer of its
//! own slice length and this. A slice that errs long costs little: the worker renders as much,
//! it only uploads less often.
//!
//! Slices cannot be longer than their tasks, and a farm's first passes are tasks of one sample a
//! pixel: many workers finishing short tasks lease faster than any slice length helps. So a lease
//! is also refused while [`QUEUE_SECONDS`] of the store's writes (at its measured capacity, at
//! least [`MIN_QUEUE`] writes) are under way: it is answered 429 `slow_down` with a
//! `Retry-After` of one turn of every worker that wants work at that capacity, spread so that they
//! do not come back together. The writes under way bound what a granted lease waits for, and the
//! store runs at what it can take whatever the crowd. (An earlier version also admitted leases
//! at `u C` a second; with group commit the capacity measured at a lower load reads lower, so
//! the admitted rate spiralled down to a fifth of what the store takes: docs/benchmarks.md.)
//! Uploads are never refused: they carry finished work.
//!
//! The estimate is redone at most once per [`WINDOW`], by whichever write ends after the window
//! closes; between those a write costs two uncontended lock operations.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

/// How often the estimate is redone.
pub const WINDOW: Duration = Duration::from_secs(1);
/// The longest slice the server asks for: past it a worker's lost slice costs too much work.
pub const MAX_SLICE_SECONDS: f64 = 60.0;
/// A worker counts as active for this long after its last lease or upload (or for two slice
/// lengths, when that is longer).
const ACTIVE_FOR: Duration = Duration::from_secs(30);
/// A lease is refused while this many seconds of the store's writes (at its measured capacity)
/// are under way, so that the ones granted wait little; at least [`MIN_QUEUE`] writes.
const QUEUE_SECONDS: f64 = 0.025;
/// The writes under way that refuse a lease before any capacity was measured, and at least.
const MIN_QUEUE: u32 = 16;
/// The capacity a refused worker's turn is reckoned at before any was measured.
const UNMEASURED_CAPACITY: f64 = 100.0;
/// Weight of a new window's capacity in the running estimate.
const SMOOTHING: f64 = 0.3;
/// Windows busier than this long (of writes in flight) measure the capacity; quieter ones say
/// too little about it.
const MIN_BUSY: Duration = Duration::from_millis(20);

/// What a write was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Write {
    Upload,
    Lease,
}

/// The estimate as it stands.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PacingView {
    /// Slice length asked of workers, in seconds (0 before anything was measured).
    pub slice_seconds: f64,
    /// Writes per busy second of the store, smoothed (`None` before a busy window).
    pub capacity: Option<f64>,
    /// Workers that leased or uploaded lately.
    pub active_workers: usize,
    /// Leases per upload over the last window with uploads.
    pub leases_per_upload: f64,
    /// Leases refused so far (429 `slow_down`).
    pub leases_refused: u64,
}

pub struct Pacing {
    /// `None`: no back-pressure (the capacity is still measured, for the metrics).
    target_load: Option<f64>,
    state: Mutex<State>,
    /// [`PacingView::slice_seconds`] as `f64` bits, read without the lock.
    slice_bits: AtomicU64,
}

struct State {
    in_flight: u32,
    /// When the write now under way with none before it began.
    busy_since: Option<Instant>,
    window_start: Instant,
    busy: Duration,
    uploads: u64,
    leases: u64,
    view: PacingView,
    seen: HashMap<String, Instant>,
    /// Leases refused so far.
    refused: u64,
}

/// A lease refused for now: try again after this many seconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SlowDown {
    pub retry_after_seconds: u32,
}

/// A write under way; dropping it ends it.
pub struct WriteGuard<'a> {
    pacing: &'a Pacing,
    kind: Write,
}

impl Drop for WriteGuard<'_> {
    fn drop(&mut self) {
        self.pacing.end(self.kind, Instant::now());
    }
}

impl Pacing {
    /// `target_load`: the share of the measured capacity the workers' writes should take (the
    /// rest is headroom for bursts, heartbeats, submissions and readers); `None` or a share that
    /// is not above 0: no back-pressure.
    pub fn new(target_load: Option<f64>) -> Pacing {
        let target_load = target_load
            .filter(|t| t.is_finite() && *t > 0.0)
            .map(|t| t.min(1.0));
        Pacing {
            target_load,
            state: Mutex::new(State {
                in_flight: 0,
                busy_since: None,
                window_start: Instant::now(),
                busy: Duration::ZERO,
                uploads: 0,
                leases: 0,
                view: PacingView::default(),
                seen: HashMap::new(),
                refused: 0,
            }),
            slice_bits: AtomicU64::new(0f64.to_bits()),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // Nothing here panics while holding the lock.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The slice length to ask of workers now, in seconds (0: no more than their own).
    pub fn slice_seconds(&self) -> f64 {
        f64::from_bits(self.slice_bits.load(Ordering::Relaxed))
    }

    /// The estimate as it stands (for metrics and tests).
    pub fn view(&self) -> PacingView {
        let s = self.lock();
        PacingView {
            leases_refused: s.refused,
            ..s.view
        }
    }

    /// Starts a write of `kind` by `worker`; it ends when the guard is dropped. A lease beyond
    /// the admitted rate, or behind too many writes under way, is refused instead (uploads always
    /// start).
    pub fn begin(&self, kind: Write, worker: &str) -> Result<WriteGuard<'_>, SlowDown> {
        self.admit(kind, worker, Instant::now())?;
        Ok(WriteGuard { pacing: self, kind })
    }

    /// Leases refused so far.
    pub fn refused(&self) -> u64 {
        self.lock().refused
    }

    fn admit(&self, kind: Write, worker: &str, now: Instant) -> Result<(), SlowDown> {
        let mut s = self.lock();
        if self.target_load.is_none() || kind == Write::Upload {
            Self::started(&mut s, now);
            return Ok(());
        }
        let capacity = s.view.capacity.filter(|c| *c > 0.0);
        let queue = capacity.map_or(MIN_QUEUE, |c| ((c * QUEUE_SECONDS) as u32).max(MIN_QUEUE));
        if s.in_flight >= queue {
            s.refused += 1;
            // A worker refused wants work: it counts among the active ones.
            Self::note(&mut s, worker, now);
            // Long enough for every such worker to have had a turn, spread over ±50 %.
            let per_second = capacity.unwrap_or(UNMEASURED_CAPACITY);
            let turn = (s.seen.len().max(1) as f64 / per_second).clamp(1.0, MAX_SLICE_SECONDS);
            let spread = 0.5
                + (s.refused.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11) as f64
                    / (1u64 << 53) as f64;
            return Err(SlowDown {
                retry_after_seconds: (turn * spread).ceil().max(1.0) as u32,
            });
        }
        Self::started(&mut s, now);
        Ok(())
    }

    fn started(s: &mut State, now: Instant) {
        if s.in_flight == 0 {
            s.busy_since = Some(now);
        }
        s.in_flight += 1;
    }

    /// Notes `worker` as active (it was granted a lease or had a slice merged).
    pub fn seen(&self, worker: &str) {
        Self::note(&mut self.lock(), worker, Instant::now());
    }

    fn note(s: &mut State, worker: &str, now: Instant) {
        match s.seen.get_mut(worker) {
            Some(t) => *t = now,
            None => {
                s.seen.insert(worker.to_string(), now);
            }
        }
    }

    fn end(&self, kind: Write, now: Instant) {
        let mut s = self.lock();
        s.in_flight = s.in_flight.saturating_sub(1);
        if s.in_flight == 0 {
            if let Some(since) = s.busy_since.take() {
                s.busy += now.saturating_duration_since(since);
            }
        }
        match kind {
            Write::Upload => s.uploads += 1,
            Write::Lease => s.leases += 1,
        }
        if now.saturating_duration_since(s.window_start) >= WINDOW {
            self.estimate(&mut s, now);
        }
    }

    /// Closes the window: a new capacity sample, the lease share, the active workers, the slice.
    fn estimate(&self, s: &mut State, now: Instant) {
        // A write still under way counts its time so far in this window, the rest in the next.
        if let Some(since) = s.busy_since.as_mut() {
            s.busy += now.saturating_duration_since(*since);
            *since = now;
        }
        let writes = s.uploads + s.leases;
        if s.busy >= MIN_BUSY && writes > 0 {
            let sample = writes as f64 / s.busy.as_secs_f64();
            s.view.capacity = Some(match s.view.capacity {
                Some(c) => c + SMOOTHING * (sample - c),
                None => sample,
            });
        }
        if s.uploads > 0 {
            s.view.leases_per_upload = s.leases as f64 / s.uploads as f64;
        }
        let horizon = ACTIVE_FOR.max(Duration::from_secs_f64(2.0 * s.view.slice_seconds));
        s.seen
            .retain(|_, t| now.saturating_duration_since(*t) <= horizon);
        s.view.active_workers = s.seen.len();
        s.view.slice_seconds = match (s.view.capacity, self.target_load) {
            (Some(c), Some(u)) if c > 0.0 => {
                (s.view.active_workers as f64 * (1.0 + s.view.leases_per_upload) / (u * c))
                    .min(MAX_SLICE_SECONDS)
            }
            _ => 0.0,
        };
        self.slice_bits
            .store(s.view.slice_seconds.to_bits(), Ordering::Relaxed);
        s.window_start = now;
        s.busy = Duration::ZERO;
        s.uploads = 0;
        s.leases = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `writes` writes of `each` one after another from `t`, returning the time after.
    fn serial(p: &Pacing, t: Instant, writes: u32, each: Duration, kind: Write) -> Instant {
        let mut t = t;
        for _ in 0..writes {
            Pacing::started(&mut p.lock(), t);
            t += each;
            p.end(kind, t);
        }
        t
    }

    #[test]
    fn the_slice_grows_with_the_workers_and_the_cost_of_a_write() {
        let p = Pacing::new(Some(0.5));
        assert_eq!(p.slice_seconds(), 0.0, "nothing measured");
        for i in 0..100 {
            p.seen(&format!("w{i}"));
        }
        let t0 = p.lock().window_start;
        // 1 ms a write, back to back: 1,000 writes a second; one lease per four uploads.
        let t = serial(&p, t0, 800, Duration::from_millis(1), Write::Upload);
        let t = serial(&p, t, 200, Duration::from_millis(1), Write::Lease);
        let v = p.view();
        let c = v.capacity.expect("a busy window");
        assert!((c - 1000.0).abs() < 1.0, "{c}");
        assert!((v.leases_per_upload - 0.25).abs() < 1e-9);
        assert_eq!(v.active_workers, 100);
        // 100 workers × 1.25 writes a slice / (0.5 × 1,000 a second) = 0.25 s.
        assert!(
            (p.slice_seconds() - 0.25).abs() < 1e-3,
            "{}",
            p.slice_seconds()
        );

        // Ten times the workers, writes twice as dear: twenty times the slice.
        for i in 100..1000 {
            p.seen(&format!("w{i}"));
        }
        let mut t = t;
        for _ in 0..20 {
            t = serial(&p, t, 400, Duration::from_millis(2), Write::Upload);
            t = serial(&p, t, 100, Duration::from_millis(2), Write::Lease);
        }
        let s = p.slice_seconds();
        assert!((s - 5.0).abs() < 0.05, "{s}");
    }

    #[test]
    fn overlapping_writes_count_their_busy_time_once_and_the_slice_is_capped() {
        let p = Pacing::new(Some(0.5));
        for i in 0..100_000 {
            p.seen(&format!("w{i}"));
        }
        let t0 = p.lock().window_start;
        // Ten writes at once, each 100 ms, over one second of busy time: 100 a second.
        let mut t = t0;
        for _ in 0..10 {
            for _ in 0..10 {
                Pacing::started(&mut p.lock(), t);
            }
            t += Duration::from_millis(100);
            for _ in 0..10 {
                p.end(Write::Upload, t);
            }
        }
        // (The window closes as the last ten end, with nine still counted as under way.)
        let c = p.view().capacity.unwrap();
        assert!((c - 100.0).abs() < 10.0, "{c}");
        assert_eq!(p.slice_seconds(), MAX_SLICE_SECONDS);
    }

    /// A lease finding too many writes under way is told to come back later, after a turn of
    /// every worker that wants work; uploads always start.
    #[test]
    fn leases_behind_a_full_queue_are_told_to_come_back_later() {
        // Before any measurement: 16 writes under way at most for a lease.
        let fresh = Pacing::new(Some(0.5));
        let t0 = fresh.lock().window_start;
        for _ in 0..MIN_QUEUE {
            assert!(fresh.admit(Write::Lease, "w0", t0).is_ok());
        }
        let slow = fresh.admit(Write::Lease, "w1", t0).unwrap_err();
        // One worker wanting work, at the unmeasured capacity: the shortest turn, 1 s ± 50 %.
        assert!((1..=2).contains(&slow.retry_after_seconds), "{slow:?}");
        assert!(
            fresh.admit(Write::Upload, "w0", t0).is_ok(),
            "uploads always start"
        );
        fresh.end(Write::Upload, t0);
        fresh.end(Write::Lease, t0);
        assert!(
            fresh.admit(Write::Lease, "w1", t0).is_ok(),
            "one ended: room again"
        );

        // Measured at 1,000 writes a second: QUEUE_SECONDS of them (25 writes) under way at most.
        let p = Pacing::new(Some(0.5));
        let t0 = p.lock().window_start;
        for i in 0..2000 {
            p.seen(&format!("w{i}"));
        }
        let t = serial(&p, t0, 1000, Duration::from_millis(1), Write::Upload);
        assert!((p.view().capacity.unwrap() - 1000.0).abs() < 1.0);
        let mut refused = Vec::new();
        for _ in 0..1000 {
            if let Err(slow) = p.admit(Write::Lease, "w0", t) {
                refused.push(slow.retry_after_seconds);
            }
        }
        let queue = (1000.0 * QUEUE_SECONDS) as usize;
        assert_eq!(queue, 25);
        assert_eq!(refused.len(), 1000 - queue, "{queue} admitted");
        assert_eq!(p.refused(), (1000 - queue) as u64);
        // 2,000 workers at 1,000 a second: a turn is 2 s, spread over 1–3 s.
        assert!(refused.iter().all(|&s| (1..=3).contains(&s)), "{refused:?}");
        assert!(refused.contains(&2) && refused.contains(&3), "spread");
        for _ in 0..10 {
            assert!(p.admit(Write::Upload, "w0", t).is_ok());
        }
        for _ in 0..20 {
            p.end(Write::Lease, t);
        }
        let admitted = (0..100)
            .filter(|_| p.admit(Write::Lease, "w0", t).is_ok())
            .count();
        assert_eq!(
            admitted,
            queue - (queue + 10 - 20),
            "{} under way after 20 ended: room for the rest of the {queue}",
            queue + 10 - 20
        );
    }

    #[test]
    fn without_a_target_nothing_is_asked_or_refused() {
        let p = Pacing::new(None);
        for i in 0..1000 {
            p.seen(&format!("w{i}"));
        }
        let t0 = p.lock().window_start;
        let t = serial(&p, t0, 1000, Duration::from_millis(1), Write::Upload);
        assert!(p.view().capacity.is_some(), "still measured");
        assert_eq!(p.slice_seconds(), 0.0);
        for _ in 0..1000 {
            assert!(p.admit(Write::Lease, "w0", t).is_ok());
        }
    }

    #[test]
    fn quiet_windows_keep_the_estimate_and_idle_workers_drop_out() {
        let p = Pacing::new(Some(0.5));
        p.seen("a");
        let t0 = p.lock().window_start;
        let t = serial(&p, t0, 100, Duration::from_millis(10), Write::Upload);
        let before = p.view().capacity.unwrap();
        // One short write in a long window: too little busy time to say anything.
        let t = serial(
            &p,
            t + Duration::from_secs(5),
            1,
            Duration::from_millis(1),
            Write::Upload,
        );
        assert_eq!(p.view().capacity, Some(before));
        // Long after the worker's last write it is no longer counted.
        {
            let mut s = p.lock();
            for v in s.seen.values_mut() {
                *v = t0;
            }
        }
        serial(
            &p,
            t + ACTIVE_FOR * 2,
            1,
            Duration::from_millis(1),
            Write::Lease,
        );
        assert_eq!(p.view().active_workers, 0);
        assert_eq!(p.slice_seconds(), 0.0);
    }
}
