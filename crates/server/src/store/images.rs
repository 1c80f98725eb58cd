//! Reading a job's image from the store: one snapshot of its tiles (the job's version and every
//! tile's sample count and stored size), then the stored accumulations a batch of tiles at a time
//! within that snapshot, so that assembling an image never holds all of them at once.

use super::error::{Error, StoreResult};
use super::{Dialect, Store};
use sqlx::{Any, AnyPool, Row, Transaction};

/// What the snapshot says of one tile.
#[derive(Clone, Copy, Debug)]
pub struct TileMeta {
    pub index: i64,
    /// Samples merged into every pixel of the tile.
    pub samples: u64,
    /// The bytes of its stored accumulation; 0 before its first slice.
    pub stored: u64,
}

/// Reads images; cheap to clone, so that work running apart from any request can own one.
#[derive(Clone)]
pub struct ImageReader {
    pool: AnyPool,
    dialect: Dialect,
}

/// One consistent view of a job's tiles: a read-only transaction (on PostgreSQL at `REPEATABLE
/// READ`, so that its queries see one snapshot; SQLite's read transactions always do).
pub struct ImageSnapshot {
    tx: Transaction<'static, Any>,
    job_id: String,
    /// The job's version, or a frame's ([`ImageReader::frame_version`]) for a frame's tiles.
    pub version: i64,
    pub tiles: Vec<TileMeta>,
}

impl Store {
    pub fn image_reader(&self) -> ImageReader {
        ImageReader {
            pool: self.pool().clone(),
            dialect: self.dialect(),
        }
    }
}

impl ImageReader {
    /// The job's version and tiles (those of `tiles`, an index range with both ends included:
    /// a frame's, and then the frame's version; `None`: all); 404 when the job is gone.
    pub async fn snapshot(
        &self,
        job_id: &str,
        tiles: Option<(i64, i64)>,
    ) -> StoreResult<ImageSnapshot> {
        let frame = tiles.is_some();
        let mut tx = self.pool.begin().await?;
        if self.dialect == Dialect::Postgres {
            sqlx::query("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ, READ ONLY")
                .execute(&mut *tx)
                .await?;
        }
        let version: i64 = match sqlx::query("SELECT version FROM jobs WHERE id = $1")
            .bind(job_id)
            .fetch_optional(&mut *tx)
            .await?
        {
            Some(r) => r.try_get("version")?,
            None => return Err(Error::not_found("job", job_id)),
        };
        let rows = sqlx::query(
            "SELECT tile_index, samples, merges, \
             CAST(COALESCE(length(accum), 0) AS BIGINT) AS stored FROM tiles WHERE job_id = $1 AND tile_index >= $2 AND tile_index <= $3 \
             ORDER BY tile_index",
        )
        .bind(job_id)
        .bind(tiles.map_or(0, |t| t.0))
        .bind(tiles.map_or(i64::MAX, |t| t.1))
        .fetch_all(&mut *tx)
        .await?;
        let tiles = rows
            .iter()
            .map(|r| {
                Ok(TileMeta {
                    index: r.try_get("tile_index")?,
                    samples: r.try_get::<i64, _>("samples")?.max(0) as u64,
                    stored: r.try_get::<i64, _>("stored")?.max(0) as u64,
                })
            })
            .collect::<Result<Vec<_>, sqlx::Error>>()?;
        let version = if frame {
            rows.iter()
                .map(|r| r.try_get::<i64, _>("merges"))
                .sum::<Result<i64, sqlx::Error>>()?
        } else {
            version
        };
        Ok(ImageSnapshot {
            tx,
            job_id: job_id.to_string(),
            version,
            tiles,
        })
    }
}

impl ImageReader {
    /// The version of a frame's image: the slices merged into its tiles (`tiles`, an index range
    /// with both ends included), so that it changes only when the frame does. 0 before its first
    /// slice (and for a job that is gone).
    pub async fn frame_version(&self, job_id: &str, (first, last): (i64, i64)) -> StoreResult<i64> {
        let row = sqlx::query(
            "SELECT CAST(COALESCE(SUM(merges), 0) AS BIGINT) AS v FROM tiles \
             WHERE job_id = $1 AND tile_index >= $2 AND tile_index <= $3",
        )
        .bind(job_id)
        .bind(first)
        .bind(last)
        .fetch_one(&self.pool)
        .await?;
        Ok(row.try_get("v")?)
    }
}

impl ImageSnapshot {
    /// The stored accumulations (slice encoding) of the tiles `first..=last` that have one, by
    /// tile index.
    pub async fn stored(&mut self, first: i64, last: i64) -> StoreResult<Vec<(i64, Vec<u8>)>> {
        let rows = sqlx::query(
            "SELECT tile_index, accum FROM tiles WHERE job_id = $1 AND tile_index >= $2 \
             AND tile_index <= $3 AND accum IS NOT NULL ORDER BY tile_index",
        )
        .bind(&self.job_id)
        .bind(first)
        .bind(last)
        .fetch_all(&mut *self.tx)
        .await?;
        Ok(rows
            .iter()
            .map(|r| Ok((r.try_get("tile_index")?, r.try_get("accum")?)))
            .collect::<Result<Vec<_>, sqlx::Error>>()?)
    }

    /// Ends the read transaction.
    pub async fn end(self) -> StoreResult<()> {
        self.tx.commit().await?;
        Ok(())
    }
}
