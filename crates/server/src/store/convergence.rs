//! Each job's error estimate and its convergence history (error and samples against time), and
//! each frame's of a frame job.

use super::error::{Error, StoreResult};
use super::{ImageEstimate, Store};
use pathfarm_wire::api::{Convergence, ConvergencePoint};
use sqlx::Row;
use std::collections::HashMap;

/// A new point is recorded once the job has run this much longer than at its last point, as a
/// fraction of the elapsed time: points are log-spaced, about 50 per decade of time, so a job of
/// an hour keeps a few hundred rows and the chart on log–log axes stays evenly covered.
const RELATIVE_SPACING: f64 = 0.05;
/// …but never closer than this (early in a job, when the relative spacing would be tiny).
const MIN_SPACING_MS: i64 = 200;

/// An error estimate of one image of a job.
pub struct Estimate {
    /// The job version (merged slices) the image was assembled at.
    pub version: i64,
    pub relative_error: Option<f64>,
    /// Samples in that image.
    pub samples: u64,
    /// Record a history point whatever the spacing (the job's last image).
    pub last: bool,
}

/// Whether a point at `elapsed` ms is due after the last one at `last` (see [`RELATIVE_SPACING`]).
fn due(last: Option<i64>, elapsed: i64) -> bool {
    last.is_none_or(|last| {
        let gap = ((last as f64 * RELATIVE_SPACING) as i64).max(MIN_SPACING_MS);
        elapsed - last >= gap
    })
}

/// The time of a point: `elapsed`, except that an image's last point is never earlier than the
/// point before it, so that it replaces that point rather than being dropped and the history
/// always ends with the final image.
///
/// It can be earlier: the last image may land in the same millisecond as the point before it (a
/// job's final merges come close together), and on PostgreSQL an estimate can read the job
/// still running and time its point at "now" while the finishing merge, which stamped
/// `finished_ms` a moment before, has not yet committed; the final estimate is then timed at
/// `finished_ms`, before that point.
fn final_elapsed(last_image: bool, last: Option<i64>, elapsed: i64) -> i64 {
    match last {
        Some(last) if last_image => elapsed.max(last),
        _ => elapsed,
    }
}

/// An optional error as a bindable number: −1 (which no relative error is) for none, turned back
/// into NULL by the SQL (`NULLIF(…, -1.0)`).
///
/// Why not bind the `Option<f64>`: sqlx 0.9's `Any` driver sends a `None` of `f64` to PostgreSQL
/// as a NULL *float4* (`AnyArguments::convert_into` maps `Null(Double)` to `Option::<f32>`). The
/// connection caches the statement with that parameter type, and every later estimate bound on
/// that connection as a float8 then fails with "incorrect binary data format in bind parameter 1".
fn bindable_error(e: Option<f64>) -> f64 {
    e.unwrap_or(-1.0)
}

impl Store {
    /// Stores the job's current error estimate (unless a newer one is already stored, as another
    /// server may have made it) and adds a point to its history when enough time has passed.
    pub async fn record_estimate(&self, id: &str, e: &Estimate) -> StoreResult<()> {
        self.record_estimates(id, e, &[], |_| false).await
    }

    /// [`Store::record_estimate`], and a point in the history of each frame of a frame job
    /// (`frames`, as the tiles sum them) that has samples since its last point, when one is due
    /// by the job's spacing or the frame has ended (`ended`: every planned sample merged, or its
    /// noise target reached). One transaction: a reader that sees the job's estimate at a version
    /// (`GET /jobs/{id}` refreshes a finished job's only while it is older) also sees every
    /// frame's history as of that version.
    pub async fn record_estimates(
        &self,
        id: &str,
        e: &Estimate,
        frames: &[ImageEstimate],
        ended: impl Fn(&ImageEstimate) -> bool,
    ) -> StoreResult<()> {
        let mut w = self.write().await?;
        self.job_point(&mut w.tx, id, e).await?;
        if !frames.is_empty() {
            self.frame_points(&mut w.tx, id, frames, ended).await?;
        }
        w.commit().await?;
        Ok(())
    }

    async fn job_point(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        id: &str,
        e: &Estimate,
    ) -> StoreResult<()> {
        let row = sqlx::query(
            "UPDATE jobs SET rel_error = NULLIF($1, -1.0), rel_error_version = $2 \
             WHERE id = $3 AND rel_error_version < $2 RETURNING started_ms, finished_ms",
        )
        .bind(bindable_error(e.relative_error))
        .bind(e.version)
        .bind(id)
        .fetch_optional(&mut **tx)
        .await?;
        let Some(row) = row else {
            return Ok(()); // deleted, or a newer estimate won
        };
        let started: Option<i64> = row.try_get("started_ms")?;
        let finished: Option<i64> = row.try_get("finished_ms")?;
        if let Some(started) = started {
            let now = self.now_ms();
            let elapsed = (finished.unwrap_or(now).min(now) - started).max(0);
            let last: Option<i64> =
                sqlx::query("SELECT MAX(elapsed_ms) AS last FROM job_progress WHERE job_id = $1")
                    .bind(id)
                    .fetch_one(&mut **tx)
                    .await?
                    .try_get("last")?;
            let elapsed = final_elapsed(e.last, last, elapsed);
            let due = due(last, elapsed);
            let later = last.is_none_or(|last| elapsed > last || (e.last && elapsed == last));
            if (due || e.last) && later {
                sqlx::query(
                    "INSERT INTO job_progress (job_id, elapsed_ms, samples_done, rel_error) \
                     VALUES ($1, $2, $3, NULLIF($4, -1.0)) ON CONFLICT (job_id, elapsed_ms) \
                     DO UPDATE SET samples_done = excluded.samples_done, rel_error = excluded.rel_error \
                     WHERE job_progress.samples_done < excluded.samples_done",
                )
                .bind(id)
                .bind(elapsed)
                .bind(e.samples as i64)
                .bind(bindable_error(e.relative_error))
                .execute(&mut **tx)
                .await?;
            }
        }
        Ok(())
    }

    async fn frame_points(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        id: &str,
        frames: &[ImageEstimate],
        ended: impl Fn(&ImageEstimate) -> bool,
    ) -> StoreResult<()> {
        let row = sqlx::query("SELECT started_ms, finished_ms FROM jobs WHERE id = $1")
            .bind(id)
            .fetch_optional(&mut **tx)
            .await?;
        let Some(row) = row else {
            return Ok(()); // deleted meanwhile
        };
        let Some(started) = row.try_get::<Option<i64>, _>("started_ms")? else {
            return Ok(()); // nothing leased yet, so nothing merged
        };
        let finished: Option<i64> = row.try_get("finished_ms")?;
        let now = self.now_ms();
        let elapsed = (finished.unwrap_or(now).min(now) - started).max(0);
        let lasts: HashMap<i64, (i64, i64)> = sqlx::query(
            "SELECT frame, MAX(elapsed_ms) AS last, MAX(samples_done) AS samples \
             FROM frame_progress WHERE job_id = $1 GROUP BY frame",
        )
        .bind(id)
        .fetch_all(&mut **tx)
        .await?
        .iter()
        .map(|r| {
            Ok((
                r.try_get("frame")?,
                (r.try_get("last")?, r.try_get("samples")?),
            ))
        })
        .collect::<Result<_, sqlx::Error>>()?;
        for f in frames {
            let Some(frame) = f.frame else { continue };
            let last = lasts.get(&frame).copied();
            let samples = f.samples_done as i64;
            if samples == 0 || last.is_some_and(|(_, n)| n >= samples) {
                continue; // nothing new
            }
            let ended = ended(f);
            let last_ms = last.map(|(t, _)| t);
            let elapsed = final_elapsed(ended, last_ms, elapsed);
            let later = last_ms.is_none_or(|t| elapsed > t || (ended && elapsed == t));
            if (due(last_ms, elapsed) || ended) && later {
                sqlx::query(
                    "INSERT INTO frame_progress (job_id, frame, elapsed_ms, samples_done, rel_error) \
                     VALUES ($1, $2, $3, $4, NULLIF($5, -1.0)) \
                     ON CONFLICT (job_id, frame, elapsed_ms) DO UPDATE SET \
                     samples_done = excluded.samples_done, rel_error = excluded.rel_error \
                     WHERE frame_progress.samples_done < excluded.samples_done",
                )
                .bind(id)
                .bind(frame)
                .bind(elapsed)
                .bind(samples)
                .bind(bindable_error(f.relative_error))
                .execute(&mut **tx)
                .await?;
            }
        }
        Ok(())
    }

    /// The convergence history, oldest first: the job's, or with `frame` that frame's (a frame
    /// of the job's; the caller checks it is one).
    pub async fn convergence(&self, id: &str, frame: Option<i64>) -> StoreResult<Convergence> {
        let mut tx = self.pool().begin().await?;
        let exists = sqlx::query("SELECT 1 AS one FROM jobs WHERE id = $1")
            .bind(id)
            .fetch_optional(&mut *tx)
            .await?
            .is_some();
        if !exists {
            return Err(Error::not_found("job", id));
        }
        let rows = match frame {
            None => {
                sqlx::query(
                    "SELECT elapsed_ms, samples_done, rel_error FROM job_progress \
                     WHERE job_id = $1 ORDER BY elapsed_ms",
                )
                .bind(id)
                .fetch_all(&mut *tx)
                .await?
            }
            Some(frame) => {
                sqlx::query(
                    "SELECT elapsed_ms, samples_done, rel_error FROM frame_progress \
                     WHERE job_id = $1 AND frame = $2 ORDER BY elapsed_ms",
                )
                .bind(id)
                .bind(frame)
                .fetch_all(&mut *tx)
                .await?
            }
        };
        tx.commit().await?;
        let mut points = Vec::with_capacity(rows.len());
        let (mut prev_t, mut prev_n) = (0i64, 0i64);
        for r in &rows {
            let t: i64 = r.try_get("elapsed_ms")?;
            let n: i64 = r.try_get("samples_done")?;
            let dt = (t - prev_t).max(1) as f64 / 1000.0;
            points.push(ConvergencePoint {
                elapsed_s: t as f64 / 1000.0,
                samples_done: n.max(0) as u64,
                relative_error: r.try_get("rel_error")?,
                samples_per_second: (n - prev_n).max(0) as f64 / dt,
            });
            (prev_t, prev_n) = (t, n);
        }
        Ok(Convergence {
            job_id: id.to_string(),
            points,
        })
    }
}
