//! Durable storage of the planning server's patient sessions.
//!
//! A session has metadata ([`SessionRecord`]), named blobs (the uploaded label map, cached models;
//! stored zstd-compressed) and an append-only log of plan edits. The server acknowledges an edit
//! only after [`SessionStore::append`] returned, which is durable (fsynced) by contract, so a
//! crash never loses an acknowledged edit.
//!
//! The API is synchronous: the server calls it from blocking threads (never from inside an async
//! context: the PostgreSQL client runs its own small runtime). Backends: [`SqliteStore`] (one
//! embedded database file in a data directory, the default), [`PostgresStore`] (a PostgreSQL
//! database that several replicas share, over a connection pool, optionally TLS) and
//! [`MemoryStore`] (same semantics, nothing on disk: tests and ephemeral servers).
//!
//! **Leases.** Several server replicas may share one store; exactly one runs a session's
//! planner at a time. A replica [`claim`](SessionStore::claim)s a session's lease for a time
//! and renews it while it holds the session; another replica's claim succeeds only once the
//! lease has expired or was released. Each new holder gets a larger fencing token, and a
//! store handle that was granted a token refuses its own later writes to that session with
//! [`StoreError::Fenced`] once another holder has claimed it: a paused former owner can never
//! append. Lease expiry is measured by the store's one clock (the database server's, for a
//! shared database), never by the replicas' clocks.
//!
//! Error messages name ids, keys, lengths and limits, never display names, blob contents or
//! metadata, which may identify a patient.

mod codec;
mod memory;
mod postgres;
mod sqlite;

pub use self::postgres::{DEFAULT_POOL_SIZE, PostgresStore};
pub use memory::MemoryStore;
pub use sqlite::{DB_FILE, GroupCommitStats, SCHEMA_VERSION, SqliteStore};

/// One session's metadata. `id` is opaque and server-made; `display_name` is the client's label
/// (possibly a patient identifier: it never appears in errors, and `Debug` shows only its length).
#[derive(Clone, PartialEq, Eq)]
pub struct SessionRecord {
    pub id: String,
    pub display_name: String,
    pub created_ms: i64,
    pub last_access_ms: i64,
}

impl std::fmt::Debug for SessionRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionRecord")
            .field("id", &self.id)
            .field("display_name_bytes", &self.display_name.len())
            .field("created_ms", &self.created_ms)
            .field("last_access_ms", &self.last_access_ms)
            .finish()
    }
}

/// A named blob: free-form metadata (JSON by convention) and bytes. The bytes are stored
/// zstd-compressed and returned decompressed.
#[derive(Clone, PartialEq, Eq)]
pub struct Blob {
    pub meta_json: String,
    pub data: Vec<u8>,
}

// Contents may be patient data: Debug shows sizes only.
impl std::fmt::Debug for Blob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Blob")
            .field("meta_json_bytes", &self.meta_json.len())
            .field("data_bytes", &self.data.len())
            .finish()
    }
}

/// One log record; `seq` is its 1-based position in the session's log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogRecord {
    pub seq: u64,
    pub json: String,
}

/// What the store holds: sessions, and payload bytes (compressed blob data, blob metadata and
/// log records; not indexes or free pages).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StoreUsage {
    pub sessions: u64,
    pub stored_bytes: u64,
}

/// A server replica as leases name it: an id unique to the process, and the addresses at which
/// clients reach it (shown to clients that call another replica).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Replica {
    pub id: String,
    /// gRPC address, `host:port`.
    pub grpc: String,
    /// HTTP face's base URL, `http(s)://host:port`.
    pub http: String,
}

impl Replica {
    /// The replica's name: its id up to the last `@` (ids are `NAME@PROCESS`). Names are
    /// unique among live replicas, so a lease held under this name by another process was
    /// held by an earlier, gone process of this replica.
    pub fn name(&self) -> &str {
        replica_name(&self.id)
    }

    /// Whether a lease held by `holder` is this replica's own or an earlier process's of it.
    pub fn succeeds(&self, holder: &Replica) -> bool {
        holder.id == self.id || holder.name() == self.name()
    }
}

fn replica_name(id: &str) -> &str {
    id.rsplit_once('@').map_or(id, |(name, _)| name)
}

/// A session's unexpired lease.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lease {
    pub holder: Replica,
    /// Fencing token: larger for every new holder of the session's lease.
    pub token: u64,
    /// Time left until it expires, by the store's clock.
    pub remaining_ms: u64,
}

/// The outcome of [`SessionStore::claim`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Claim {
    /// The caller holds the lease with this fencing token.
    Granted { token: u64 },
    /// Another replica holds it.
    Held(Lease),
}

/// Limits and compression of a store.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StoreOptions {
    /// zstd level for blobs (1 fastest … 19; negative levels are faster still).
    pub zstd_level: i32,
    /// Largest blob (uncompressed) accepted by `put_blob` and inflated by `blob`.
    pub max_blob_bytes: u64,
    /// Largest log record, blob metadata or display name, in bytes.
    pub max_record_bytes: usize,
}

impl Default for StoreOptions {
    fn default() -> Self {
        Self {
            zstd_level: 3,
            // A 512×512×1000 u16 label map; also leaves the compressed worst case below SQLite's
            // 1e9-byte value limit.
            max_blob_bytes: 512 << 20,
            // The record of the largest plan the plan limits allow (32 resections of 64×64
            // control points, compact JSON: about 10 MiB) fits.
            max_record_bytes: 16 << 20,
        }
    }
}

/// Errors of a [`SessionStore`].
#[derive(Debug, Clone, thiserror::Error)]
pub enum StoreError {
    #[error("session {id} not found")]
    NotFound { id: String },
    #[error("session {id} already exists")]
    AlreadyExists { id: String },
    #[error("log conflict: append expected a log of {expected} records, the log has {actual}")]
    Conflict { expected: u64, actual: u64 },
    #[error("{what} is {size} bytes, above the limit of {limit} bytes")]
    TooLarge {
        what: &'static str,
        size: u64,
        limit: u64,
    },
    #[error("invalid {what}: {reason}")]
    Invalid { what: &'static str, reason: String },
    #[error("store is corrupt: {detail}")]
    Corrupt { detail: String },
    #[error(
        "store schema version {found} is newer than this build supports ({supported}); use a newer resecta"
    )]
    SchemaTooNew { found: i64, supported: i64 },
    #[error("session {id} is held by another replica: this replica's lease on it has ended")]
    Fenced { id: String },
    #[error("storage backend: {0}")]
    Backend(String),
}

/// Durable storage of sessions, their blobs and their edit logs.
///
/// Every method that names a session returns [`StoreError::NotFound`] when it does not exist
/// (except `session` and `delete_session`, which answer `None`/`false`). Writes are durable when
/// they return.
pub trait SessionStore: Send + Sync + std::fmt::Debug {
    /// Creates a session; [`StoreError::AlreadyExists`] if its id is taken.
    fn create_session(&self, rec: &SessionRecord) -> Result<(), StoreError>;
    /// All sessions, ordered by `created_ms`, then `id`.
    fn sessions(&self) -> Result<Vec<SessionRecord>, StoreError>;
    fn session(&self, id: &str) -> Result<Option<SessionRecord>, StoreError>;
    /// Deletes a session with its blobs and log; `false` if it did not exist.
    fn delete_session(&self, id: &str) -> Result<bool, StoreError>;
    /// Records an access at `at_ms`; `last_access_ms` never moves backwards.
    fn touch(&self, id: &str, at_ms: i64) -> Result<(), StoreError>;
    /// Stores a blob under `key` (e.g. "labelmap", "models"), replacing any previous one.
    fn put_blob(&self, id: &str, key: &str, blob: &Blob) -> Result<(), StoreError>;
    fn blob(&self, id: &str, key: &str) -> Result<Option<Blob>, StoreError>;
    /// Deletes a blob; `false` if the session has no blob under `key`.
    fn delete_blob(&self, id: &str, key: &str) -> Result<bool, StoreError>;
    /// Appends `records` at seq expected_len+1.. atomically; Conflict if the log's length != expected_len.
    /// Durable (fsynced) when it returns. Returns the new length.
    fn append(&self, id: &str, expected_len: u64, records: &[String]) -> Result<u64, StoreError>;
    /// Log records with seq > `after`, in order.
    fn log(&self, id: &str, after: u64) -> Result<Vec<LogRecord>, StoreError>;
    fn log_len(&self, id: &str) -> Result<u64, StoreError>;
    /// Ids of sessions with `last_access_ms < before_ms`, least recently used first.
    fn idle_since(&self, before_ms: i64) -> Result<Vec<String>, StoreError>;
    fn usage(&self) -> Result<StoreUsage, StoreError>;

    // ---- leases (module docs) -----------------------------------------------------------------

    /// Takes session `id`'s lease for `replica` for `ttl_ms`: granted when there is no lease,
    /// when it has expired or was released, when `replica.id` holds it already (then it is
    /// renewed with the same token), or when an earlier process of the same replica name holds
    /// it ([`Replica::succeeds`]: a restarted replica takes its sessions back at once); a new
    /// holder's token is larger than every earlier one of the session. Once granted, this handle's writes to the session (`append`, `put_blob`,
    /// `delete_blob`, `delete_session`) fail with [`StoreError::Fenced`] if another holder has
    /// claimed it since. `Held` when another replica's lease is unexpired.
    fn claim(&self, id: &str, replica: &Replica, ttl_ms: u64) -> Result<Claim, StoreError>;
    /// Extends by `ttl_ms` the leases among `ids` that `replica_id` still holds with the
    /// tokens this handle was granted; returns the others (taken over, released or deleted),
    /// to which this handle's writes stay fenced (until it claims them again).
    fn renew(
        &self,
        replica_id: &str,
        ids: &[String],
        ttl_ms: u64,
    ) -> Result<Vec<String>, StoreError>;
    /// Ends `replica_id`'s lease on `id` at once (draining), so another replica's next claim
    /// succeeds; `false` if it did not hold it. The token is kept: the next holder's is larger.
    fn release(&self, id: &str, replica_id: &str) -> Result<bool, StoreError>;
    /// The session's unexpired lease, if any.
    fn lease(&self, id: &str) -> Result<Option<Lease>, StoreError>;
}

/// Longest session id or blob key.
pub const MAX_NAME_LEN: usize = 128;

/// Ids and keys: 1..=128 ASCII letters, digits and `-_.:` (they appear in messages and logs).
fn check_name(what: &'static str, name: &str) -> Result<(), StoreError> {
    let ok = !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b':'));
    if ok {
        Ok(())
    } else {
        Err(StoreError::Invalid {
            what,
            reason: format!("must be 1 to {MAX_NAME_LEN} ASCII letters, digits or -_.:"),
        })
    }
}

/// A count or length as a database integer.
fn to_i64(what: &'static str, v: u64) -> Result<i64, StoreError> {
    i64::try_from(v).map_err(|_| StoreError::Invalid {
        what,
        reason: format!("{v} exceeds {}", i64::MAX),
    })
}

/// A database integer read back as a count or length: negative means a damaged store.
fn to_u64(what: &str, v: i64) -> Result<u64, StoreError> {
    u64::try_from(v).map_err(|_| StoreError::Corrupt {
        detail: format!("negative {what} {v}"),
    })
}

fn not_found(id: &str) -> StoreError {
    StoreError::NotFound { id: id.to_owned() }
}

fn check_record(opts: &StoreOptions, what: &'static str, len: usize) -> Result<(), StoreError> {
    if len > opts.max_record_bytes {
        return Err(StoreError::TooLarge {
            what,
            size: len as u64,
            limit: opts.max_record_bytes as u64,
        });
    }
    Ok(())
}

fn check_session(opts: &StoreOptions, rec: &SessionRecord) -> Result<(), StoreError> {
    check_name("session id", &rec.id)?;
    check_record(opts, "display name", rec.display_name.len())
}

fn check_records(opts: &StoreOptions, records: &[String]) -> Result<(), StoreError> {
    records
        .iter()
        .try_for_each(|r| check_record(opts, "log record", r.len()))
}
