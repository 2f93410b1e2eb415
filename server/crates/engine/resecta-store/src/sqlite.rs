//! Embedded SQLite backend: one database file in the data directory, WAL journal, every commit
//! fsynced (`synchronous=FULL`).
//!
//! **Group commit.** Log appends from concurrent callers (several sessions editing at once) share
//! one transaction and so one fsync: an append queues itself; if no commit is in progress it
//! leads one, taking every append queued so far, otherwise it waits, and the appends that queued
//! meanwhile are the next leader's batch. Each append of a batch runs in its own savepoint, so a
//! conflict or a missing session fails that append alone; the batch commits once, and every
//! caller returns only after that commit (fsync included) returned: an append is still
//! acknowledged only once its records are durable.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use rusqlite::{
    Connection, ErrorCode, OpenFlags, OptionalExtension, Transaction, TransactionBehavior, params,
};

use crate::codec::{pack_within, unpack};
use crate::{
    Blob, Claim, Lease, LogRecord, Replica, SessionRecord, SessionStore, StoreError, StoreOptions,
    StoreUsage, check_name, check_record, check_records, check_session, not_found, to_i64, to_u64,
};

/// Database file name inside the data directory.
pub const DB_FILE: &str = "resecta.sqlite3";
/// Schema version written to `PRAGMA user_version`: 1 sessions, blobs and the log; 2 leases.
pub const SCHEMA_VERSION: i64 = 2;
/// `PRAGMA application_id` of a resecta store ("RSST").
const APPLICATION_ID: i64 = 0x5253_5354;
/// SQLite's default limit on one value (SQLITE_MAX_LENGTH).
const SQLITE_MAX_VALUE: u64 = 1_000_000_000;
const BUSY_TIMEOUT: Duration = Duration::from_secs(10);

const SCHEMA: &str = "
CREATE TABLE sessions (
    id TEXT PRIMARY KEY NOT NULL,
    display_name TEXT NOT NULL,
    created_ms INTEGER NOT NULL,
    last_access_ms INTEGER NOT NULL
);
CREATE INDEX sessions_by_created ON sessions (created_ms, id);
CREATE INDEX sessions_by_access ON sessions (last_access_ms, id);
CREATE TABLE blobs (
    session_id TEXT NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
    key TEXT NOT NULL,
    meta_json TEXT NOT NULL,
    raw_len INTEGER NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (session_id, key)
);
CREATE TABLE log (
    session_id TEXT NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
    seq INTEGER NOT NULL,
    json TEXT NOT NULL,
    PRIMARY KEY (session_id, seq)
) WITHOUT ROWID;
";

/// Migrations from each version to the next: `MIGRATIONS[v - 1]` takes version v to v + 1.
const MIGRATIONS: [&str; 1] = ["
CREATE TABLE leases (
    session_id TEXT PRIMARY KEY NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
    holder_id TEXT NOT NULL,
    holder_grpc TEXT NOT NULL,
    holder_http TEXT NOT NULL,
    token INTEGER NOT NULL,
    expires_ms INTEGER NOT NULL
);
"];

/// Most appends one group commit takes.
const MAX_BATCH: usize = 256;

/// Sessions in `DIR/resecta.sqlite3`. Writes go through one connection, reads through another
/// (WAL lets them run side by side); blobs are (de)compressed outside both locks; log appends
/// are group-committed (module docs).
pub struct SqliteStore {
    path: PathBuf,
    opts: StoreOptions,
    writer: Mutex<Connection>,
    reader: Mutex<Connection>,
    group_commit: bool,
    queue: Mutex<CommitQueue>,
    /// Signalled when a batch is done (results published, the leader's place free).
    queue_done: Condvar,
    commits: AtomicU64,
    appends: AtomicU64,
    /// Lease tokens this handle was granted, by session.
    fences: Mutex<HashMap<String, u64>>,
}

/// One append waiting for a group commit.
struct PendingAppend {
    ticket: u64,
    /// The lease token this handle holds on the session, if any.
    fence: Option<u64>,
    id: String,
    expected_len: u64,
    records: Vec<String>,
}

#[derive(Default)]
struct CommitQueue {
    next_ticket: u64,
    pending: Vec<PendingAppend>,
    /// A caller is committing a batch.
    leading: bool,
    /// Results of committed batches not yet collected by their callers, by ticket.
    done: HashMap<u64, Result<u64, StoreError>>,
}

/// Log commits and the appends they carried, since the store was opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GroupCommitStats {
    /// Committed log transactions (one fsync each).
    pub commits: u64,
    /// Appends acknowledged by them (successful or not).
    pub appends: u64,
}

impl std::fmt::Debug for SqliteStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SqliteStore")
            .field("path", &self.path)
            .field("opts", &self.opts)
            .finish_non_exhaustive()
    }
}

/// Maps SQLite errors; corruption gets its own variant.
fn db(e: rusqlite::Error) -> StoreError {
    match e.sqlite_error_code() {
        Some(ErrorCode::DatabaseCorrupt | ErrorCode::NotADatabase) => StoreError::Corrupt {
            detail: e.to_string(),
        },
        _ => StoreError::Backend(e.to_string()),
    }
}

fn lock(m: &Mutex<Connection>) -> MutexGuard<'_, Connection> {
    // A panic inside a transaction rolls it back on unwind; the connection stays usable.
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

fn session_exists(conn: &Connection, id: &str) -> Result<bool, StoreError> {
    conn.prepare_cached("SELECT 1 FROM sessions WHERE id = ?1")
        .and_then(|mut st| st.exists([id]))
        .map_err(db)
}

fn log_len(conn: &Connection, id: &str) -> Result<u64, StoreError> {
    let n: i64 = conn
        .prepare_cached("SELECT COALESCE(MAX(seq), 0) FROM log WHERE session_id = ?1")
        .and_then(|mut st| st.query_row([id], |r| r.get(0)))
        .map_err(db)?;
    to_u64("log length", n)
}

fn open_connection(path: &Path, flags: OpenFlags) -> Result<Connection, StoreError> {
    let conn = Connection::open_with_flags(path, flags).map_err(db)?;
    conn.busy_timeout(BUSY_TIMEOUT).map_err(db)?;
    conn.pragma_update(None, "foreign_keys", true).map_err(db)?;
    Ok(conn)
}

/// Checks the file is a resecta store of a known schema, creating the schema in a new file.
fn migrate(conn: &mut Connection) -> Result<(), StoreError> {
    let tx = conn
        .transaction_with_behavior(TransactionBehavior::Immediate)
        .map_err(db)?;
    let version: i64 = tx
        .pragma_query_value(None, "user_version", |r| r.get(0))
        .map_err(db)?;
    let app_id: i64 = tx
        .pragma_query_value(None, "application_id", |r| r.get(0))
        .map_err(db)?;
    if version == 0 {
        let tables: i64 = tx
            .query_row("SELECT COUNT(*) FROM sqlite_schema", [], |r| r.get(0))
            .map_err(db)?;
        if tables != 0 {
            return Err(StoreError::Corrupt {
                detail: "holds tables but no resecta schema version".into(),
            });
        }
        tx.execute_batch(SCHEMA).map_err(db)?;
        for m in MIGRATIONS {
            tx.execute_batch(m).map_err(db)?;
        }
        tx.pragma_update(None, "application_id", APPLICATION_ID)
            .map_err(db)?;
        tx.pragma_update(None, "user_version", SCHEMA_VERSION)
            .map_err(db)?;
    } else if app_id != APPLICATION_ID {
        return Err(StoreError::Corrupt {
            detail: format!(
                "{DB_FILE} is an SQLite database of another application (id {app_id:#x})"
            ),
        });
    } else if version > SCHEMA_VERSION {
        return Err(StoreError::SchemaTooNew {
            found: version,
            supported: SCHEMA_VERSION,
        });
    } else if version < 0 {
        return Err(StoreError::Corrupt {
            detail: format!("schema version {version}"),
        });
    } else {
        for m in &MIGRATIONS[usize::try_from(version - 1).unwrap_or(0)..] {
            tx.execute_batch(m).map_err(writable)?;
        }
        // A real write (the version, migrated or not), so that a store on a read-only file
        // system or file is refused here rather than at the first acknowledged edit.
        tx.pragma_update(None, "user_version", SCHEMA_VERSION)
            .map_err(writable)?;
    }
    tx.commit().map_err(writable)
}

/// A failed write, named for what it usually means when the file is read-only.
fn writable(e: rusqlite::Error) -> StoreError {
    if e.sqlite_error_code() == Some(rusqlite::ErrorCode::ReadOnly) {
        StoreError::Backend("the store cannot be written (read-only file or file system)".into())
    } else {
        db(e)
    }
}

impl SqliteStore {
    /// Opens (creating if needed) the store in `dir`.
    pub fn open(dir: &Path, opts: StoreOptions) -> Result<Self, StoreError> {
        Self::open_inner(dir, opts).map_err(|e| match e {
            StoreError::Corrupt { detail } => StoreError::Corrupt {
                detail: format!("{}: {detail}", dir.join(DB_FILE).display()),
            },
            StoreError::Backend(msg) => {
                StoreError::Backend(format!("opening {}: {msg}", dir.join(DB_FILE).display()))
            }
            e @ (StoreError::NotFound { .. }
            | StoreError::AlreadyExists { .. }
            | StoreError::Conflict { .. }
            | StoreError::TooLarge { .. }
            | StoreError::Invalid { .. }
            | StoreError::SchemaTooNew { .. }
            | StoreError::Fenced { .. }) => e,
        })
    }

    fn open_inner(dir: &Path, opts: StoreOptions) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| StoreError::Backend(format!("cannot create the data directory: {e}")))?;
        let path = dir.join(DB_FILE);
        let mut writer = open_connection(
            &path,
            OpenFlags::SQLITE_OPEN_READ_WRITE
                | OpenFlags::SQLITE_OPEN_CREATE
                | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )?;
        let mode: String = writer
            .pragma_update_and_check(None, "journal_mode", "WAL", |r| r.get(0))
            .map_err(db)?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(StoreError::Backend(format!(
                "cannot use a write-ahead log (journal mode {mode})"
            )));
        }
        writer
            .pragma_update(None, "synchronous", "FULL")
            .map_err(db)?;
        // Truncate the WAL back to 64 MiB after checkpoints that follow large blob writes.
        writer
            .pragma_update(None, "journal_size_limit", 64_i64 << 20)
            .map_err(db)?;
        migrate(&mut writer)?;
        let reader = open_connection(
            &path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )?;
        reader.pragma_update(None, "query_only", true).map_err(db)?;
        Ok(Self {
            path,
            opts,
            writer: Mutex::new(writer),
            reader: Mutex::new(reader),
            group_commit: true,
            queue: Mutex::new(CommitQueue::default()),
            queue_done: Condvar::new(),
            commits: AtomicU64::new(0),
            appends: AtomicU64::new(0),
            fences: Mutex::default(),
        })
    }

    /// The store with one transaction and one fsync per append, as before group commit: only
    /// to measure what group commit gains (`examples/append_latency.rs`).
    #[doc(hidden)]
    pub fn without_group_commit(mut self) -> Self {
        self.group_commit = false;
        self
    }

    /// Log commits and the appends they carried so far.
    pub fn group_commit_stats(&self) -> GroupCommitStats {
        GroupCommitStats {
            commits: self.commits.load(Ordering::Relaxed),
            appends: self.appends.load(Ordering::Relaxed),
        }
    }

    /// Queues an append and returns its result once the batch holding it is committed, leading
    /// that commit when no other caller is.
    fn append_grouped(&self, append: PendingAppend) -> Result<u64, StoreError> {
        let mut q = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
        q.next_ticket += 1;
        let ticket = q.next_ticket;
        q.pending.push(PendingAppend { ticket, ..append });
        loop {
            if let Some(result) = q.done.remove(&ticket) {
                return result;
            }
            if q.leading {
                q = self
                    .queue_done
                    .wait(q)
                    .unwrap_or_else(PoisonError::into_inner);
                continue;
            }
            q.leading = true;
            let take = q.pending.len().min(MAX_BATCH);
            let batch: Vec<PendingAppend> = q.pending.drain(..take).collect();
            drop(q);
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                self.commit_batch(&batch)
            }));
            q = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
            q.leading = false;
            let results = match &outcome {
                Ok(results) => results.clone(),
                Err(_) => vec![Err(StoreError::Backend("log append panicked".into())); batch.len()],
            };
            q.done.extend(batch.iter().map(|a| a.ticket).zip(results));
            self.queue_done.notify_all();
            if let Err(panic) = outcome {
                drop(q);
                std::panic::resume_unwind(panic);
            }
        }
    }

    /// Appends a batch in one transaction, each append in its own savepoint, and commits it
    /// once. One result per append, in order; a failed commit fails every append.
    fn commit_batch(&self, batch: &[PendingAppend]) -> Vec<Result<u64, StoreError>> {
        let mut conn = lock(&self.writer);
        let mut tx = match conn.transaction_with_behavior(TransactionBehavior::Immediate) {
            Ok(tx) => tx,
            Err(e) => return vec![Err(db(e)); batch.len()],
        };
        let mut results: Vec<Result<u64, StoreError>> = batch
            .iter()
            .map(|a| append_in_savepoint(&mut tx, a))
            .collect();
        // synchronous=FULL: the WAL is fsynced before commit returns.
        if results.iter().any(Result::is_ok) {
            if let Err(e) = tx.commit() {
                let e = db(e);
                for r in &mut results {
                    *r = Err(e.clone());
                }
            }
            self.commits.fetch_add(1, Ordering::Relaxed);
        }
        self.appends
            .fetch_add(batch.len() as u64, Ordering::Relaxed);
        results
    }
}

/// One append inside `tx`, rolled back alone if it fails.
fn append_in_savepoint(tx: &mut Transaction<'_>, a: &PendingAppend) -> Result<u64, StoreError> {
    let sp = tx.savepoint().map_err(db)?;
    if !session_exists(&sp, &a.id)? {
        return Err(not_found(&a.id));
    }
    check_fence(&sp, &a.id, a.fence)?;
    let actual = log_len(&sp, &a.id)?;
    if actual != a.expected_len {
        return Err(StoreError::Conflict {
            expected: a.expected_len,
            actual,
        });
    }
    let new_len = actual + a.records.len() as u64;
    to_i64("log length", new_len)?;
    {
        let mut st = sp
            .prepare_cached("INSERT INTO log (session_id, seq, json) VALUES (?1, ?2, ?3)")
            .map_err(db)?;
        for (json, seq) in a.records.iter().zip(a.expected_len + 1..) {
            st.execute(params![a.id, seq as i64, json]).map_err(db)?;
        }
    }
    sp.commit().map_err(db)?;
    Ok(new_len)
}

/// `Fenced` if `fence` (this handle's token) is no longer the session's lease token.
fn check_fence(conn: &Connection, id: &str, fence: Option<u64>) -> Result<(), StoreError> {
    let Some(fence) = fence else {
        return Ok(());
    };
    let token: Option<i64> = conn
        .prepare_cached("SELECT token FROM leases WHERE session_id = ?1")
        .and_then(|mut st| st.query_row([id], |r| r.get(0)).optional())
        .map_err(db)?;
    if token.and_then(|t| u64::try_from(t).ok()) == Some(fence) {
        Ok(())
    } else {
        Err(StoreError::Fenced { id: id.to_owned() })
    }
}

/// Milliseconds since the Unix epoch: the lease clock of a store on one machine.
fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

fn ttl(ttl_ms: u64) -> i64 {
    i64::try_from(ttl_ms)
        .unwrap_or(i64::MAX / 4)
        .min(i64::MAX / 4)
}

impl SqliteStore {
    fn fence(&self, id: &str) -> Option<u64> {
        self.fences
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(id)
            .copied()
    }

    fn fences(&self) -> MutexGuard<'_, HashMap<String, u64>> {
        self.fences.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The database file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn options(&self) -> &StoreOptions {
        &self.opts
    }
}

fn read_record(r: &rusqlite::Row<'_>) -> rusqlite::Result<SessionRecord> {
    Ok(SessionRecord {
        id: r.get(0)?,
        display_name: r.get(1)?,
        created_ms: r.get(2)?,
        last_access_ms: r.get(3)?,
    })
}

impl SessionStore for SqliteStore {
    fn create_session(&self, rec: &SessionRecord) -> Result<(), StoreError> {
        check_session(&self.opts, rec)?;
        let conn = lock(&self.writer);
        let inserted = conn
            .prepare_cached(
                "INSERT INTO sessions (id, display_name, created_ms, last_access_ms)
                 VALUES (?1, ?2, ?3, ?4) ON CONFLICT (id) DO NOTHING",
            )
            .and_then(|mut st| {
                st.execute(params![
                    rec.id,
                    rec.display_name,
                    rec.created_ms,
                    rec.last_access_ms
                ])
            })
            .map_err(db)?;
        if inserted == 0 {
            return Err(StoreError::AlreadyExists { id: rec.id.clone() });
        }
        Ok(())
    }

    fn sessions(&self) -> Result<Vec<SessionRecord>, StoreError> {
        let conn = lock(&self.reader);
        let mut st = conn
            .prepare_cached(
                "SELECT id, display_name, created_ms, last_access_ms FROM sessions
                 ORDER BY created_ms, id",
            )
            .map_err(db)?;
        st.query_map([], read_record)
            .and_then(Iterator::collect)
            .map_err(db)
    }

    fn session(&self, id: &str) -> Result<Option<SessionRecord>, StoreError> {
        let conn = lock(&self.reader);
        conn.prepare_cached(
            "SELECT id, display_name, created_ms, last_access_ms FROM sessions WHERE id = ?1",
        )
        .and_then(|mut st| st.query_row([id], read_record).optional())
        .map_err(db)
    }

    fn delete_session(&self, id: &str) -> Result<bool, StoreError> {
        let mut conn = lock(&self.writer);
        let tx = conn.transaction().map_err(db)?;
        if !session_exists(&tx, id)? {
            return Ok(false);
        }
        check_fence(&tx, id, self.fence(id))?;
        tx.prepare_cached("DELETE FROM sessions WHERE id = ?1")
            .and_then(|mut st| st.execute([id]))
            .map_err(db)?;
        tx.commit().map_err(db)?;
        self.fences().remove(id);
        Ok(true)
    }

    fn touch(&self, id: &str, at_ms: i64) -> Result<(), StoreError> {
        let conn = lock(&self.writer);
        let n = conn
            .prepare_cached(
                "UPDATE sessions SET last_access_ms = MAX(last_access_ms, ?2) WHERE id = ?1",
            )
            .and_then(|mut st| st.execute(params![id, at_ms]))
            .map_err(db)?;
        if n == 0 {
            return Err(not_found(id));
        }
        Ok(())
    }

    fn put_blob(&self, id: &str, key: &str, blob: &Blob) -> Result<(), StoreError> {
        check_name("blob key", key)?;
        check_record(&self.opts, "blob metadata", blob.meta_json.len())?;
        if !session_exists(&lock(&self.reader), id)? {
            return Err(not_found(id));
        }
        let (packed, raw_len) = pack_within(&self.opts, &blob.data, SQLITE_MAX_VALUE)?;
        let mut conn = lock(&self.writer);
        let tx = conn.transaction().map_err(db)?;
        check_fence(&tx, id, self.fence(id))?;
        let n = tx
            .prepare_cached(
                "INSERT INTO blobs (session_id, key, meta_json, raw_len, data)
                 SELECT id, ?2, ?3, ?4, ?5 FROM sessions WHERE id = ?1
                 ON CONFLICT (session_id, key) DO UPDATE SET
                   meta_json = excluded.meta_json, raw_len = excluded.raw_len, data = excluded.data",
            )
            .and_then(|mut st| st.execute(params![id, key, blob.meta_json, raw_len, packed.data]))
            .map_err(db)?;
        if n == 0 {
            return Err(not_found(id));
        }
        tx.commit().map_err(db)
    }

    fn blob(&self, id: &str, key: &str) -> Result<Option<Blob>, StoreError> {
        type Row = (Option<String>, Option<i64>, Option<Vec<u8>>);
        let row: Option<Row> = {
            let conn = lock(&self.reader);
            conn.prepare_cached(
                "SELECT b.meta_json, b.raw_len, b.data FROM sessions s
                 LEFT JOIN blobs b ON b.session_id = s.id AND b.key = ?2 WHERE s.id = ?1",
            )
            .and_then(|mut st| {
                st.query_row([id, key], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
                    .optional()
            })
            .map_err(db)?
        };
        match row {
            None => Err(not_found(id)),
            Some((Some(meta_json), Some(raw_len), Some(data))) => {
                let data = unpack(&self.opts, to_u64("blob length", raw_len)?, &data)?;
                Ok(Some(Blob { meta_json, data }))
            }
            Some(_) => Ok(None),
        }
    }

    fn delete_blob(&self, id: &str, key: &str) -> Result<bool, StoreError> {
        let mut conn = lock(&self.writer);
        let tx = conn.transaction().map_err(db)?;
        if !session_exists(&tx, id)? {
            return Err(not_found(id));
        }
        check_fence(&tx, id, self.fence(id))?;
        let n = tx
            .prepare_cached("DELETE FROM blobs WHERE session_id = ?1 AND key = ?2")
            .and_then(|mut st| st.execute([id, key]))
            .map_err(db)?;
        tx.commit().map_err(db)?;
        Ok(n > 0)
    }

    fn append(&self, id: &str, expected_len: u64, records: &[String]) -> Result<u64, StoreError> {
        check_records(&self.opts, records)?;
        let append = PendingAppend {
            ticket: 0,
            fence: self.fence(id),
            id: id.to_owned(),
            expected_len,
            records: records.to_vec(),
        };
        if !self.group_commit {
            let mut results = self.commit_batch(std::slice::from_ref(&append));
            return results
                .pop()
                .unwrap_or_else(|| Err(StoreError::Backend("no result of a log append".into())));
        }
        self.append_grouped(append)
    }

    fn log(&self, id: &str, after: u64) -> Result<Vec<LogRecord>, StoreError> {
        let after = i64::try_from(after).unwrap_or(i64::MAX);
        let mut conn = lock(&self.reader);
        let tx = conn.transaction().map_err(db)?;
        if !session_exists(&tx, id)? {
            return Err(not_found(id));
        }
        let rows: Vec<(i64, String)> = tx
            .prepare_cached(
                "SELECT seq, json FROM log WHERE session_id = ?1 AND seq > ?2 ORDER BY seq",
            )
            .and_then(|mut st| {
                st.query_map(params![id, after], |r| Ok((r.get(0)?, r.get(1)?)))?
                    .collect()
            })
            .map_err(db)?;
        rows.into_iter()
            .map(|(seq, json)| {
                Ok(LogRecord {
                    seq: to_u64("log seq", seq)?,
                    json,
                })
            })
            .collect()
    }

    fn log_len(&self, id: &str) -> Result<u64, StoreError> {
        let mut conn = lock(&self.reader);
        let tx = conn.transaction().map_err(db)?;
        if !session_exists(&tx, id)? {
            return Err(not_found(id));
        }
        log_len(&tx, id)
    }

    fn idle_since(&self, before_ms: i64) -> Result<Vec<String>, StoreError> {
        let conn = lock(&self.reader);
        conn.prepare_cached(
            "SELECT id FROM sessions WHERE last_access_ms < ?1 ORDER BY last_access_ms, id",
        )
        .and_then(|mut st| st.query_map([before_ms], |r| r.get(0))?.collect())
        .map_err(db)
    }

    fn usage(&self) -> Result<StoreUsage, StoreError> {
        let mut conn = lock(&self.reader);
        let tx = conn.transaction().map_err(db)?;
        let (sessions, blobs, log): (i64, i64, i64) = tx
            .query_row(
                "SELECT (SELECT COUNT(*) FROM sessions),
                        (SELECT COALESCE(SUM(length(data) + octet_length(meta_json)), 0) FROM blobs),
                        (SELECT COALESCE(SUM(octet_length(json)), 0) FROM log)",
                [],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .map_err(db)?;
        Ok(StoreUsage {
            sessions: to_u64("session count", sessions)?,
            stored_bytes: to_u64("stored bytes", blobs)? + to_u64("stored bytes", log)?,
        })
    }

    fn claim(&self, id: &str, replica: &Replica, ttl_ms: u64) -> Result<Claim, StoreError> {
        let mut conn = lock(&self.writer);
        let tx = conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(db)?;
        if !session_exists(&tx, id)? {
            return Err(not_found(id));
        }
        let now = now_ms();
        let row = lease_row(&tx, id)?;
        let token = match &row {
            Some((holder, token, expires)) if *expires > now && !replica.succeeds(holder) => {
                return Ok(Claim::Held(Lease {
                    holder: holder.clone(),
                    token: *token,
                    remaining_ms: to_u64("lease time", expires - now)?,
                }));
            }
            Some((holder, token, _)) if holder.id == replica.id => *token,
            Some((_, token, _)) => token + 1,
            None => 1,
        };
        let token_i64 = to_i64("lease token", token)?;
        tx.prepare_cached(
            "INSERT INTO leases (session_id, holder_id, holder_grpc, holder_http, token, expires_ms)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6) ON CONFLICT (session_id) DO UPDATE SET
               holder_id = excluded.holder_id, holder_grpc = excluded.holder_grpc,
               holder_http = excluded.holder_http, token = excluded.token,
               expires_ms = excluded.expires_ms",
        )
        .and_then(|mut st| {
            st.execute(params![
                id,
                replica.id,
                replica.grpc,
                replica.http,
                token_i64,
                now.saturating_add(ttl(ttl_ms))
            ])
        })
        .map_err(db)?;
        tx.commit().map_err(db)?;
        self.fences().insert(id.to_owned(), token);
        Ok(Claim::Granted { token })
    }

    fn renew(
        &self,
        replica_id: &str,
        ids: &[String],
        ttl_ms: u64,
    ) -> Result<Vec<String>, StoreError> {
        let until = now_ms().saturating_add(ttl(ttl_ms));
        let mut conn = lock(&self.writer);
        let tx = conn.transaction().map_err(db)?;
        let mut lost = Vec::new();
        let fences = self.fences();
        for id in ids {
            let renewed = match fences.get(id) {
                Some(&token) => {
                    let token = to_i64("lease token", token)?;
                    tx.prepare_cached(
                        "UPDATE leases SET expires_ms = ?4
                         WHERE session_id = ?1 AND holder_id = ?2 AND token = ?3",
                    )
                    .and_then(|mut st| st.execute(params![id, replica_id, token, until]))
                    .map_err(db)?
                }
                None => 0,
            };
            if renewed == 0 {
                // The token stays: this handle's writes to a lost session remain fenced.
                lost.push(id.clone());
            }
        }
        tx.commit().map_err(db)?;
        Ok(lost)
    }

    fn release(&self, id: &str, replica_id: &str) -> Result<bool, StoreError> {
        let now = now_ms();
        let n = lock(&self.writer)
            .prepare_cached(
                "UPDATE leases SET expires_ms = ?3
                 WHERE session_id = ?1 AND holder_id = ?2 AND expires_ms > ?3",
            )
            .and_then(|mut st| st.execute(params![id, replica_id, now]))
            .map_err(db)?;
        self.fences().remove(id);
        Ok(n > 0)
    }

    fn lease(&self, id: &str) -> Result<Option<Lease>, StoreError> {
        let mut conn = lock(&self.reader);
        let tx = conn.transaction().map_err(db)?;
        if !session_exists(&tx, id)? {
            return Err(not_found(id));
        }
        let now = now_ms();
        match lease_row(&tx, id)? {
            Some((holder, token, expires)) if expires > now => Ok(Some(Lease {
                holder,
                token,
                remaining_ms: to_u64("lease time", expires - now)?,
            })),
            _ => Ok(None),
        }
    }
}

/// A session's lease row: holder, token, expiry (ms since the epoch).
fn lease_row(conn: &Connection, id: &str) -> Result<Option<(Replica, u64, i64)>, StoreError> {
    let row: Option<(String, String, String, i64, i64)> = conn
        .prepare_cached(
            "SELECT holder_id, holder_grpc, holder_http, token, expires_ms FROM leases
             WHERE session_id = ?1",
        )
        .and_then(|mut st| {
            st.query_row([id], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?))
            })
            .optional()
        })
        .map_err(db)?;
    row.map(|(id, grpc, http, token, expires)| {
        Ok((
            Replica { id, grpc, http },
            to_u64("lease token", token)?,
            expires,
        ))
    })
    .transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Running as root, no permission makes a file read-only; a read-only connection to a
    /// store's database gives the same SQLITE_READONLY as a read-only mount.
    #[test]
    fn a_store_that_cannot_be_written_is_refused_at_open() {
        let dir = tempfile::tempdir().unwrap();
        drop(SqliteStore::open(dir.path(), StoreOptions::default()).unwrap());
        let path = dir.path().join(DB_FILE);
        let mut read_only = open_connection(&path, OpenFlags::SQLITE_OPEN_READ_ONLY).unwrap();
        let e = migrate(&mut read_only).unwrap_err();
        assert!(e.to_string().contains("cannot be written"), "{e}");
        // A writable one passes, again and again.
        let mut writer = open_connection(&path, OpenFlags::SQLITE_OPEN_READ_WRITE).unwrap();
        migrate(&mut writer).unwrap();
        migrate(&mut writer).unwrap();
    }
}
