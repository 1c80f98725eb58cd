//! One budget for the request bodies the server holds in memory at once: a scene submission (up
//! to the scene limit) and a slice upload (up to its tile's largest honest slice) are read whole
//! before they are checked further, so without a bound a crowd of concurrent large uploads could
//! take as much memory as the connection cap times the largest body. Each such request reserves
//! its declared length (its route's limit when it declares none) before its body is read, and
//! holds the reservation until it is answered; one larger than the whole budget waits for all of
//! it and runs alone. A request that finds no room within [`crate::config::Limits::body_wait`]
//! is answered 503 `busy` with `Retry-After`, before any of its body is read.

use crate::error::{ApiError, ApiResult};
use std::time::Duration;
use tokio::sync::{Semaphore, SemaphorePermit};

/// The budget's unit: reservations are rounded up to whole KiB.
const UNIT: u64 = 1024;

/// The `Retry-After` of a refusal, in seconds.
const RETRY_AFTER_SECONDS: u32 = 2;

pub struct BodyBudget {
    units: Semaphore,
    total: u32,
    wait: Duration,
}

impl BodyBudget {
    /// A budget of `bytes` (at least one unit), where a reservation waits at most `wait`.
    pub fn new(bytes: u64, wait: Duration) -> BodyBudget {
        let total = u32::try_from(bytes.div_ceil(UNIT).max(1)).unwrap_or(u32::MAX >> 3);
        BodyBudget {
            units: Semaphore::new(total as usize),
            total,
            wait,
        }
    }

    /// Reserves room for a body of `bytes` (`what` names it in a refusal).
    pub async fn reserve(&self, bytes: u64, what: &str) -> ApiResult<SemaphorePermit<'_>> {
        let units = u32::try_from(bytes.div_ceil(UNIT))
            .unwrap_or(u32::MAX)
            .clamp(1, self.total);
        match tokio::time::timeout(self.wait, self.units.acquire_many(units)).await {
            Ok(Ok(permit)) => Ok(permit),
            Ok(Err(e)) => Err(ApiError::internal(format!("body budget: {e}"))),
            Err(_) => Err(ApiError::busy(
                format!(
                    "the server holds as many request bodies as it may ({} MiB); {what} of {bytes} \
                     bytes must wait: try again",
                    (u64::from(self.total) * UNIT) >> 20
                ),
                RETRY_AFTER_SECONDS,
            )),
        }
    }

    /// Bytes free now (for tests and diagnostics).
    pub fn available(&self) -> u64 {
        self.units.available_permits() as u64 * UNIT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reservations_wait_for_room_and_give_up_after_the_wait() {
        let budget = BodyBudget::new(10 * UNIT, Duration::from_millis(50));
        let a = budget.reserve(6 * UNIT, "a").await.unwrap();
        assert_eq!(budget.available(), 4 * UNIT);
        let e = budget.reserve(5 * UNIT, "b").await.unwrap_err();
        assert_eq!((e.status.as_u16(), e.code), (503, "busy"));
        assert_eq!(e.retry_after, Some(RETRY_AFTER_SECONDS));
        drop(a);
        // Larger than the whole budget: it waits for all of it.
        let all = budget.reserve(100 * UNIT, "c").await.unwrap();
        assert_eq!(budget.available(), 0);
        drop(all);
        assert_eq!(budget.available(), 10 * UNIT);
        // Rounded up to a unit, never zero.
        let one = budget.reserve(0, "d").await.unwrap();
        assert_eq!(budget.available(), 9 * UNIT);
        drop(one);
    }
}
