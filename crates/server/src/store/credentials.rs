//! Worker credentials this server has looked up lately, so that a worker's calls (every lease,
//! heartbeat and upload) do not each begin with a database round trip to learn whose credential
//! it is: on a busy farm that lookup waited for a pooled connection as long as the work it
//! authorised, even for a lease refused in memory (docs/benchmarks.md, "a lease in one round
//! trip, and a shorter write queue").
//!
//! A credential names the same worker for as long as the worker's row lives: ids and credentials
//! are made at registration and never change, so a cached answer can be wrong only once the row
//! is deleted (an idle registration collected: `Store::collect_idle_workers`). This server then
//! forgets every entry at once; another server sharing the database forgets it within
//! [`TTL`]. Until then the collected worker's calls there find no worker (404) or a stale lease
//! instead of an unknown credential (401): its leases went back to the queue with the collection,
//! so it can take nothing, and `pathfarm worker` registers again on that 404 as on the 401.
//! Only credentials that were found are kept (random guesses add nothing), at most [`CAPACITY`]
//! of them.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How long a lookup is trusted. Longer than the slices a loaded farm asks for, so a worker
/// that uploads once a slice finds its entry.
pub const TTL: Duration = Duration::from_secs(120);

/// The most entries kept (about 150 bytes each): ten times the workers the load tests drive.
pub const CAPACITY: usize = 100_000;

#[derive(Default)]
pub struct CredentialCache {
    /// Credential digest → (worker id, when it was read from the database).
    entries: Mutex<HashMap<String, (String, Instant)>>,
    /// Counts the clears: a lookup that read the database before a clear does not insert what
    /// it read after it (the row may be the one just deleted).
    clears: AtomicU64,
}

/// When a lookup began: its time and the clears before it ([`CredentialCache::lookup_began`]).
#[derive(Clone, Copy)]
pub struct LookupStart {
    at: Instant,
    clears: u64,
}

impl CredentialCache {
    /// The worker `digest` belongs to, if it was read within [`TTL`] of `now`.
    pub fn get(&self, digest: &str, now: Instant) -> Option<String> {
        let entries = self.entries.lock().ok()?;
        let (id, read) = entries.get(digest)?;
        (now.saturating_duration_since(*read) < TTL).then(|| id.clone())
    }

    /// Marks the start of a database lookup, before its query.
    pub fn lookup_began(&self, at: Instant) -> LookupStart {
        LookupStart {
            at,
            clears: self.clears.load(Ordering::SeqCst),
        }
    }

    /// Remembers that `digest` belongs to `id`, as a lookup begun at `start` read it (nothing,
    /// when the cache was cleared since).
    pub fn insert(&self, digest: String, id: String, start: LookupStart) {
        let Ok(mut entries) = self.entries.lock() else {
            return;
        };
        // Under the lock, which `clear` takes too: a clear is either counted here or after
        // this insert (and then removes it).
        if self.clears.load(Ordering::SeqCst) != start.clears {
            return;
        }
        let read = start.at;
        if entries.len() >= CAPACITY {
            entries.retain(|_, (_, at)| read.saturating_duration_since(*at) < TTL);
            if entries.len() >= CAPACITY {
                entries.clear();
            }
        }
        entries.insert(digest, (id, read));
    }

    /// Forgets every entry (worker rows were deleted).
    pub fn clear(&self) {
        if let Ok(mut entries) = self.entries.lock() {
            self.clears.fetch_add(1, Ordering::SeqCst);
            entries.clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_answer_until_their_time_is_up_or_they_are_cleared() {
        let cache = CredentialCache::default();
        let t0 = Instant::now();
        assert_eq!(cache.get("d1", t0), None);
        cache.insert("d1".into(), "w1".into(), cache.lookup_began(t0));
        assert_eq!(cache.get("d1", t0 + TTL / 2).as_deref(), Some("w1"));
        assert_eq!(cache.get("d1", t0 + TTL), None);
        assert_eq!(cache.get("d2", t0), None);
        cache.clear();
        assert_eq!(cache.get("d1", t0), None);
    }

    #[test]
    fn a_lookup_begun_before_a_clear_inserts_nothing() {
        let cache = CredentialCache::default();
        let t0 = Instant::now();
        let start = cache.lookup_began(t0);
        cache.clear();
        cache.insert("d1".into(), "w1".into(), start);
        assert_eq!(cache.get("d1", t0), None);
        cache.insert("d1".into(), "w1".into(), cache.lookup_began(t0));
        assert_eq!(cache.get("d1", t0).as_deref(), Some("w1"));
    }

    #[test]
    fn a_full_cache_drops_the_stale_entries_first() {
        let cache = CredentialCache::default();
        let t0 = Instant::now();
        for i in 0..CAPACITY - 1 {
            cache.insert(format!("old{i}"), "w".into(), cache.lookup_began(t0));
        }
        let later = t0 + TTL / 2;
        cache.insert("fresh".into(), "wf".into(), cache.lookup_began(later));
        // Full: the next insert past the TTL of the old ones drops them, not the fresh one.
        let past = t0 + TTL + Duration::from_secs(1);
        cache.insert("new".into(), "wn".into(), cache.lookup_began(past));
        assert_eq!(cache.get("fresh", past).as_deref(), Some("wf"));
        assert_eq!(cache.get("new", past).as_deref(), Some("wn"));
        assert_eq!(cache.entries.lock().unwrap().len(), 2);
    }
}
