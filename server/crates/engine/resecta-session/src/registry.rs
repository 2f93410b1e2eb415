//! The session table: the sessions held in memory and the memory each uses, the session-count
//! and memory quotas as reservations (checked and taken in one step, given back when what they
//! were taken for fails), and which sessions are idle past the expiry. No store and no async:
//! the session operations (`sessions`) and the upload call it with what the store says.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use crate::error::{Quota, Result, SessionError};
use crate::support::internal;

/// When a held session was last used (ms since the epoch).
pub(crate) trait LastAccess {
    fn last_access_ms(&self) -> i64;
}

/// The sessions held in memory with their memory, and the two quotas over all sessions.
#[derive(Debug)]
pub(crate) struct Registry<T> {
    max_sessions: u64,
    max_memory: u64,
    table: Mutex<Table<T>>,
    /// Sessions stored plus those being created; `None` until the first reservation counts
    /// the stored ones.
    sessions: Mutex<Option<u64>>,
}

#[derive(Debug)]
struct Table<T> {
    held: HashMap<String, Held<T>>,
    /// Bytes reserved by label maps being loaded.
    reserved: u64,
}

#[derive(Debug)]
struct Held<T> {
    session: Arc<T>,
    memory: u64,
}

impl<T> Table<T> {
    fn memory(&self) -> u64 {
        self.held.values().map(|h| h.memory).sum::<u64>() + self.reserved
    }
}

/// A place in the session-count quota: kept by [`SessionSlot::commit`], given back when dropped.
#[must_use]
#[derive(Debug)]
pub(crate) struct SessionSlot<'a> {
    sessions: &'a Mutex<Option<u64>>,
    committed: bool,
}

impl SessionSlot<'_> {
    /// The session was created: the place stays taken.
    pub(crate) fn commit(mut self) {
        self.committed = true;
    }
}

impl Drop for SessionSlot<'_> {
    fn drop(&mut self) {
        if !self.committed
            && let Ok(mut n) = self.sessions.lock()
            && let Some(n) = n.as_mut()
        {
            *n = n.saturating_sub(1);
        }
    }
}

/// Bytes of the memory quota reserved for a session's label map: the session's memory once
/// [`MemorySlot::commit`]ted, given back when dropped.
#[must_use]
#[derive(Debug)]
pub(crate) struct MemorySlot<'a, T> {
    registry: &'a Registry<T>,
    id: String,
    bytes: u64,
}

impl<T> MemorySlot<'_, T> {
    /// The label map is loaded: its bytes become the session's memory (none if the session
    /// was dropped meanwhile).
    pub(crate) fn commit(self) -> Result<()> {
        let mut table = self.registry.table()?;
        if let Some(held) = table.held.get_mut(&self.id) {
            held.memory = self.bytes;
        }
        Ok(())
    }
}

impl<T> Drop for MemorySlot<'_, T> {
    fn drop(&mut self) {
        if let Ok(mut table) = self.registry.table.lock() {
            table.reserved = table.reserved.saturating_sub(self.bytes);
        }
    }
}

impl<T> Registry<T> {
    pub(crate) fn new(max_sessions: usize, max_memory: u64) -> Self {
        Self {
            max_sessions: max_sessions as u64,
            max_memory,
            table: Mutex::new(Table {
                held: HashMap::new(),
                reserved: 0,
            }),
            sessions: Mutex::new(None),
        }
    }

    fn table(&self) -> Result<MutexGuard<'_, Table<T>>> {
        self.table
            .lock()
            .map_err(|_| internal("session table lock poisoned"))
    }

    fn sessions(&self) -> Result<MutexGuard<'_, Option<u64>>> {
        self.sessions
            .lock()
            .map_err(|_| internal("session count lock poisoned"))
    }

    pub(crate) fn get(&self, id: &str) -> Result<Option<Arc<T>>> {
        Ok(self.table()?.held.get(id).map(|h| Arc::clone(&h.session)))
    }

    /// The session `id` as held, or else `fresh`, held from now on.
    pub(crate) fn get_or_insert(&self, id: &str, fresh: Arc<T>) -> Result<Arc<T>> {
        let mut table = self.table()?;
        let held = table.held.entry(id.to_owned()).or_insert(Held {
            session: fresh,
            memory: 0,
        });
        Ok(Arc::clone(&held.session))
    }

    /// Holds `session` as `id`; returns how many sessions are held.
    pub(crate) fn insert(&self, id: &str, session: Arc<T>) -> Result<usize> {
        let mut table = self.table()?;
        table
            .held
            .insert(id.to_owned(), Held { session, memory: 0 });
        Ok(table.held.len())
    }

    /// Stops holding `id`, and frees its memory.
    pub(crate) fn remove(&self, id: &str) -> Result<Option<Arc<T>>> {
        Ok(self.table()?.held.remove(id).map(|h| h.session))
    }

    /// Takes a place in the session-count quota, or refuses with [`Quota::Sessions`]: the check
    /// and the taking are one step, so parallel creations never pass the limit together.
    /// `count_stored` counts the stored sessions; it is called once, under the count's lock,
    /// on the first reservation (the count is kept from then on).
    pub(crate) fn reserve_session(
        &self,
        count_stored: impl FnOnce() -> Result<u64>,
    ) -> Result<SessionSlot<'_>> {
        let mut sessions = self.sessions()?;
        let n = match *sessions {
            Some(n) => n,
            None => *sessions.insert(count_stored()?),
        };
        if n >= self.max_sessions {
            return Err(SessionError::Quota(
                Quota::Sessions,
                format!("the server holds {n} sessions, its limit"),
            ));
        }
        *sessions = Some(n + 1);
        Ok(SessionSlot {
            sessions: &self.sessions,
            committed: false,
        })
    }

    /// Deletes a stored session with `delete` (which says whether it existed) under the count's
    /// lock, and counts it out.
    pub(crate) fn delete_stored(&self, delete: impl FnOnce() -> Result<bool>) -> Result<bool> {
        let mut sessions = self.sessions()?;
        let existed = delete()?;
        if existed && let Some(n) = sessions.as_mut() {
            *n = n.saturating_sub(1);
        }
        Ok(existed)
    }

    /// Estimated memory of all held sessions, reservations included.
    pub(crate) fn memory_in_use(&self) -> Result<u64> {
        Ok(self.table()?.memory())
    }

    /// Sets the memory of a held session (a restored label map's; restoring checks the budget
    /// itself, and never refuses a call's session).
    pub(crate) fn set_memory(&self, id: &str, bytes: u64) -> Result<()> {
        if let Some(held) = self.table()?.held.get_mut(id) {
            held.memory = bytes;
        }
        Ok(())
    }

    /// Reserves `bytes` for a new label map of session `id`, which replaces its present one,
    /// or refuses with `refused(bytes in use by the others)`: the check and the reservation
    /// are one step, so parallel uploads never pass the limit together.
    pub(crate) fn reserve_memory(
        &self,
        id: &str,
        bytes: u64,
        refused: impl FnOnce(u64) -> SessionError,
    ) -> Result<MemorySlot<'_, T>> {
        let mut table = self.table()?;
        let own = table.held.get(id).map_or(0, |h| h.memory);
        let others = table.memory() - own;
        if others.saturating_add(bytes) > self.max_memory {
            return Err(refused(others));
        }
        table.reserved += bytes;
        Ok(MemorySlot {
            registry: self,
            id: id.to_owned(),
            bytes,
        })
    }
}

impl<T: LastAccess> Registry<T> {
    /// Whether session `id`, which the store finds idle since `before`, is still idle: not
    /// held, or held and not used since.
    pub(crate) fn still_idle(&self, id: &str, before: i64) -> Result<bool> {
        Ok(self
            .table()?
            .held
            .get(id)
            .is_none_or(|h| h.session.last_access_ms() < before))
    }
}

/// Sessions last used before this time (ms) are idle at `now_ms` past `expiry`.
pub(crate) fn idle_cutoff(now_ms: i64, expiry: Duration) -> i64 {
    now_ms - i64::try_from(expiry.as_millis()).unwrap_or(i64::MAX)
}

#[cfg(test)]
mod tests {
    use std::sync::Barrier;
    use std::sync::atomic::{AtomicI64, Ordering};

    use super::*;

    #[derive(Debug, Default)]
    struct Fake(AtomicI64);

    impl LastAccess for Fake {
        fn last_access_ms(&self) -> i64 {
            self.0.load(Ordering::Relaxed)
        }
    }

    fn fake(last: i64) -> Arc<Fake> {
        Arc::new(Fake(AtomicI64::new(last)))
    }

    fn refused(others: u64) -> SessionError {
        SessionError::Quota(Quota::Memory, format!("{others} in use"))
    }

    /// How many of `threads` threads, started together, get `true` from `try_take(i)`.
    fn granted_in_parallel(threads: usize, try_take: impl Fn(usize) -> bool + Sync) -> usize {
        let barrier = Barrier::new(threads);
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|i| {
                    let (barrier, try_take) = (&barrier, &try_take);
                    scope.spawn(move || {
                        barrier.wait();
                        try_take(i)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap())
                .filter(|&ok| ok)
                .count()
        })
    }

    #[test]
    fn parallel_reservations_never_pass_the_session_quota() {
        let registry = Registry::<Fake>::new(10, 0);
        let granted = granted_in_parallel(60, |_| match registry.reserve_session(|| Ok(3)) {
            Ok(slot) => {
                slot.commit();
                true
            }
            Err(SessionError::Quota(Quota::Sessions, _)) => false,
            Err(e) => panic!("{e}"),
        });
        assert_eq!(granted, 7, "3 stored, limit 10");
        let e = registry.reserve_session(|| Ok(0)).unwrap_err();
        assert!(e.to_string().contains("holds 10 sessions"), "{e}");
    }

    #[test]
    fn a_session_place_is_given_back_when_the_creation_fails_and_on_delete() {
        let registry = Registry::<Fake>::new(2, 0);
        let mut counted = 0;
        let first = registry
            .reserve_session(|| {
                counted += 1;
                Ok(1)
            })
            .unwrap();
        // The last place is taken: a second creation is refused until the first fails.
        assert!(registry.reserve_session(|| Ok(0)).is_err());
        drop(first);
        registry.reserve_session(|| Ok(0)).unwrap().commit();
        assert!(registry.reserve_session(|| Ok(0)).is_err());
        assert_eq!(counted, 1, "the store is counted once");
        // A delete of nothing frees nothing; a delete of a stored session frees its place.
        assert!(!registry.delete_stored(|| Ok(false)).unwrap());
        assert!(registry.reserve_session(|| Ok(0)).is_err());
        assert!(registry.delete_stored(|| Ok(true)).unwrap());
        registry.reserve_session(|| Ok(0)).unwrap().commit();
    }

    #[test]
    fn a_failing_count_takes_no_place() {
        let registry = Registry::<Fake>::new(1, 0);
        assert!(matches!(
            registry.reserve_session(|| Err(internal("store down"))),
            Err(SessionError::Internal(_))
        ));
        registry.reserve_session(|| Ok(0)).unwrap().commit();
    }

    #[test]
    fn parallel_memory_reservations_never_pass_the_budget() {
        const THREADS: usize = 32;
        let registry = Registry::new(THREADS, 1000);
        for i in 0..THREADS {
            registry.insert(&i.to_string(), fake(0)).unwrap();
        }
        let granted = granted_in_parallel(THREADS, |i| {
            registry
                .reserve_memory(&i.to_string(), 300, refused)
                .and_then(MemorySlot::commit)
                .is_ok()
        });
        assert_eq!(granted, 3);
        assert_eq!(registry.memory_in_use().unwrap(), 900);
    }

    #[test]
    fn memory_is_accounted_per_session_and_freed_with_it() {
        let registry = Registry::new(4, 1000);
        registry.insert("a", fake(0)).unwrap();
        registry.insert("b", fake(0)).unwrap();
        registry.set_memory("a", 600).unwrap();
        // A reservation counts while it is held, and is given back when dropped.
        let slot = registry.reserve_memory("b", 400, refused).unwrap();
        assert_eq!(registry.memory_in_use().unwrap(), 1000);
        let e = registry.reserve_memory("c", 1, refused).unwrap_err();
        assert!(e.to_string().contains("1000 in use"), "{e}");
        drop(slot);
        assert_eq!(registry.memory_in_use().unwrap(), 600);
        // A new label map replaces the session's own: only the others' memory counts.
        registry
            .reserve_memory("a", 1000, refused)
            .unwrap()
            .commit()
            .unwrap();
        assert_eq!(registry.memory_in_use().unwrap(), 1000);
        assert!(registry.reserve_memory("b", 1, refused).is_err());
        // Committed to a session dropped meanwhile: nothing stays in use.
        let slot = registry.reserve_memory("gone", 0, refused).unwrap();
        slot.commit().unwrap();
        assert!(registry.remove("a").unwrap().is_some());
        assert_eq!(registry.memory_in_use().unwrap(), 0);
        assert!(registry.remove("a").unwrap().is_none());
    }

    #[test]
    fn held_sessions_are_found_and_inserted_once() {
        let registry = Registry::new(4, 0);
        let first = fake(1);
        let held = registry.get_or_insert("a", Arc::clone(&first)).unwrap();
        assert!(Arc::ptr_eq(&held, &first));
        let again = registry.get_or_insert("a", fake(2)).unwrap();
        assert!(Arc::ptr_eq(&again, &first), "the held one wins");
        assert!(Arc::ptr_eq(&registry.get("a").unwrap().unwrap(), &first));
        assert!(registry.get("b").unwrap().is_none());
        assert_eq!(registry.insert("b", fake(0)).unwrap(), 2);
    }

    #[test]
    fn expiry_keeps_sessions_used_in_memory_since_the_cutoff() {
        let now = 10_000_000;
        let before = idle_cutoff(now, Duration::from_secs(60));
        assert_eq!(before, now - 60_000);
        assert_eq!(idle_cutoff(now, Duration::MAX), now - i64::MAX);
        let registry = Registry::new(4, 0);
        registry.insert("used", fake(before)).unwrap();
        registry.insert("stale", fake(before - 1)).unwrap();
        let idle: Vec<_> = ["used", "stale", "unloaded"]
            .into_iter()
            .filter(|id| registry.still_idle(id, before).unwrap())
            .collect();
        assert_eq!(idle, ["stale", "unloaded"]);
    }
}
