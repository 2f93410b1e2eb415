//! In-memory backend: the semantics of [`crate::SqliteStore`] without a disk.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use crate::codec::{Packed, pack, unpack};
use crate::{
    Blob, Claim, Lease, LogRecord, Replica, SessionRecord, SessionStore, StoreError, StoreOptions,
    StoreUsage, check_name, check_record, check_records, check_session,
};

#[derive(Debug)]
struct StoredBlob {
    meta_json: String,
    packed: Packed,
}

#[derive(Debug)]
struct Session {
    rec: SessionRecord,
    blobs: BTreeMap<String, StoredBlob>,
    log: Vec<String>,
    /// The lease's holder and expiry (`None`: never claimed).
    lease: Option<(Replica, Instant)>,
    /// The last token granted (kept through releases and expiry).
    token: u64,
}

/// Sessions in memory (blobs compressed as on disk); lost when the last handle is dropped.
/// [`MemoryStore::share`] gives another handle on the same sessions, as a second replica's
/// connection to a shared database would be (its own fencing tokens).
#[derive(Default)]
pub struct MemoryStore {
    opts: StoreOptions,
    sessions: Arc<Mutex<BTreeMap<String, Session>>>,
    /// Tokens this handle was granted, by session.
    fences: Mutex<HashMap<String, u64>>,
}

// Contents may be patient data: Debug shows the options and the session count only.
impl std::fmt::Debug for MemoryStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MemoryStore")
            .field("opts", &self.opts)
            .field("sessions", &self.lock().len())
            .finish()
    }
}

impl MemoryStore {
    pub fn new(opts: StoreOptions) -> Self {
        Self {
            opts,
            sessions: Arc::default(),
            fences: Mutex::default(),
        }
    }

    /// Another handle on the same sessions, with no leases granted to it yet.
    pub fn share(&self) -> Self {
        Self {
            opts: self.opts,
            sessions: Arc::clone(&self.sessions),
            fences: Mutex::default(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, BTreeMap<String, Session>> {
        // Every update is applied whole after its checks, so a poisoned map is still consistent.
        self.sessions.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn fences(&self) -> MutexGuard<'_, HashMap<String, u64>> {
        self.fences.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The session, for a write: `Fenced` if this handle was granted a token another holder
    /// has since superseded.
    fn writable<'a>(
        &self,
        map: &'a mut BTreeMap<String, Session>,
        id: &str,
    ) -> Result<&'a mut Session, StoreError> {
        let s = get_mut(map, id)?;
        match self.fences().get(id) {
            Some(&token) if token != s.token => Err(StoreError::Fenced { id: id.to_owned() }),
            _ => Ok(s),
        }
    }
}

/// The holder of an unexpired lease.
fn live_holder(s: &Session, now: Instant) -> Option<(&Replica, Duration)> {
    s.lease
        .as_ref()
        .filter(|(_, until)| *until > now)
        .map(|(r, until)| (r, *until - now))
}

fn get<'a>(map: &'a BTreeMap<String, Session>, id: &str) -> Result<&'a Session, StoreError> {
    map.get(id)
        .ok_or_else(|| StoreError::NotFound { id: id.to_owned() })
}

fn get_mut<'a>(
    map: &'a mut BTreeMap<String, Session>,
    id: &str,
) -> Result<&'a mut Session, StoreError> {
    map.get_mut(id)
        .ok_or_else(|| StoreError::NotFound { id: id.to_owned() })
}

impl SessionStore for MemoryStore {
    fn create_session(&self, rec: &SessionRecord) -> Result<(), StoreError> {
        check_session(&self.opts, rec)?;
        let mut map = self.lock();
        if map.contains_key(&rec.id) {
            return Err(StoreError::AlreadyExists { id: rec.id.clone() });
        }
        map.insert(
            rec.id.clone(),
            Session {
                rec: rec.clone(),
                blobs: BTreeMap::new(),
                log: Vec::new(),
                lease: None,
                token: 0,
            },
        );
        Ok(())
    }

    fn sessions(&self) -> Result<Vec<SessionRecord>, StoreError> {
        let mut recs: Vec<SessionRecord> = self.lock().values().map(|s| s.rec.clone()).collect();
        recs.sort_by(|a, b| (a.created_ms, &a.id).cmp(&(b.created_ms, &b.id)));
        Ok(recs)
    }

    fn session(&self, id: &str) -> Result<Option<SessionRecord>, StoreError> {
        Ok(self.lock().get(id).map(|s| s.rec.clone()))
    }

    fn delete_session(&self, id: &str) -> Result<bool, StoreError> {
        let mut map = self.lock();
        if !map.contains_key(id) {
            return Ok(false);
        }
        self.writable(&mut map, id)?;
        map.remove(id);
        self.fences().remove(id);
        Ok(true)
    }

    fn touch(&self, id: &str, at_ms: i64) -> Result<(), StoreError> {
        let mut map = self.lock();
        let rec = &mut get_mut(&mut map, id)?.rec;
        rec.last_access_ms = rec.last_access_ms.max(at_ms);
        Ok(())
    }

    fn put_blob(&self, id: &str, key: &str, blob: &Blob) -> Result<(), StoreError> {
        check_name("blob key", key)?;
        check_record(&self.opts, "blob metadata", blob.meta_json.len())?;
        get(&self.lock(), id)?;
        let packed = pack(&self.opts, &blob.data)?;
        let stored = StoredBlob {
            meta_json: blob.meta_json.clone(),
            packed,
        };
        self.writable(&mut self.lock(), id)?
            .blobs
            .insert(key.to_owned(), stored);
        Ok(())
    }

    fn blob(&self, id: &str, key: &str) -> Result<Option<Blob>, StoreError> {
        let (meta_json, packed) = {
            let map = self.lock();
            match get(&map, id)?.blobs.get(key) {
                None => return Ok(None),
                Some(b) => (b.meta_json.clone(), b.packed.clone()),
            }
        };
        let data = unpack(&self.opts, packed.raw_len, &packed.data)?;
        Ok(Some(Blob { meta_json, data }))
    }

    fn delete_blob(&self, id: &str, key: &str) -> Result<bool, StoreError> {
        Ok(self
            .writable(&mut self.lock(), id)?
            .blobs
            .remove(key)
            .is_some())
    }

    fn append(&self, id: &str, expected_len: u64, records: &[String]) -> Result<u64, StoreError> {
        check_records(&self.opts, records)?;
        let mut map = self.lock();
        let log = &mut self.writable(&mut map, id)?.log;
        let actual = log.len() as u64;
        if actual != expected_len {
            return Err(StoreError::Conflict {
                expected: expected_len,
                actual,
            });
        }
        log.extend_from_slice(records);
        Ok(log.len() as u64)
    }

    fn log(&self, id: &str, after: u64) -> Result<Vec<LogRecord>, StoreError> {
        let map = self.lock();
        let log = &get(&map, id)?.log;
        let start = usize::try_from(after).unwrap_or(usize::MAX).min(log.len());
        Ok(log[start..]
            .iter()
            .zip(start as u64 + 1..)
            .map(|(json, seq)| LogRecord {
                seq,
                json: json.clone(),
            })
            .collect())
    }

    fn log_len(&self, id: &str) -> Result<u64, StoreError> {
        Ok(get(&self.lock(), id)?.log.len() as u64)
    }

    fn idle_since(&self, before_ms: i64) -> Result<Vec<String>, StoreError> {
        let mut idle: Vec<(i64, String)> = self
            .lock()
            .values()
            .filter(|s| s.rec.last_access_ms < before_ms)
            .map(|s| (s.rec.last_access_ms, s.rec.id.clone()))
            .collect();
        idle.sort();
        Ok(idle.into_iter().map(|(_, id)| id).collect())
    }

    fn usage(&self) -> Result<StoreUsage, StoreError> {
        let map = self.lock();
        let stored_bytes = map
            .values()
            .map(|s| {
                let blobs: usize = s
                    .blobs
                    .values()
                    .map(|b| b.meta_json.len() + b.packed.data.len())
                    .sum();
                let log: usize = s.log.iter().map(String::len).sum();
                (blobs + log) as u64
            })
            .sum();
        Ok(StoreUsage {
            sessions: map.len() as u64,
            stored_bytes,
        })
    }

    fn claim(&self, id: &str, replica: &Replica, ttl_ms: u64) -> Result<Claim, StoreError> {
        let now = Instant::now();
        let mut map = self.lock();
        let s = get_mut(&mut map, id)?;
        if let Some((holder, left)) = live_holder(s, now)
            && !replica.succeeds(holder)
        {
            return Ok(Claim::Held(Lease {
                holder: holder.clone(),
                token: s.token,
                remaining_ms: left.as_millis().try_into().unwrap_or(u64::MAX),
            }));
        }
        let same_holder = s.lease.as_ref().is_some_and(|(r, _)| r.id == replica.id);
        if !same_holder {
            s.token += 1;
        }
        s.lease = Some((replica.clone(), now + Duration::from_millis(ttl_ms)));
        self.fences().insert(id.to_owned(), s.token);
        Ok(Claim::Granted { token: s.token })
    }

    fn renew(
        &self,
        replica_id: &str,
        ids: &[String],
        ttl_ms: u64,
    ) -> Result<Vec<String>, StoreError> {
        let until = Instant::now() + Duration::from_millis(ttl_ms);
        let mut map = self.lock();
        let fences = self.fences();
        let mut lost = Vec::new();
        for id in ids {
            let held = map.get_mut(id).and_then(|s| {
                let token = *fences.get(id)?;
                let (holder, _) = s.lease.as_mut()?;
                (holder.id == replica_id && s.token == token).then_some(s)
            });
            match held {
                Some(s) => {
                    if let Some(lease) = s.lease.as_mut() {
                        lease.1 = until;
                    }
                }
                // The token stays: this handle's writes to a lost session remain fenced.
                None => lost.push(id.clone()),
            }
        }
        Ok(lost)
    }

    fn release(&self, id: &str, replica_id: &str) -> Result<bool, StoreError> {
        let mut map = self.lock();
        self.fences().remove(id);
        let Some(s) = map.get_mut(id) else {
            return Ok(false);
        };
        let now = Instant::now();
        match s.lease.as_mut() {
            Some((holder, until)) if holder.id == replica_id && *until > now => {
                *until = now;
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    fn lease(&self, id: &str) -> Result<Option<Lease>, StoreError> {
        let map = self.lock();
        let s = get(&map, id)?;
        Ok(live_holder(s, Instant::now()).map(|(holder, left)| Lease {
            holder: holder.clone(),
            token: s.token,
            remaining_ms: left.as_millis().try_into().unwrap_or(u64::MAX),
        }))
    }
}
