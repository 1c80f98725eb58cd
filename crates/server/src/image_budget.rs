//! The server's budget for image memory: every byte that job images take, kept or in the
//! making, is reserved here first ([`crate::ServerConfig::image_cache_bytes`], 1 GiB by default).
//!
//! A build reserves the image it makes plus what it reads and decodes meanwhile, an encoding the
//! buffers it fills; a finished image keeps the reservation of its own pixels for as long as it
//! lives (in the cache or in a request's hands), and a kept encoding that of its bytes. So the
//! server's image memory stays within the budget however many requests ask for images at once.
//! One piece of work larger than the whole budget (an image of more pixels than the budget holds at
//! 20 bytes each) reserves the whole budget: it waits until nothing else holds any, then runs
//! alone.
//!
//! Reservations are counted in units of [`UNIT`] bytes, rounded up.

use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, TryAcquireError};

/// Bytes per unit of the budget.
pub const UNIT: usize = 1 << 10;

/// The units of `bytes`, rounded up.
fn units_of(bytes: usize) -> usize {
    bytes.div_ceil(UNIT)
}

/// Room taken from the budget, given back when dropped.
#[derive(Debug, Default)]
pub struct Reservation {
    permit: Option<OwnedSemaphorePermit>,
}

impl Reservation {
    /// No room at all (what nothing needs, or what the holder did without).
    pub fn none() -> Reservation {
        Reservation { permit: None }
    }

    /// The bytes this reservation holds (a multiple of [`UNIT`]).
    pub fn bytes(&self) -> usize {
        self.permit.as_ref().map_or(0, |p| p.num_permits()) * UNIT
    }

    /// Whether it holds room for `bytes`.
    pub fn covers(&self, bytes: usize) -> bool {
        self.bytes() >= units_of(bytes) * UNIT
    }

    /// Splits off room for `bytes` (rounded up to whole units), or `None` when this reservation
    /// holds less than that.
    pub fn split(&mut self, bytes: usize) -> Option<Reservation> {
        let n = units_of(bytes);
        if n == 0 {
            return Some(Reservation::none());
        }
        let part = self.permit.as_mut()?.split(n)?;
        Some(Reservation { permit: Some(part) })
    }

    /// Adds `other`'s room to this one.
    pub fn merge(&mut self, other: Reservation) {
        match (&mut self.permit, other.permit) {
            (Some(mine), Some(theirs)) => mine.merge(theirs),
            (mine @ None, theirs) => *mine = theirs,
            (Some(_), None) => {}
        }
    }
}

/// The budget: a semaphore of units.
pub struct ImageBudget {
    units: Arc<Semaphore>,
    total: usize,
    /// How long work waits for room before it is refused (503 `busy`).
    pub wait: Duration,
}

impl ImageBudget {
    /// A budget of `bytes` (at least one unit).
    pub fn new(bytes: usize, wait: Duration) -> ImageBudget {
        let total = units_of(bytes).clamp(1, Semaphore::MAX_PERMITS);
        ImageBudget {
            units: Arc::new(Semaphore::new(total)),
            total,
            wait,
        }
    }

    /// The whole budget in bytes.
    pub fn total_bytes(&self) -> usize {
        self.total * UNIT
    }

    /// The bytes reserved now.
    pub fn reserved_bytes(&self) -> usize {
        (self.total - self.units.available_permits().min(self.total)) * UNIT
    }

    /// The units to ask for `bytes` of work: at most the whole budget, so that work larger than
    /// the budget still runs (alone). Never more than one acquisition can ask for.
    fn units_for(&self, bytes: usize) -> u32 {
        units_of(bytes).min(self.total).min(u32::MAX as usize) as u32
    }

    /// Room for `bytes` (capped at the whole budget) if it is free now.
    pub fn try_reserve(&self, bytes: usize) -> Option<Reservation> {
        let n = self.units_for(bytes);
        if n == 0 {
            return Some(Reservation::none());
        }
        match self.units.clone().try_acquire_many_owned(n) {
            Ok(permit) => Some(Reservation {
                permit: Some(permit),
            }),
            Err(TryAcquireError::NoPermits | TryAcquireError::Closed) => None,
        }
    }

    /// Room for `bytes` (capped at the whole budget), waiting at most `patience` for it.
    pub async fn reserve_within(&self, bytes: usize, patience: Duration) -> Option<Reservation> {
        let n = self.units_for(bytes);
        if n == 0 {
            return Some(Reservation::none());
        }
        match tokio::time::timeout(patience, self.units.clone().acquire_many_owned(n)).await {
            Ok(Ok(permit)) => Some(Reservation {
                permit: Some(permit),
            }),
            // Timed out (the semaphore is never closed).
            Ok(Err(_)) | Err(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reservations_hold_room_until_dropped_and_work_over_the_budget_runs_alone() {
        let budget = ImageBudget::new(10 * UNIT, Duration::from_millis(10));
        let mut a = budget.try_reserve(3 * UNIT + 1).unwrap();
        assert_eq!(a.bytes(), 4 * UNIT);
        assert_eq!(budget.reserved_bytes(), 4 * UNIT);
        let kept = a.split(UNIT).unwrap();
        assert!(a.split(10 * UNIT).is_none());
        drop(a);
        assert_eq!(budget.reserved_bytes(), UNIT);
        // More than the whole budget: it waits until all of it is free.
        assert!(budget.try_reserve(100 * UNIT).is_none());
        assert!(budget
            .reserve_within(100 * UNIT, Duration::from_millis(20))
            .await
            .is_none());
        drop(kept);
        let all = budget.try_reserve(100 * UNIT).unwrap();
        assert_eq!(all.bytes(), budget.total_bytes());
        assert!(budget.try_reserve(1).is_none());
        assert!(budget.try_reserve(0).is_some(), "nothing needs no room");
        let mut merged = Reservation::none();
        merged.merge(all);
        assert!(merged.covers(10 * UNIT) && !merged.covers(10 * UNIT + 1));
    }
}
