//! The session table: the sessions held in memory, the session-count quota as reservations
//! (checked and taken in one step, given back when the creation fails), and which sessions are
//! idle past the expiry. No store and no async: the session operations (`sessions`) call it
//! with what the store says. Memory is the [`Budget`](crate::budget::Budget)'s.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use crate::error::{Quota, Result, SessionError};
use crate::support::internal;

/// When a held session was last used (ms since the epoch), and whether a client watches it.
pub(crate) trait LastAccess {
    fn last_access_ms(&self) -> i64;
    fn watched(&self) -> bool;
}

/// The sessions held in memory, and the session-count quota.
#[derive(Debug)]
pub(crate) struct Registry<T> {
    max_sessions: u64,
    table: Mutex<HashMap<String, Arc<T>>>,
    /// Sessions stored plus those being created; `None` until the first reservation counts
    /// the stored ones.
    sessions: Mutex<Option<u64>>,
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

impl<T> Registry<T> {
    pub(crate) fn new(max_sessions: usize) -> Self {
        Self {
            max_sessions: max_sessions as u64,
            table: Mutex::new(HashMap::new()),
            sessions: Mutex::new(None),
        }
    }

    fn table(&self) -> Result<MutexGuard<'_, HashMap<String, Arc<T>>>> {
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
        Ok(self.table()?.get(id).map(Arc::clone))
    }

    /// The session `id` as held, or else `fresh`, held from now on.
    pub(crate) fn get_or_insert(&self, id: &str, fresh: Arc<T>) -> Result<Arc<T>> {
        let mut table = self.table()?;
        Ok(Arc::clone(table.entry(id.to_owned()).or_insert(fresh)))
    }

    /// Holds `session` as `id`; returns how many sessions are held.
    pub(crate) fn insert(&self, id: &str, session: Arc<T>) -> Result<usize> {
        let mut table = self.table()?;
        table.insert(id.to_owned(), session);
        Ok(table.len())
    }

    /// The ids of the sessions held.
    pub(crate) fn ids(&self) -> Result<Vec<String>> {
        Ok(self.table()?.keys().cloned().collect())
    }

    /// Stops holding `id`.
    pub(crate) fn remove(&self, id: &str) -> Result<Option<Arc<T>>> {
        Ok(self.table()?.remove(id))
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

    /// Forgets the session count, so that the next reservation counts the stored sessions
    /// again: replicas sharing a store each create sessions, and the quota is the store's.
    pub(crate) fn recount(&self) -> Result<()> {
        *self.sessions()? = None;
        Ok(())
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
}

impl<T: LastAccess> Registry<T> {
    /// Whether session `id`, which the store finds idle since `before`, is still idle: not
    /// held, or held, not used since and not watched (a session on a surgeon's screen is in
    /// use).
    pub(crate) fn still_idle(&self, id: &str, before: i64) -> Result<bool> {
        Ok(self
            .table()?
            .get(id)
            .is_none_or(|s| s.last_access_ms() < before && !s.watched()))
    }
}

/// Sessions last used before this time (ms) are idle at `now_ms` past `expiry`.
pub(crate) fn idle_cutoff(now_ms: i64, expiry: Duration) -> i64 {
    now_ms - i64::try_from(expiry.as_millis()).unwrap_or(i64::MAX)
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicI64, Ordering};

    use super::*;
    use crate::budget::tests::granted_in_parallel;

    #[derive(Debug, Default)]
    struct Fake(AtomicI64, bool);

    impl LastAccess for Fake {
        fn last_access_ms(&self) -> i64 {
            self.0.load(Ordering::Relaxed)
        }
        fn watched(&self) -> bool {
            self.1
        }
    }

    fn fake(last: i64) -> Arc<Fake> {
        Arc::new(Fake(AtomicI64::new(last), false))
    }

    #[test]
    fn parallel_reservations_never_pass_the_session_quota() {
        let registry = Registry::<Fake>::new(10);
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
        let registry = Registry::<Fake>::new(2);
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
        let registry = Registry::<Fake>::new(1);
        assert!(matches!(
            registry.reserve_session(|| Err(internal("store down"))),
            Err(SessionError::Internal(_))
        ));
        registry.reserve_session(|| Ok(0)).unwrap().commit();
    }

    #[test]
    fn held_sessions_are_found_and_inserted_once() {
        let registry = Registry::new(4);
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
        let registry = Registry::new(4);
        registry.insert("used", fake(before)).unwrap();
        registry.insert("stale", fake(before - 1)).unwrap();
        let watched = Fake(AtomicI64::new(before - 1), true);
        registry.insert("watched", Arc::new(watched)).unwrap();
        let idle: Vec<_> = ["used", "stale", "watched", "unloaded"]
            .into_iter()
            .filter(|id| registry.still_idle(id, before).unwrap())
            .collect();
        assert_eq!(idle, ["stale", "unloaded"]);
    }
}
