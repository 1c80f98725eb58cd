//! Job churn.

use super::recorder::Kind;
use super::{nap, Shared, SoakConfig};
use crate::harness::farm_err;
use crate::loadgen::synthetic;
use crate::BenchError;
use pathfarm_tracer::output::decode_exr;
use pathfarm_wire::api::{JobSettings, JobState, JobView};
use pathfarm_wire::{decode_slice, SliceLimits};
use pathfarm_worker::client::ApiClient;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

#[derive(Default)]
pub(super) struct Churn {
    pub(super) submitted: u64,
    pub(super) completed: u64,
    pub(super) verified: u64,
    pub(super) deleted: u64,
    /// Samples of the completed jobs, read before they were deleted.
    pub(super) completed_samples: u64,
    pub(super) job_seconds: Vec<f64>,
    /// Jobs live when the run stopped.
    pub(super) live: Vec<String>,
}

/// What every pixel of a completed job must be: the mean of the synthetic slices, as the server's
/// EXR writes it (f32), computed here from one of those slices.
pub(super) fn expected_pixel() -> Result<[f32; 3], BenchError> {
    let bytes = synthetic(0, 0, 1, 1, 0, 1);
    let slice = decode_slice(&bytes, &SliceLimits { max_pixels: 1 })
        .map_err(|e| farm_err(format!("soak: decoding a synthetic slice: {e}")))?;
    slice
        .acc
        .mean_image()
        .first()
        .map(|p| [p[0], p[1], p[2]])
        .ok_or_else(|| farm_err("soak: an empty synthetic slice"))
}

async fn submit(
    client: &ApiClient,
    cfg: &SoakConfig,
    scene: &[u8],
    n: u64,
    shared: &Shared,
) -> Option<String> {
    let mut s = JobSettings::new(cfg.job.width, cfg.job.height, cfg.job.spp);
    s.tile_size = cfg.job.tile_size;
    s.name = Some(format!("soak-{n}"));
    let t = Instant::now();
    let r = client.submit(scene.to_vec(), "soak.gltf", &s).await;
    shared
        .rec
        .client(Kind::Submit, t, r, || format!("job {n}"))
        .map(|c| c.id)
}

/// Checks a completed job's image: every pixel `expected`, every pixel `spp` samples.
async fn verify(client: &ApiClient, job: &JobView, expected: [f32; 3], shared: &Shared) -> bool {
    let t = Instant::now();
    let r = client.image_exr(&job.id, true).await;
    let Some(bytes) = shared
        .rec
        .client(Kind::ImageExr, t, r, || format!("job {}", job.id))
    else {
        return false;
    };
    let fail = |what: String| {
        shared
            .rec
            .error(Kind::ImageExr, format!("job {}: {what}", job.id));
        false
    };
    let img = match decode_exr(&bytes) {
        Ok(i) => i,
        Err(e) => return fail(format!("undecodable EXR: {e}")),
    };
    let (w, h) = (job.settings.width as usize, job.settings.height as usize);
    if (img.width, img.height) != (w, h) {
        return fail(format!("EXR is {}×{}, not {w}×{h}", img.width, img.height));
    }
    let planned = job.settings.width as u64 * job.settings.height as u64 * job.settings.spp as u64;
    if job.samples_done != planned {
        return fail(format!(
            "completed with {} samples merged, {planned} planned",
            job.samples_done
        ));
    }
    let spp = job.settings.spp as f32;
    for (name, want) in [
        ("R", expected[0]),
        ("G", expected[1]),
        ("B", expected[2]),
        ("samples", spp),
    ] {
        let values = match img.channel(name) {
            Ok(v) => v,
            Err(e) => return fail(e.to_string()),
        };
        if let Some(i) = values.iter().position(|&v| v.to_bits() != want.to_bits()) {
            return fail(format!(
                "channel {name} of pixel ({}, {}) is {}, not {want}",
                i % w,
                i / w,
                values[i]
            ));
        }
    }
    true
}

/// Keeps `cfg.live_jobs` jobs live: checks the list every half second; a completed job is
/// verified, deleted and replaced; a job that ends otherwise is an error (and replaced too).
pub(super) async fn churn(
    client: ApiClient,
    cfg: Arc<SoakConfig>,
    scene: Arc<Vec<u8>>,
    expected: [f32; 3],
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) -> Churn {
    let mut c = Churn::default();
    let mut live: Vec<(String, Instant)> = Vec::new();
    // The first jobs go in one "farm job time" apart (what the whole farm takes for one job's
    // uploads), so that their generations stay staggered: submitted together, they would all end
    // together, and the farm would run dry in every generation's tail instead of moving on to
    // the other jobs.
    let stagger = Duration::from_secs_f64(cfg.job.uploads() as f64 * cfg.pace / cfg.workers as f64);
    let mut next_first = Instant::now();
    let mut filled = false;
    loop {
        while live.len() < cfg.live_jobs
            && !*stop.borrow()
            && (filled || Instant::now() >= next_first)
        {
            let Some(id) = submit(&client, &cfg, &scene, c.submitted, &shared).await else {
                break;
            };
            c.submitted += 1;
            live.push((id, Instant::now()));
            next_first = Instant::now() + stagger;
            // Staggered until the first `live_jobs` are in; replacements go in at once.
            filled |= c.submitted >= cfg.live_jobs as u64;
        }
        if nap(&mut stop, Duration::from_millis(500)).await {
            break;
        }
        let t = Instant::now();
        let r = client.jobs(None, 1, 100).await;
        let Some(list) = shared.rec.client(Kind::JobsList, t, r, || "churn".into()) else {
            continue;
        };
        for job in list.jobs.iter().filter(|j| j.state.is_final()) {
            let Some(pos) = live.iter().position(|(id, _)| id == &job.id) else {
                continue;
            };
            let (_, submitted_at) = live.remove(pos);
            if job.state == JobState::Completed {
                c.completed += 1;
                c.completed_samples += job.samples_done;
                c.job_seconds.push(submitted_at.elapsed().as_secs_f64());
                if verify(&client, job, expected, &shared).await {
                    c.verified += 1;
                }
            } else {
                shared.rec.error(
                    Kind::JobsList,
                    format!(
                        "job {} ended {} ({:?})",
                        job.id,
                        job.state.as_str(),
                        job.message
                    ),
                );
            }
            let t = Instant::now();
            let r = client.delete_job(&job.id).await;
            if shared
                .rec
                .client(Kind::Delete, t, r, || format!("job {}", job.id))
                .is_some()
            {
                c.deleted += 1;
            }
        }
    }
    c.live = live.into_iter().map(|(id, _)| id).collect();
    c
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_expected_pixel_is_the_synthetic_radiance() {
        assert_eq!(expected_pixel().unwrap(), [0.5, 0.25, 0.125]);
    }
}
