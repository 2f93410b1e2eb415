//! The session operations: sessions in memory (the [`Registry`]) and in the store, their
//! creation within the session quota, listing, deletion and idle expiry.

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::{Arc, Mutex};

use resecta_store::SessionRecord;
use tokio::sync::Mutex as AsyncMutex;

use crate::api::{SessionInfo, SessionState};
use crate::error::{Result, SessionError};
use crate::log;
use crate::registry::{LastAccess, Registry, idle_cutoff};
use crate::service::Service;
use crate::state::{Session, State};
use crate::support::{blocking, now_ms};
use crate::watch::Hub;

/// Longest display name (characters, i.e. Unicode scalar values); control characters are
/// refused.
pub const MAX_DISPLAY_NAME: usize = 256;
/// Last-access times are written at most this often per session (ms).
const TOUCH_EVERY_MS: i64 = 60_000;

fn check_display_name(name: &str) -> Result<()> {
    if name.is_empty() || name.chars().count() > MAX_DISPLAY_NAME {
        return Err(SessionError::Invalid(format!(
            "display name must have 1 to {MAX_DISPLAY_NAME} characters"
        )));
    }
    if name.chars().any(char::is_control) {
        return Err(SessionError::Invalid(
            "display name must not contain control characters".into(),
        ));
    }
    Ok(())
}

impl LastAccess for Session {
    fn last_access_ms(&self) -> i64 {
        self.last_touch_ms.load(Ordering::Relaxed)
    }
    fn watched(&self) -> bool {
        self.hub.watchers() > 0
    }
}

impl Service {
    pub(crate) fn new_session(&self, rec: &SessionRecord, restored: bool) -> Arc<Session> {
        Arc::new(Session {
            id: rec.id.clone(),
            state: Arc::new(AsyncMutex::new(State {
                display_name: rec.display_name.clone(),
                created_ms: rec.created_ms,
                restored,
                loaded: None,
                models: None,
                version: 0,
                generation: 0,
            })),
            hub: Arc::new(Hub::new(self.config.ring, self.config.encode)),
            last_touch_ms: AtomicI64::new(rec.last_access_ms),
            volumes_scheduled: AtomicBool::new(false),
            last_edit: Mutex::new(std::time::Instant::now()),
            deleted: Arc::new(AtomicBool::new(false)),
            damaged: AtomicBool::new(false),
            lost: AtomicBool::new(false),
        })
    }

    /// The session `id`, from memory or the store, without recording an access.
    /// On a replicated server, a session not held here is claimed first
    /// ([`SessionError::Elsewhere`] while another replica holds it).
    pub(crate) async fn session_unrecorded(&self, id: &str) -> Result<Arc<Session>> {
        let found = self.registry.get(id)?;
        if let Some(s) = found {
            if !s.lost.load(Ordering::Acquire) {
                return Ok(s);
            }
            self.evict(id, None)?;
        }
        let store = Arc::clone(&self.store);
        let key = id.to_owned();
        let rec = blocking(move || Ok(store.session(&key)?)).await?;
        let rec = rec.ok_or_else(|| SessionError::UnknownSession(id.into()))?;
        self.claim(id).await?;
        let fresh = self.new_session(&rec, false);
        self.registry.get_or_insert(id, fresh)
    }

    /// The session `id`, from memory or the store; records the access.
    pub(crate) async fn session(&self, id: &str) -> Result<Arc<Session>> {
        let session = self.session_unrecorded(id).await?;
        let now = now_ms();
        if now - session.last_touch_ms.load(Ordering::Relaxed) >= TOUCH_EVERY_MS {
            session.last_touch_ms.store(now, Ordering::Relaxed);
            let store = Arc::clone(&self.store);
            let key = id.to_owned();
            // Off the request path: the access time only feeds idle expiry.
            tokio::spawn(blocking(move || {
                store
                    .touch(&key, now)
                    .inspect_err(|e| tracing::warn!(error = %e, "recording a session access"))?;
                Ok(())
            }));
        }
        Ok(session)
    }

    #[cfg(test)]
    pub(crate) fn memory_in_use(&self) -> Result<u64> {
        self.budget.in_use()
    }

    pub async fn create_session(&self, display_name: &str) -> Result<SessionInfo> {
        check_display_name(display_name)?;
        let store = Arc::clone(&self.store);
        let registry: Arc<Registry<Session>> = Arc::clone(&self.registry);
        let now = now_ms();
        let rec = SessionRecord {
            id: uuid::Uuid::new_v4().simple().to_string(),
            display_name: display_name.to_owned(),
            created_ms: now,
            last_access_ms: now,
        };
        let stored = rec.clone();
        let shared = self.config.replica.is_some();
        blocking(move || {
            if shared {
                // Other replicas create sessions too: the quota counts the store's.
                registry.recount()?;
            }
            let slot = registry.reserve_session(|| Ok(store.usage()?.sessions))?;
            store.create_session(&stored)?;
            slot.commit();
            Ok(())
        })
        .await?;
        self.claim(&rec.id).await?;
        let session = self.new_session(&rec, true);
        let loaded = self.registry.insert(&rec.id, Arc::clone(&session))?;
        metrics::gauge!("resecta_sessions_loaded").set(loaded as f64);
        tracing::info!(session = %rec.id, "session created");
        self.describe(&session).await
    }

    pub async fn list_sessions(&self) -> Result<Vec<SessionInfo>> {
        let store = Arc::clone(&self.store);
        let records = blocking(move || Ok(store.sessions()?)).await?;
        let mut out = Vec::with_capacity(records.len());
        for rec in records {
            let described = match self.registry.get(&rec.id)? {
                Some(s) => self.describe(&s).await,
                None => self.describe_stored(rec.clone()).await,
            };
            match described {
                Ok(info) => out.push(info),
                // Deleted meanwhile.
                Err(SessionError::UnknownSession(_)) => {}
                // One unreadable session never breaks the listing.
                Err(e) => {
                    tracing::warn!(session = %rec.id, error = %e, "stored session unreadable");
                    out.push(damaged_info(rec));
                }
            }
        }
        Ok(out)
    }

    pub async fn get_session(&self, id: &str) -> Result<SessionInfo> {
        let s = self.session(id).await?;
        self.describe(&s).await
    }

    pub async fn delete_session(&self, id: &str) -> Result<()> {
        if self.config.replica.is_some() {
            // Only the holder deletes: its memory goes with the stored session.
            match self.session_unrecorded(id).await {
                Ok(_) | Err(SessionError::UnknownSession(_)) => {}
                Err(e) => return Err(e),
            }
        }
        let store = Arc::clone(&self.store);
        let registry = Arc::clone(&self.registry);
        let key = id.to_owned();
        let existed =
            blocking(move || registry.delete_stored(|| Ok(store.delete_session(&key)?))).await?;
        let dropped = self.registry.remove(id)?;
        self.budget.release(id)?;
        if let Some(s) = &dropped {
            // Stops its planner set-up; what it holds is freed when the set-up returns.
            s.deleted.store(true, Ordering::Release);
            s.hub.close();
        }
        if !existed && dropped.is_none() {
            return Err(SessionError::UnknownSession(id.into()));
        }
        tracing::info!(session = %id, "session deleted");
        Ok(())
    }

    /// Deletes sessions idle for longer than the configured expiry; returns how many.
    pub async fn expire_idle(&self) -> Result<usize> {
        let Some(expiry) = self.config.idle_expiry else {
            return Ok(0);
        };
        let before = idle_cutoff(now_ms(), expiry);
        let store = Arc::clone(&self.store);
        let idle = blocking(move || Ok(store.idle_since(before)?)).await?;
        let mut n = 0;
        for id in idle {
            if self.registry.still_idle(&id, before)? {
                match self.delete_session(&id).await {
                    Ok(()) => n += 1,
                    // Another replica holds it (and expires it), or deleted it meanwhile.
                    Err(SessionError::Elsewhere(_) | SessionError::UnknownSession(_)) => {}
                    Err(e) => return Err(e),
                }
            }
        }
        Ok(n)
    }

    async fn describe(&self, s: &Arc<Session>) -> Result<SessionInfo> {
        if s.damaged.load(Ordering::Acquire) {
            let store = Arc::clone(&self.store);
            let key = s.id.clone();
            let rec = blocking(move || Ok(store.session(&key)?))
                .await?
                .ok_or_else(|| SessionError::UnknownSession(s.id.as_str().into()))?;
            return Ok(damaged_info(rec));
        }
        let st = s.state.lock().await;
        if !st.restored {
            drop(st);
            let store = Arc::clone(&self.store);
            let key = s.id.clone();
            let rec = blocking(move || Ok(store.session(&key)?))
                .await?
                .ok_or_else(|| SessionError::UnknownSession(s.id.as_str().into()))?;
            return self.describe_stored(rec).await;
        }
        Ok(SessionInfo {
            id: s.id.clone(),
            display_name: st.display_name.clone(),
            created_ms: st.created_ms,
            last_access_ms: s.last_touch_ms.load(Ordering::Relaxed),
            state: match (&st.loaded, &st.models) {
                (None, _) => SessionState::Empty,
                (Some(_), None) => SessionState::LabelMap,
                (Some(_), Some(_)) => SessionState::Ready,
            },
            plan_version: st.version,
            label_map: st.loaded.as_ref().map(|l| l.summary.clone()),
        })
    }

    /// A session not loaded in memory, from its record and small blobs only.
    async fn describe_stored(&self, rec: SessionRecord) -> Result<SessionInfo> {
        let store = Arc::clone(&self.store);
        let key = rec.id.clone();
        let (version, summary, models) =
            blocking(move || log::stored_summary(&*store, &key)).await?;
        Ok(SessionInfo {
            id: rec.id,
            display_name: rec.display_name,
            created_ms: rec.created_ms,
            last_access_ms: rec.last_access_ms,
            state: match (&summary, models) {
                (None, _) => SessionState::Empty,
                (Some(_), false) => SessionState::LabelMap,
                (Some(_), true) => SessionState::Ready,
            },
            plan_version: version,
            label_map: summary,
        })
    }
}

/// A stored session that cannot be restored, as listings show it.
fn damaged_info(rec: SessionRecord) -> SessionInfo {
    SessionInfo {
        id: rec.id,
        display_name: rec.display_name,
        created_ms: rec.created_ms,
        last_access_ms: rec.last_access_ms,
        state: SessionState::Damaged,
        plan_version: 0,
        label_map: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_names() {
        assert!(check_display_name("Patient 7, liver").is_ok());
        assert!(check_display_name(&"x".repeat(MAX_DISPLAY_NAME)).is_ok());
        for bad in ["", "tab\there", &"x".repeat(MAX_DISPLAY_NAME + 1)] {
            assert!(matches!(
                check_display_name(bad),
                Err(SessionError::Invalid(_))
            ));
        }
    }
}
