//! Dashboard pollers.

use super::recorder::Kind;
use super::{nap, Shared};
use pathfarm_wire::api::{JobList, JobState, JobView};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Polling intervals of the dashboard's pages (`jobs.js`, `job.js`, `workers.js`).
const JOBS_EVERY: Duration = Duration::from_millis(1000);
const THUMB_EVERY: Duration = Duration::from_millis(3000);
const THUMB_PARALLEL: usize = 2;
const JOB_LIVE_EVERY: Duration = Duration::from_millis(330);
const JOB_FINAL_EVERY: Duration = Duration::from_millis(5000);
const CONVERGENCE_EVERY: Duration = Duration::from_millis(1000);
const WORKERS_EVERY: Duration = Duration::from_millis(2000);

/// An answer as a browser's `fetch` sees it.
struct Answer {
    status: u16,
    etag: Option<String>,
    body: Vec<u8>,
}

/// One dashboard tab.
pub(super) struct Browser {
    pub(super) i: usize,
    pub(super) http: reqwest::Client,
    pub(super) base: String,
    pub(super) token: Option<String>,
    pub(super) shared: Arc<Shared>,
}

/// A row's thumbnail (`jobs.js`, `maybeThumb`).
#[derive(Default)]
struct Thumb {
    etag: Option<String>,
    samples_done: Option<u64>,
    state: Option<JobState>,
    at: Option<Instant>,
}

impl Browser {
    /// `GET /api/v1{path}` with the token and, given one, `If-None-Match`. 404 is expected only
    /// where `gone_ok` (a job deleted under an open page); any other 4xx, a 5xx or no answer is an
    /// error (`None`).
    async fn get(
        &self,
        kind: Kind,
        path: &str,
        etag: Option<&str>,
        gone_ok: bool,
    ) -> Option<Answer> {
        let t = Instant::now();
        let mut rb = self.http.get(format!("{}/api/v1{path}", self.base));
        if let Some(tok) = &self.token {
            rb = rb.bearer_auth(tok);
        }
        if let Some(tag) = etag {
            rb = rb.header(reqwest::header::IF_NONE_MATCH, tag);
        }
        let resp = match rb.send().await {
            Ok(r) => r,
            Err(e) => {
                self.shared.rec.observe(kind, t, "transport");
                self.shared.rec.error(
                    kind,
                    format!("poller-{}: GET {path}: {}", self.i, with_causes(&e)),
                );
                return None;
            }
        };
        let status = resp.status().as_u16();
        let tag = resp
            .headers()
            .get(reqwest::header::ETAG)
            .and_then(|v| v.to_str().ok())
            .map(str::to_string);
        // The whole body, as the page reads it (`res.json()`, `res.blob()`).
        let body = match resp.bytes().await {
            Ok(b) => b.to_vec(),
            Err(e) => {
                self.shared.rec.observe(kind, t, "transport");
                self.shared.rec.error(
                    kind,
                    format!("poller-{}: GET {path}: body: {}", self.i, with_causes(&e)),
                );
                return None;
            }
        };
        self.shared.rec.observe(kind, t, &status.to_string());
        let ok = matches!(status, 200 | 304) || (gone_ok && status == 404);
        if !ok {
            let text: String = String::from_utf8_lossy(&body).chars().take(200).collect();
            self.shared.rec.error(
                kind,
                format!("poller-{}: GET {path}: {status}: {text}", self.i),
            );
            return None;
        }
        Some(Answer {
            status,
            etag: tag,
            body,
        })
    }

    fn json<T: serde::de::DeserializeOwned>(&self, kind: Kind, a: &Answer) -> Option<T> {
        match serde_json::from_slice(&a.body) {
            Ok(v) => Some(v),
            Err(e) => {
                self.shared
                    .rec
                    .error(kind, format!("poller-{}: undecodable answer: {e}", self.i));
                None
            }
        }
    }

    async fn jobs_list(&self) -> Option<JobList> {
        let a = self
            .get(Kind::JobsList, "/jobs?page=1&per_page=50", None, false)
            .await?;
        self.json(Kind::JobsList, &a)
    }

    pub(super) async fn run(self, page_for: Duration, mut stop: watch::Receiver<bool>) {
        let mut seen: Vec<JobView> = Vec::new();
        let mut visits = 0usize;
        // Tabs start on different pages, so all three are open at any time.
        let mut page = self.i % 3;
        while !*stop.borrow() {
            let until = Instant::now() + page_for;
            match page {
                0 => self.jobs_page(until, &mut seen, &mut stop).await,
                1 => {
                    if seen.is_empty() {
                        // Opened on a job's page: the user came from the list.
                        if let Some(list) = self.jobs_list().await {
                            seen = list.jobs;
                        }
                    }
                    let live: Vec<&JobView> = seen.iter().filter(|j| !j.state.is_final()).collect();
                    let pick = if live.is_empty() {
                        seen.get((self.i + visits) % seen.len().max(1))
                    } else {
                        live.get((self.i + visits) % live.len()).copied()
                    };
                    if let Some(id) = pick.map(|j| j.id.clone()) {
                        visits += 1;
                        self.job_page(&id, until, &stop).await;
                    }
                }
                _ => self.workers_page(until, &mut stop).await,
            }
            page = (page + 1) % 3;
        }
    }

    /// `jobs.js`: the list every second (after the last answer), and a row's thumbnail when its
    /// samples moved, at most every 3 s per row (and once more when the job ends), 2 at a time.
    async fn jobs_page(
        &self,
        until: Instant,
        seen: &mut Vec<JobView>,
        stop: &mut watch::Receiver<bool>,
    ) {
        let mut thumbs: HashMap<String, Thumb> = HashMap::new();
        loop {
            if let Some(list) = self.jobs_list().await {
                thumbs.retain(|id, _| list.jobs.iter().any(|j| &j.id == id));
                let mut fetched = 0;
                for job in &list.jobs {
                    let t = thumbs.entry(job.id.clone()).or_default();
                    if job.samples_done == 0 || Some(job.samples_done) == t.samples_done {
                        continue;
                    }
                    let ended = job.state.is_final() && t.state != Some(job.state);
                    if !ended && t.at.is_some_and(|at| at.elapsed() < THUMB_EVERY) {
                        continue;
                    }
                    if fetched >= THUMB_PARALLEL {
                        break;
                    }
                    fetched += 1;
                    let path = format!("/jobs/{}/preview.png", job.id);
                    if let Some(a) = self
                        .get(Kind::Preview, &path, t.etag.as_deref(), true)
                        .await
                    {
                        if a.status != 404 {
                            t.etag = a.etag.or(t.etag.take());
                            t.samples_done = Some(job.samples_done);
                            t.state = Some(job.state);
                        }
                    }
                    t.at = Some(Instant::now());
                }
                *seen = list.jobs;
            }
            if nap(stop, JOBS_EVERY.min(remaining(until))).await || Instant::now() >= until {
                return;
            }
        }
    }

    /// `job.js`: the job about three times a second while it can change (every 5 s once final),
    /// then its preview when its samples moved (`If-None-Match` with the tag on screen); its
    /// convergence history every second until the final one is fetched. A 404 (the job was
    /// deleted) ends the page, as the dashboard's "No such job".
    async fn job_page(&self, id: &str, until: Instant, stop: &watch::Receiver<bool>) {
        // Set when the page closes (left, or its job deleted): ends the convergence poller too.
        let closed = AtomicBool::new(false);
        // 0: unknown, 1: live, 2: final.
        let state = std::sync::atomic::AtomicU8::new(0);
        let main = async {
            let mut stop = stop.clone();
            let mut shown: Option<(Option<String>, u64)> = None;
            loop {
                let Some(a) = self
                    .get(Kind::Job, &format!("/jobs/{id}"), None, true)
                    .await
                else {
                    if nap(&mut stop, JOB_LIVE_EVERY.min(remaining(until))).await
                        || Instant::now() >= until
                    {
                        break;
                    }
                    continue;
                };
                if a.status == 404 {
                    closed.store(true, Ordering::Relaxed);
                    break;
                }
                let Some(job) = self.json::<JobView>(Kind::Job, &a) else {
                    break;
                };
                let is_final = job.state.is_final();
                state.store(if is_final { 2 } else { 1 }, Ordering::Relaxed);
                let changed = shown.as_ref().is_none_or(|s| s.1 != job.samples_done);
                if job.samples_done > 0 && changed {
                    let held = shown.as_ref().and_then(|s| s.0.clone());
                    let path = format!("/jobs/{id}/preview.png?view=image&exposure=0");
                    if let Some(p) = self.get(Kind::Preview, &path, held.as_deref(), true).await {
                        if p.status == 404 {
                            closed.store(true, Ordering::Relaxed);
                            break;
                        }
                        shown = Some((p.etag.or(held), job.samples_done));
                    }
                }
                let every = if is_final {
                    JOB_FINAL_EVERY
                } else {
                    JOB_LIVE_EVERY
                };
                if nap(&mut stop, every.min(remaining(until))).await || Instant::now() >= until {
                    break;
                }
            }
            closed.store(true, Ordering::Relaxed);
        };
        let convergence = async {
            let mut stop = stop.clone();
            let mut final_fetched = false;
            loop {
                if closed.load(Ordering::Relaxed) {
                    break;
                }
                let s = state.load(Ordering::Relaxed);
                if s != 0 && !final_fetched {
                    let path = format!("/jobs/{id}/convergence");
                    if self
                        .get(Kind::Convergence, &path, None, true)
                        .await
                        .is_some()
                    {
                        final_fetched = s == 2;
                    }
                }
                if nap(&mut stop, CONVERGENCE_EVERY.min(remaining(until))).await
                    || Instant::now() >= until
                {
                    break;
                }
            }
        };
        tokio::join!(main, convergence);
    }

    /// `workers.js`: the list every two seconds.
    async fn workers_page(&self, until: Instant, stop: &mut watch::Receiver<bool>) {
        loop {
            if let Some(a) = self.get(Kind::WorkersList, "/workers", None, false).await {
                let _: Option<pathfarm_wire::api::WorkerList> = self.json(Kind::WorkersList, &a);
            }
            if nap(stop, WORKERS_EVERY.min(remaining(until))).await || Instant::now() >= until {
                return;
            }
        }
    }
}

fn remaining(until: Instant) -> Duration {
    until.saturating_duration_since(Instant::now())
}

/// An error and its causes, outermost first: reqwest's own text ("error sending request") says
/// only which step failed, its causes say why (a reset, a closed connection, a timeout).
fn with_causes(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text
}
