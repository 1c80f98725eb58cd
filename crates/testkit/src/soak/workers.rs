//! Simulated workers.

use super::recorder::{lock, status_key, Kind};
use super::{nap, Shared};
use crate::loadgen::synthetic;
use pathfarm_wire::api::{Lease, WorkerRegistered};
use pathfarm_worker::client::ApiClient;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// The lease a worker holds, for its heartbeat.
type Held = Arc<Mutex<Option<(i64, String)>>>;

pub(super) struct SimWorker {
    pub(super) i: usize,
    pub(super) client: ApiClient,
    pub(super) reg: WorkerRegistered,
    pub(super) pace: Duration,
    /// When this worker starts, after the window opens (spread over one pace).
    pub(super) offset: Duration,
    /// Its place among the workers, 0..1: spreads their starts and heartbeats.
    pub(super) phase: f64,
    pub(super) scene_len: usize,
}

impl SimWorker {
    pub(super) async fn run(self, shared: Arc<Shared>, mut stop: watch::Receiver<bool>) {
        let held: Held = Arc::new(Mutex::new(None));
        let heartbeat = tokio::spawn(heartbeat_loop(
            self.client.clone(),
            self.reg.clone(),
            self.phase,
            held.clone(),
            shared.clone(),
            stop.clone(),
        ));
        let mut scene_hash: Option<String> = None;
        // `pathfarm worker`'s idle backoff: 20 ms doubling to its default idle poll, 500 ms.
        let mut idle = Duration::from_millis(20);
        if !nap(&mut stop, self.offset).await {
            while !*stop.borrow() {
                let t = Instant::now();
                match self.client.lease(&self.reg.worker_id).await {
                    Ok(Some(lease)) => {
                        shared.rec.observe(Kind::Lease, t, "200");
                        shared.leases.fetch_add(1, Ordering::Relaxed);
                        idle = Duration::from_millis(20);
                        if scene_hash.as_deref() != Some(lease.scene_hash.as_str()) {
                            if !self.fetch_scene(&lease.scene_hash, &shared).await {
                                self.release(&lease, &shared).await;
                                nap(&mut stop, Duration::from_secs(1)).await;
                                continue;
                            }
                            scene_hash = Some(lease.scene_hash.clone());
                        }
                        *lock(&held) = Some((lease.task_id, lease.lease_token.clone()));
                        self.work_on(&lease, &shared, &mut stop).await;
                        *lock(&held) = None;
                    }
                    Ok(None) => {
                        shared.rec.observe(Kind::Lease, t, "204");
                        shared.leases_empty.fetch_add(1, Ordering::Relaxed);
                        nap(&mut stop, idle).await;
                        idle = (idle * 2).min(Duration::from_millis(500));
                    }
                    Err(e) if e.status() == Some(reqwest::StatusCode::TOO_MANY_REQUESTS) => {
                        // Back-pressure: `pathfarm worker` waits as the server says.
                        shared.rec.observe(Kind::Lease, t, "429");
                        let after = e.retry_after().unwrap_or(Duration::from_secs(1));
                        nap(&mut stop, after.min(Duration::from_secs(60))).await;
                    }
                    Err(e) => {
                        shared.rec.observe(Kind::Lease, t, &status_key(&e));
                        shared
                            .rec
                            .error(Kind::Lease, format!("sim-{}: {e}", self.i));
                        nap(&mut stop, Duration::from_secs(1)).await;
                    }
                }
            }
        }
        if let Err(e) = heartbeat.await {
            shared
                .rec
                .fault(format!("sim-{}: heartbeat task: {e}", self.i));
        }
        let t = Instant::now();
        let r = self.client.deregister(&self.reg.worker_id).await;
        shared
            .rec
            .client(Kind::SignOff, t, r, || format!("sim-{}", self.i));
    }

    async fn fetch_scene(&self, hash: &str, shared: &Shared) -> bool {
        let t = Instant::now();
        let r = self.client.scene(hash).await;
        let Some(bytes) = shared.rec.client(Kind::Scene, t, r, || {
            format!("sim-{}: scene {hash}", self.i)
        }) else {
            return false;
        };
        if bytes.len() != self.scene_len {
            shared.rec.error(
                Kind::Scene,
                format!(
                    "sim-{}: scene {hash} is {} bytes, {} were submitted",
                    self.i,
                    bytes.len(),
                    self.scene_len
                ),
            );
            return false;
        }
        true
    }

    /// Uploads the task's samples one by one, `pace` apart; gives the rest back when stopped.
    async fn work_on(&self, lease: &Lease, shared: &Shared, stop: &mut watch::Receiver<bool>) {
        let tile = lease.tile;
        let tile_pixels = u64::from(tile.width) * u64::from(tile.height);
        let mut begin = lease.sample_begin;
        while begin < lease.sample_end {
            if nap(stop, self.pace).await {
                self.release(lease, shared).await;
                return;
            }
            let body = synthetic(tile.x0, tile.y0, tile.width, tile.height, begin, begin + 1);
            let t = Instant::now();
            let r = self
                .client
                .upload_slice(lease.task_id, &lease.lease_token, body)
                .await;
            let Some(ack) = shared.rec.client(Kind::Upload, t, r, || {
                format!(
                    "sim-{}: task {} samples [{begin}, {})",
                    self.i,
                    lease.task_id,
                    begin + 1
                )
            }) else {
                // The upload's fate is unknown (an error is recorded): leave the task to expire.
                return;
            };
            if ack.duplicate {
                shared.uploads_duplicate.fetch_add(1, Ordering::Relaxed);
            } else {
                shared.uploads_accepted.fetch_add(1, Ordering::Relaxed);
                shared
                    .samples_accepted
                    .fetch_add(tile_pixels, Ordering::Relaxed);
                if !shared.closed.load(Ordering::Relaxed) {
                    shared.window_uploads.fetch_add(1, Ordering::Relaxed);
                }
            }
            begin = ack.task_samples_done.max(begin + 1);
            if ack.task_complete {
                return;
            }
            if !ack.keep_going {
                self.release(lease, shared).await;
                return;
            }
        }
    }

    async fn release(&self, lease: &Lease, shared: &Shared) {
        let t = Instant::now();
        let r = self.client.release(lease.task_id, &lease.lease_token).await;
        shared.rec.client(Kind::Release, t, r, || {
            format!("sim-{}: task {}", self.i, lease.task_id)
        });
    }
}

/// Every `heartbeat_interval` from registration on, naming the lease held, as `pathfarm worker`.
///
/// `phase` (0..1) spreads the workers' heartbeats over one interval, as a farm's machines, started
/// at different moments, spread them; all at once they would be a burst every interval.
async fn heartbeat_loop(
    client: ApiClient,
    reg: WorkerRegistered,
    phase: f64,
    held: Held,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let interval = Duration::from_millis(reg.heartbeat_interval_ms.max(50));
    if nap(&mut stop, interval.mul_f64(phase)).await {
        return;
    }
    while !nap(&mut stop, interval).await {
        let h = lock(&held).clone();
        let hb = pathfarm_wire::api::Heartbeat {
            task_id: h.as_ref().map(|h| h.0),
            lease_token: h.as_ref().map(|h| h.1.clone()),
        };
        let t = Instant::now();
        let r = client.heartbeat(&reg.worker_id, &hb).await;
        if let Some(reply) = shared
            .rec
            .client(Kind::Heartbeat, t, r, || reg.worker_id.clone())
        {
            if h.is_some() && !reply.lease_valid {
                shared
                    .heartbeats_lease_invalid
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}
