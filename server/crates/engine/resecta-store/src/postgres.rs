//! PostgreSQL backend: a database shared by several server replicas, reached through a pool of
//! synchronous connections (`postgres` over `r2d2`), optionally over TLS (rustls).
//!
//! Semantics are [`crate::SqliteStore`]'s. Every write is one transaction that first locks the
//! session's row (`SELECT … FOR UPDATE`), so appends, lease claims, blob writes and deletion of
//! one session serialise, while different sessions proceed in parallel; an append is
//! acknowledged once its `COMMIT` returned, which PostgreSQL makes durable (WAL flushed) with
//! `synchronous_commit` on, its default (a server or role that sets it `off` is overridden to
//! `on` for the store's connections). Transactions run at READ COMMITTED whatever the database's
//! default, so each statement after the row lock sees what the previous holder of the lock
//! committed.
//!
//! Lease expiry is measured by the database server's clock (`clock_timestamp()`), never by a
//! replica's.
//!
//! Text is stored as `text`, which cannot hold a NUL character: a display name, blob metadata
//! or log record containing one is refused with [`StoreError::Invalid`] (the one difference to
//! the other backends). The database's encoding must be UTF8.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use postgres::config::{Host, SslMode};
use postgres::error::SqlState;
use postgres::types::{ToSql, Type};
use postgres::{Client, IsolationLevel, Row, Transaction};
use r2d2_postgres::PostgresConnectionManager;
use rustls::client::WebPkiServerVerifier;
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::{CryptoProvider, WebPkiSupportedAlgorithms};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::{
    CertificateError, ClientConfig, DigitallySignedStruct, RootCertStore, SignatureScheme,
};
use tokio_postgres_rustls::MakeRustlsConnect;

use crate::codec::{pack_within, unpack};
use crate::{
    Blob, Claim, Lease, LogRecord, Replica, SessionRecord, SessionStore, StoreError, StoreOptions,
    StoreUsage, check_name, check_record, check_records, check_session, not_found, to_i64, to_u64,
};

/// Connections a store keeps at most ([`PostgresStore::open`]): enough for the server's
/// blocking threads that touch the store at once; a replica of 16 connections leaves room for
/// several replicas under PostgreSQL's default `max_connections` of 100. Connections are opened
/// on demand and closed after 10 idle minutes.
pub const DEFAULT_POOL_SIZE: u32 = 16;

/// Key of the transaction-level advisory lock held while the schema is checked and migrated,
/// so that replicas starting at once do not race ("RSSTPG" and 1).
const MIGRATION_LOCK: i64 = 0x5253_5354_5047_0001;

/// Largest compressed blob stored: as the SQLite backend's limit (PostgreSQL's own is 1 GiB).
const MAX_VALUE: u64 = 1_000_000_000;

/// Longest lease accepted (longer ones are shortened to it): 1000 years, far inside
/// PostgreSQL's timestamp range.
const MAX_TTL_MS: u64 = 1000 * 366 * 24 * 3600 * 1000;

/// Connect timeout when the URL sets none (`connect_timeout`), and the longest wait for a
/// pooled connection.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Version 1: sessions, blobs, the log and leases. Ids and keys are compared bytewise
/// (`COLLATE "C"`), so listings are ordered as the other backends order them.
const SCHEMA: &str = r#"
CREATE TABLE resecta_schema (version bigint NOT NULL);
CREATE TABLE sessions (
    id text COLLATE "C" PRIMARY KEY,
    display_name text NOT NULL,
    created_ms bigint NOT NULL,
    last_access_ms bigint NOT NULL
);
CREATE INDEX sessions_by_created ON sessions (created_ms, id);
CREATE INDEX sessions_by_access ON sessions (last_access_ms, id);
CREATE TABLE blobs (
    session_id text COLLATE "C" NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
    key text COLLATE "C" NOT NULL,
    meta_json text NOT NULL,
    raw_len bigint NOT NULL,
    data bytea NOT NULL,
    PRIMARY KEY (session_id, key)
);
CREATE TABLE log (
    session_id text COLLATE "C" NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
    seq bigint NOT NULL,
    json text NOT NULL,
    PRIMARY KEY (session_id, seq)
);
CREATE TABLE leases (
    session_id text COLLATE "C" PRIMARY KEY REFERENCES sessions (id) ON DELETE CASCADE,
    holder_id text NOT NULL,
    holder_grpc text NOT NULL,
    holder_http text NOT NULL,
    token bigint NOT NULL,
    expires_at timestamptz NOT NULL
);
"#;

/// Migrations from each version to the next: `MIGRATIONS[v - 1]` takes version v to v + 1.
const MIGRATIONS: [&str; 0] = [];

/// Tables of the schema, refused in a database that has them without a `resecta_schema`.
const TABLES: [&str; 4] = ["sessions", "blobs", "log", "leases"];

type Pool = r2d2::Pool<PostgresConnectionManager<MakeRustlsConnect>>;

/// Sessions in a PostgreSQL database, shared by every replica that opens it (module docs).
pub struct PostgresStore {
    /// `postgres://user@host:port/db (sslmode=…)`: names the database in messages; never the
    /// password.
    target: String,
    opts: StoreOptions,
    /// Always `Some` until dropped (see `Drop`).
    pool: Option<Pool>,
    /// Lease tokens this handle was granted, by session.
    fences: Mutex<HashMap<String, u64>>,
}

/// Closing a connection of the synchronous driver blocks on its own runtime, which panics on
/// a thread that drives an async runtime (a server dropping its store at shutdown): the pool
/// is dropped on a thread of its own.
impl Drop for PostgresStore {
    fn drop(&mut self) {
        if let Some(pool) = self.pool.take() {
            let _ = std::thread::spawn(move || drop(pool)).join();
        }
    }
}

impl std::fmt::Debug for PostgresStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PostgresStore")
            .field("target", &self.target)
            .field("opts", &self.opts)
            .finish_non_exhaustive()
    }
}

/// How TLS to the database is used (libpq's `sslmode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TlsMode {
    Disable,
    Prefer,
    Require,
    VerifyCa,
    VerifyFull,
}

impl TlsMode {
    fn parse(s: &str) -> Result<Self, StoreError> {
        Ok(match s {
            "disable" => Self::Disable,
            "prefer" => Self::Prefer,
            "require" => Self::Require,
            "verify-ca" => Self::VerifyCa,
            "verify-full" => Self::VerifyFull,
            _ => {
                return Err(StoreError::Invalid {
                    what: "database URL",
                    reason: format!(
                        "sslmode {s:?} is not one of disable, prefer, require, verify-ca, \
                         verify-full"
                    ),
                });
            }
        })
    }

    fn name(self) -> &'static str {
        match self {
            Self::Disable => "disable",
            Self::Prefer => "prefer",
            Self::Require => "require",
            Self::VerifyCa => "verify-ca",
            Self::VerifyFull => "verify-full",
        }
    }
}

/// A parsed database URL: the connection settings, the TLS connector and what names the
/// database in messages.
struct Target {
    config: postgres::Config,
    tls: MakeRustlsConnect,
    desc: String,
    /// Passwords given, to be scrubbed from any message that might quote them.
    secrets: Vec<String>,
}

fn invalid_url(reason: impl Into<String>) -> StoreError {
    StoreError::Invalid {
        what: "database URL",
        reason: reason.into(),
    }
}

/// `%XX` decoding of a URL component.
fn percent_decode(s: &str) -> Result<String, StoreError> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = bytes
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| invalid_url("malformed %-escape"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| invalid_url("%-escapes do not decode to UTF-8"))
}

/// The password written in a URL's user info, if any (raw and decoded), to scrub from messages.
fn url_passwords(url: &str) -> Vec<String> {
    let rest = url.split_once("://").map_or(url, |(_, r)| r);
    let authority = rest.split(['/', '?']).next().unwrap_or("");
    let Some((userinfo, _)) = authority.rsplit_once('@') else {
        return Vec::new();
    };
    let Some((_, pw)) = userinfo.split_once(':') else {
        return Vec::new();
    };
    let mut out = vec![pw.to_owned()];
    if let Ok(decoded) = percent_decode(pw) {
        out.push(decoded);
    }
    out
}

/// `msg` with every password in `secrets` replaced (too short ones are left: they would mangle
/// the message and reveal nothing).
fn scrub(msg: String, secrets: &[String]) -> String {
    secrets
        .iter()
        .filter(|s| s.len() >= 4)
        .fold(msg, |m, s| m.replace(s.as_str(), "***"))
}

impl Target {
    fn parse(url: &str, password: Option<String>) -> Result<Self, StoreError> {
        let mut secrets = url_passwords(url);
        secrets.extend(password.iter().cloned());
        Self::parse_inner(url, password, &secrets).map_err(|e| match e {
            StoreError::Invalid { what, reason } => StoreError::Invalid {
                what,
                reason: scrub(reason, &secrets),
            },
            StoreError::Backend(msg) => StoreError::Backend(scrub(msg, &secrets)),
            e @ (StoreError::NotFound { .. }
            | StoreError::AlreadyExists { .. }
            | StoreError::Conflict { .. }
            | StoreError::TooLarge { .. }
            | StoreError::Corrupt { .. }
            | StoreError::SchemaTooNew { .. }
            | StoreError::Fenced { .. }) => e,
        })
    }

    fn parse_inner(
        url: &str,
        password: Option<String>,
        secrets: &[String],
    ) -> Result<Self, StoreError> {
        if !(url.starts_with("postgres://") || url.starts_with("postgresql://")) {
            return Err(invalid_url(
                "must be a postgres:// or postgresql:// URL (user@host:port/database?sslmode=…)",
            ));
        }
        // tokio-postgres knows sslmode up to require and no sslrootcert: those two are ours.
        let (base, query) = url.split_once('?').unwrap_or((url, ""));
        let mut mode = TlsMode::Prefer;
        let mut root_cert: Option<PathBuf> = None;
        let mut kept = Vec::new();
        for param in query.split('&').filter(|p| !p.is_empty()) {
            let (key, value) = param.split_once('=').unwrap_or((param, ""));
            match key {
                "sslmode" => mode = TlsMode::parse(&percent_decode(value)?)?,
                "sslrootcert" => root_cert = Some(PathBuf::from(percent_decode(value)?)),
                _ => kept.push(param),
            }
        }
        let rest = if kept.is_empty() {
            base.to_owned()
        } else {
            format!("{base}?{}", kept.join("&"))
        };
        let mut config: postgres::Config = rest
            .parse()
            .map_err(|e: postgres::Error| invalid_url(with_causes(&e)))?;
        if let Some(pw) = password {
            config.password(pw);
        }
        if config.get_connect_timeout().is_none() {
            config.connect_timeout(CONNECT_TIMEOUT);
        }
        if config.get_application_name().is_none() {
            config.application_name("resecta");
        }
        config.ssl_mode(match mode {
            TlsMode::Disable => SslMode::Disable,
            TlsMode::Prefer => SslMode::Prefer,
            TlsMode::Require | TlsMode::VerifyCa | TlsMode::VerifyFull => SslMode::Require,
        });
        let tls = MakeRustlsConnect::new(tls_config(mode, root_cert.as_deref())?);
        let desc = describe(&config, mode);
        Ok(Self {
            config,
            tls,
            desc,
            secrets: secrets.to_vec(),
        })
    }
}

/// `postgres://user@host:port/db (sslmode=…)`, without the password.
fn describe(config: &postgres::Config, mode: TlsMode) -> String {
    let ports = config.get_ports();
    let hosts: Vec<String> = config
        .get_hosts()
        .iter()
        .enumerate()
        .map(|(i, h)| {
            let port = ports.get(i).or(ports.first()).copied().unwrap_or(5432);
            match h {
                Host::Tcp(name) => format!("{name}:{port}"),
                Host::Unix(dir) => format!("{}:{port}", dir.display()),
            }
        })
        .collect();
    format!(
        "postgres://{}@{}/{} (sslmode={})",
        config.get_user().unwrap_or(""),
        hosts.join(","),
        config.get_dbname().unwrap_or(""),
        mode.name()
    )
}

fn ring() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// The rustls configuration for `mode`: no verification for prefer and require (the
/// connection is encrypted, the server unauthenticated) unless a root certificate file is
/// given, when they verify the chain as libpq does; verify-ca checks the chain to the roots of
/// `sslrootcert`, verify-full also the host name.
fn tls_config(mode: TlsMode, root_cert: Option<&Path>) -> Result<ClientConfig, StoreError> {
    let provider = ring();
    let builder = ClientConfig::builder_with_provider(Arc::clone(&provider))
        .with_safe_default_protocol_versions()
        .map_err(|e| StoreError::Backend(format!("TLS set-up: {e}")))?;
    let roots = match root_cert {
        Some(path) => Some(read_roots(path)?),
        None if matches!(mode, TlsMode::VerifyCa | TlsMode::VerifyFull) => {
            return Err(invalid_url(format!(
                "sslmode={} needs sslrootcert=PATH, a PEM file of the certificate authorities \
                 to trust",
                mode.name()
            )));
        }
        None => None,
    };
    let verifier: Arc<dyn ServerCertVerifier> = match roots {
        None => Arc::new(NoVerify(provider.signature_verification_algorithms)),
        Some(roots) => {
            let webpki =
                WebPkiServerVerifier::builder_with_provider(Arc::new(roots), Arc::clone(&provider))
                    .build()
                    .map_err(|e| StoreError::Backend(format!("TLS set-up: {e}")))?;
            if mode == TlsMode::VerifyFull {
                webpki
            } else {
                Arc::new(ChainOnly(webpki))
            }
        }
    };
    Ok(builder
        .dangerous()
        .with_custom_certificate_verifier(verifier)
        .with_no_client_auth())
}

fn read_roots(path: &Path) -> Result<RootCertStore, StoreError> {
    let bad = |reason: String| StoreError::Invalid {
        what: "sslrootcert",
        reason: format!("{}: {reason}", path.display()),
    };
    let mut roots = RootCertStore::empty();
    for cert in CertificateDer::pem_file_iter(path).map_err(|e| bad(e.to_string()))? {
        let cert = cert.map_err(|e| bad(e.to_string()))?;
        roots.add(cert).map_err(|e| bad(e.to_string()))?;
    }
    if roots.is_empty() {
        return Err(bad("holds no PEM certificate".into()));
    }
    Ok(roots)
}

/// sslmode=prefer/require without root certificates: any certificate, the handshake's
/// signatures still checked.
#[derive(Debug)]
struct NoVerify(WebPkiSupportedAlgorithms);

impl ServerCertVerifier for NoVerify {
    fn verify_server_cert(
        &self,
        _end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp_response: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        Ok(ServerCertVerified::assertion())
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls12_signature(message, cert, dss, &self.0)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(message, cert, dss, &self.0)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.0.supported_schemes()
    }
}

/// sslmode=verify-ca: the chain to a trusted root, any host name. webpki checks the name last,
/// so a name mismatch means everything else was verified.
#[derive(Debug)]
struct ChainOnly(Arc<WebPkiServerVerifier>);

impl ServerCertVerifier for ChainOnly {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        server_name: &ServerName<'_>,
        ocsp_response: &[u8],
        now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        let verified =
            self.0
                .verify_server_cert(end_entity, intermediates, server_name, ocsp_response, now);
        if let Err(rustls::Error::InvalidCertificate(
            CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. },
        )) = verified
        {
            return Ok(ServerCertVerified::assertion());
        }
        verified
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.0.verify_tls12_signature(message, cert, dss)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.0.verify_tls13_signature(message, cert, dss)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.0.supported_verify_schemes()
    }
}

/// Turns `synchronous_commit` back on for a pooled connection where the server or role set it
/// off: an append is acknowledged only once durable.
#[derive(Debug)]
struct DurableCommits;

impl r2d2::CustomizeConnection<Client, postgres::Error> for DurableCommits {
    fn on_acquire(&self, conn: &mut Client) -> Result<(), postgres::Error> {
        conn.batch_execute(DURABLE_COMMITS)
    }
}

const DURABLE_COMMITS: &str = "SELECT set_config('synchronous_commit', 'on', false) \
     WHERE current_setting('synchronous_commit') = 'off'";

/// Maps PostgreSQL errors: the message and SQLSTATE of a server error (never its DETAIL, which
/// may quote row values), the error itself otherwise (I/O, protocol).
fn db(e: postgres::Error) -> StoreError {
    if let Some(dbe) = e.as_db_error() {
        let code = dbe.code();
        if *code == SqlState::DATA_CORRUPTED || *code == SqlState::INDEX_CORRUPTED {
            return StoreError::Corrupt {
                detail: format!("{} (SQLSTATE {})", dbe.message(), code.code()),
            };
        }
    }
    StoreError::Backend(message(&e))
}

/// What a PostgreSQL error says, without a server error's DETAIL (see [`db`]).
fn message(e: &postgres::Error) -> String {
    match e.as_db_error() {
        Some(dbe) => format!(
            "PostgreSQL {}: {} (SQLSTATE {})",
            dbe.severity(),
            dbe.message(),
            dbe.code().code()
        ),
        None => format!("PostgreSQL: {}", with_causes(e)),
    }
}

/// An error and its causes, `: `-separated (tokio-postgres shows only its own kind).
fn with_causes(e: &dyn std::error::Error) -> String {
    let mut out = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        out = format!("{out}: {c}");
        cause = c.source();
    }
    out
}

/// PostgreSQL text holds no NUL character.
fn check_text(what: &'static str, s: &str) -> Result<(), StoreError> {
    if s.contains('\0') {
        return Err(StoreError::Invalid {
            what,
            reason: "contains a NUL character, which PostgreSQL text cannot hold".into(),
        });
    }
    Ok(())
}

/// The row's column `i`, errors mapped.
fn col<'a, T: postgres::types::FromSql<'a>>(row: &'a Row, i: usize) -> Result<T, StoreError> {
    row.try_get(i).map_err(db)
}

type Params<'a> = [(&'a (dyn ToSql + Sync), Type)];

/// Starts a READ COMMITTED transaction (module docs).
fn begin(client: &mut Client) -> Result<Transaction<'_>, StoreError> {
    client
        .build_transaction()
        .isolation_level(IsolationLevel::ReadCommitted)
        .start()
        .map_err(db)
}

/// Locks session `id`'s row for the transaction: `NotFound` if there is none.
fn lock_session(tx: &mut Transaction<'_>, id: &str) -> Result<(), StoreError> {
    let row = tx
        .query_typed_opt(
            "SELECT 1 FROM sessions WHERE id = $1 FOR UPDATE",
            &[(&id, Type::TEXT)],
        )
        .map_err(db)?;
    row.map(drop).ok_or_else(|| not_found(id))
}

/// `Fenced` if `fence` (this handle's token) is no longer the session's lease token; after
/// [`lock_session`], so that no claim can slip in before the write commits.
fn check_fence(tx: &mut Transaction<'_>, id: &str, fence: Option<u64>) -> Result<(), StoreError> {
    let Some(fence) = fence else {
        return Ok(());
    };
    let token: Option<i64> = tx
        .query_typed_opt(
            "SELECT token FROM leases WHERE session_id = $1",
            &[(&id, Type::TEXT)],
        )
        .map_err(db)?
        .map(|r| col(&r, 0))
        .transpose()?;
    if token.and_then(|t| u64::try_from(t).ok()) == Some(fence) {
        Ok(())
    } else {
        Err(StoreError::Fenced { id: id.to_owned() })
    }
}

/// Checks the database is a resecta store of a known schema, creating or migrating it, in one
/// transaction holding [`MIGRATION_LOCK`].
fn migrate(client: &mut Client) -> Result<(), StoreError> {
    let encoding: String = col(
        &client
            .query_one("SELECT current_setting('server_encoding')", &[])
            .map_err(db)?,
        0,
    )?;
    if encoding != "UTF8" {
        return Err(StoreError::Backend(format!(
            "the database's encoding is {encoding}; resecta needs UTF8 (CREATE DATABASE … \
             ENCODING 'UTF8')"
        )));
    }
    let mut tx = begin(client)?;
    tx.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
        .map_err(db)?;
    let versioned: bool = col(
        &tx.query_one("SELECT to_regclass('resecta_schema') IS NOT NULL", &[])
            .map_err(db)?,
        0,
    )?;
    if !versioned {
        let names: Vec<String> = TABLES.iter().map(|t| (*t).to_owned()).collect();
        let clashes: Vec<String> = tx
            .query(
                "SELECT t FROM unnest($1::text[]) AS t WHERE to_regclass(quote_ident(t)) IS NOT NULL",
                &[&names],
            )
            .map_err(db)?
            .iter()
            .map(|r| col(r, 0))
            .collect::<Result<_, _>>()?;
        if !clashes.is_empty() {
            return Err(StoreError::Corrupt {
                detail: format!(
                    "the database holds tables named {} but no resecta_schema: not a resecta store",
                    clashes.join(", ")
                ),
            });
        }
        tx.batch_execute(SCHEMA).map_err(writable)?;
        for m in MIGRATIONS {
            tx.batch_execute(m).map_err(writable)?;
        }
        tx.execute(
            "INSERT INTO resecta_schema (version) VALUES ($1)",
            &[&PostgresStore::SCHEMA_VERSION],
        )
        .map_err(writable)?;
    } else {
        let version: Option<i64> = col(
            &tx.query_one("SELECT max(version) FROM resecta_schema", &[])
                .map_err(db)?,
            0,
        )?;
        let version = version.ok_or_else(|| StoreError::Corrupt {
            detail: "resecta_schema holds no version".into(),
        })?;
        if version > PostgresStore::SCHEMA_VERSION {
            return Err(StoreError::SchemaTooNew {
                found: version,
                supported: PostgresStore::SCHEMA_VERSION,
            });
        }
        let from = usize::try_from(version - 1).map_err(|_| StoreError::Corrupt {
            detail: format!("schema version {version}"),
        })?;
        for m in &MIGRATIONS[from.min(MIGRATIONS.len())..] {
            tx.batch_execute(m).map_err(writable)?;
        }
        // A real write (the version, migrated or not), so that a read-only role or a standby
        // is refused here rather than at the first acknowledged edit.
        tx.execute(
            "UPDATE resecta_schema SET version = $1",
            &[&PostgresStore::SCHEMA_VERSION],
        )
        .map_err(writable)?;
    }
    tx.commit().map_err(writable)
}

/// A failed write, named for what it usually means when the database refuses writes.
fn writable(e: postgres::Error) -> StoreError {
    let code = e.code();
    if code == Some(&SqlState::READ_ONLY_SQL_TRANSACTION)
        || code == Some(&SqlState::INSUFFICIENT_PRIVILEGE)
    {
        StoreError::Backend(format!(
            "the store cannot be written (a standby, a read-only transaction default or a role \
             without privileges): {}",
            message(&e)
        ))
    } else {
        db(e)
    }
}

impl PostgresStore {
    /// Schema version in `resecta_schema`: 1 sessions, blobs, the log and leases.
    pub const SCHEMA_VERSION: i64 = 1;

    /// Opens the store in the database at `url`, creating or migrating its schema, with a pool
    /// of at most [`DEFAULT_POOL_SIZE`] connections.
    ///
    /// `url` is a libpq-style URL, `postgres://user[:password]@host[:port]/database[?params]`;
    /// `password`, when given (read from a file or the environment by the caller), replaces the
    /// URL's. Parameters: `sslmode=disable|prefer|require|verify-ca|verify-full` (default
    /// prefer; verify-ca and verify-full need `sslrootcert`), `sslrootcert=PATH` (PEM file of
    /// the certificate authorities to trust; with prefer or require it makes them verify the
    /// chain, as libpq does), and those tokio-postgres knows (`connect_timeout`,
    /// `application_name`, `options`, …). TLS is rustls on the ring provider. No error and no
    /// `Debug` output contains the password.
    pub fn open(
        url: &str,
        password: Option<String>,
        opts: StoreOptions,
    ) -> Result<Self, StoreError> {
        Self::open_with_pool_size(url, password, opts, DEFAULT_POOL_SIZE)
    }

    /// [`PostgresStore::open`] with at most `pool_size` (≥ 1) connections.
    pub fn open_with_pool_size(
        url: &str,
        password: Option<String>,
        opts: StoreOptions,
        pool_size: u32,
    ) -> Result<Self, StoreError> {
        if pool_size == 0 {
            return Err(StoreError::Invalid {
                what: "pool size",
                reason: "must be at least 1".into(),
            });
        }
        let target = Target::parse(url, password)?;
        let in_target = |e: StoreError| match e {
            StoreError::Backend(msg) => {
                StoreError::Backend(scrub(format!("{}: {msg}", target.desc), &target.secrets))
            }
            StoreError::Corrupt { detail } => StoreError::Corrupt {
                detail: format!("{}: {detail}", target.desc),
            },
            e @ (StoreError::NotFound { .. }
            | StoreError::AlreadyExists { .. }
            | StoreError::Conflict { .. }
            | StoreError::TooLarge { .. }
            | StoreError::Invalid { .. }
            | StoreError::SchemaTooNew { .. }
            | StoreError::Fenced { .. }) => e,
        };
        // One connection of its own first: a wrong URL or password fails here at once, with
        // the server's reason, rather than after the pool's wait.
        let mut first = target
            .config
            .connect(target.tls.clone())
            .map_err(|e| in_target(db(e)))?;
        migrate(&mut first).map_err(in_target)?;
        drop(first);
        let manager = PostgresConnectionManager::new(target.config.clone(), target.tls.clone());
        let pool = r2d2::Pool::builder()
            .max_size(pool_size)
            .min_idle(Some(0))
            .connection_timeout(CONNECT_TIMEOUT)
            .idle_timeout(Some(Duration::from_secs(600)))
            .connection_customizer(Box::new(DurableCommits))
            .build_unchecked(manager);
        Ok(Self {
            target: target.desc,
            opts,
            pool: Some(pool),
            fences: Mutex::default(),
        })
    }

    /// The database as messages name it: `postgres://user@host:port/db (sslmode=…)`.
    pub fn target(&self) -> &str {
        &self.target
    }

    pub fn options(&self) -> &StoreOptions {
        &self.opts
    }

    /// Whether the store's connections to the database are encrypted (TLS), as the server
    /// reports it for one of them.
    pub fn encrypted(&self) -> Result<bool, StoreError> {
        let mut c = self.conn()?;
        let row = c
            .query_one(
                "SELECT COALESCE((SELECT ssl FROM pg_stat_ssl WHERE pid = pg_backend_pid()), false)",
                &[],
            )
            .map_err(db)?;
        col(&row, 0)
    }

    fn conn(
        &self,
    ) -> Result<r2d2::PooledConnection<PostgresConnectionManager<MakeRustlsConnect>>, StoreError>
    {
        self.pool
            .as_ref()
            .ok_or_else(|| StoreError::Backend(format!("{}: the store is closed", self.target)))?
            .get()
            .map_err(|e| StoreError::Backend(format!("{}: {e}", self.target)))
    }

    fn fences(&self) -> MutexGuard<'_, HashMap<String, u64>> {
        self.fences.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn fence(&self, id: &str) -> Option<u64> {
        self.fences().get(id).copied()
    }

    /// Runs `f` in a transaction on a pooled connection and commits if it succeeded.
    fn write<T>(
        &self,
        f: impl FnOnce(&mut Transaction<'_>) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut c = self.conn()?;
        let mut tx = begin(&mut c)?;
        let out = f(&mut tx)?;
        tx.commit().map_err(db)?;
        Ok(out)
    }

    fn query(&self, sql: &str, params: &Params<'_>) -> Result<Vec<Row>, StoreError> {
        self.conn()?.query_typed(sql, params).map_err(db)
    }
}

fn read_record(r: &Row) -> Result<SessionRecord, StoreError> {
    Ok(SessionRecord {
        id: col(r, 0)?,
        display_name: col(r, 1)?,
        created_ms: col(r, 2)?,
        last_access_ms: col(r, 3)?,
    })
}

/// A session's lease row: holder, token, whether unexpired and the time left, by the database
/// server's clock.
fn lease_row(
    tx: &mut Transaction<'_>,
    id: &str,
) -> Result<Option<(Replica, u64, bool, u64)>, StoreError> {
    let row = tx
        .query_typed_opt(
            "SELECT holder_id, holder_grpc, holder_http, token, expires_at > c.now,
                    GREATEST(0, floor(extract(epoch FROM expires_at - c.now) * 1000))::bigint
             FROM leases, (SELECT clock_timestamp() AS now) c WHERE session_id = $1",
            &[(&id, Type::TEXT)],
        )
        .map_err(db)?;
    row.map(|r| {
        Ok((
            Replica {
                id: col(&r, 0)?,
                grpc: col(&r, 1)?,
                http: col(&r, 2)?,
            },
            to_u64("lease token", col(&r, 3)?)?,
            col(&r, 4)?,
            to_u64("lease time", col(&r, 5)?)?,
        ))
    })
    .transpose()
}

fn ttl(ttl_ms: u64) -> i64 {
    i64::try_from(ttl_ms.min(MAX_TTL_MS)).unwrap_or(i64::MAX)
}

impl SessionStore for PostgresStore {
    fn create_session(&self, rec: &SessionRecord) -> Result<(), StoreError> {
        check_session(&self.opts, rec)?;
        check_text("display name", &rec.display_name)?;
        let n = self
            .conn()?
            .execute_typed(
                "INSERT INTO sessions (id, display_name, created_ms, last_access_ms)
                 VALUES ($1, $2, $3, $4) ON CONFLICT (id) DO NOTHING",
                &[
                    (&rec.id, Type::TEXT),
                    (&rec.display_name, Type::TEXT),
                    (&rec.created_ms, Type::INT8),
                    (&rec.last_access_ms, Type::INT8),
                ],
            )
            .map_err(|e| {
                if e.code() == Some(&SqlState::UNIQUE_VIOLATION) {
                    StoreError::AlreadyExists { id: rec.id.clone() }
                } else {
                    db(e)
                }
            })?;
        if n == 0 {
            return Err(StoreError::AlreadyExists { id: rec.id.clone() });
        }
        Ok(())
    }

    fn sessions(&self) -> Result<Vec<SessionRecord>, StoreError> {
        self.query(
            "SELECT id, display_name, created_ms, last_access_ms FROM sessions
             ORDER BY created_ms, id",
            &[],
        )?
        .iter()
        .map(read_record)
        .collect()
    }

    fn session(&self, id: &str) -> Result<Option<SessionRecord>, StoreError> {
        self.query(
            "SELECT id, display_name, created_ms, last_access_ms FROM sessions WHERE id = $1",
            &[(&id, Type::TEXT)],
        )?
        .first()
        .map(read_record)
        .transpose()
    }

    fn delete_session(&self, id: &str) -> Result<bool, StoreError> {
        let fence = self.fence(id);
        let deleted = self.write(|tx| {
            match lock_session(tx, id) {
                Err(StoreError::NotFound { .. }) => return Ok(false),
                other => other?,
            }
            check_fence(tx, id, fence)?;
            tx.execute_typed("DELETE FROM sessions WHERE id = $1", &[(&id, Type::TEXT)])
                .map_err(db)?;
            Ok(true)
        })?;
        if deleted {
            self.fences().remove(id);
        }
        Ok(deleted)
    }

    fn touch(&self, id: &str, at_ms: i64) -> Result<(), StoreError> {
        let n = self
            .conn()?
            .execute_typed(
                "UPDATE sessions SET last_access_ms = GREATEST(last_access_ms, $2) WHERE id = $1",
                &[(&id, Type::TEXT), (&at_ms, Type::INT8)],
            )
            .map_err(db)?;
        if n == 0 {
            return Err(not_found(id));
        }
        Ok(())
    }

    fn put_blob(&self, id: &str, key: &str, blob: &Blob) -> Result<(), StoreError> {
        check_name("blob key", key)?;
        check_record(&self.opts, "blob metadata", blob.meta_json.len())?;
        check_text("blob metadata", &blob.meta_json)?;
        if self
            .query("SELECT 1 FROM sessions WHERE id = $1", &[(&id, Type::TEXT)])?
            .is_empty()
        {
            return Err(not_found(id));
        }
        let (packed, raw_len) = pack_within(&self.opts, &blob.data, MAX_VALUE)?;
        let fence = self.fence(id);
        self.write(|tx| {
            lock_session(tx, id)?;
            check_fence(tx, id, fence)?;
            tx.execute_typed(
                "INSERT INTO blobs (session_id, key, meta_json, raw_len, data)
                 VALUES ($1, $2, $3, $4, $5)
                 ON CONFLICT (session_id, key) DO UPDATE SET
                   meta_json = excluded.meta_json, raw_len = excluded.raw_len, data = excluded.data",
                &[
                    (&id, Type::TEXT),
                    (&key, Type::TEXT),
                    (&blob.meta_json, Type::TEXT),
                    (&raw_len, Type::INT8),
                    (&packed.data, Type::BYTEA),
                ],
            )
            .map_err(db)?;
            Ok(())
        })
    }

    fn blob(&self, id: &str, key: &str) -> Result<Option<Blob>, StoreError> {
        let rows = self.query(
            "SELECT b.meta_json, b.raw_len, b.data FROM sessions s
             LEFT JOIN blobs b ON b.session_id = s.id AND b.key = $2 WHERE s.id = $1",
            &[(&id, Type::TEXT), (&key, Type::TEXT)],
        )?;
        let Some(row) = rows.first() else {
            return Err(not_found(id));
        };
        let meta_json: Option<String> = col(row, 0)?;
        let raw_len: Option<i64> = col(row, 1)?;
        let data: Option<&[u8]> = col(row, 2)?;
        match (meta_json, raw_len, data) {
            (Some(meta_json), Some(raw_len), Some(data)) => {
                let data = unpack(&self.opts, to_u64("blob length", raw_len)?, data)?;
                Ok(Some(Blob { meta_json, data }))
            }
            _ => Ok(None),
        }
    }

    fn delete_blob(&self, id: &str, key: &str) -> Result<bool, StoreError> {
        let fence = self.fence(id);
        self.write(|tx| {
            lock_session(tx, id)?;
            check_fence(tx, id, fence)?;
            let n = tx
                .execute_typed(
                    "DELETE FROM blobs WHERE session_id = $1 AND key = $2",
                    &[(&id, Type::TEXT), (&key, Type::TEXT)],
                )
                .map_err(db)?;
            Ok(n > 0)
        })
    }

    fn append(&self, id: &str, expected_len: u64, records: &[String]) -> Result<u64, StoreError> {
        check_records(&self.opts, records)?;
        records
            .iter()
            .try_for_each(|r| check_text("log record", r))?;
        let fence = self.fence(id);
        // Committed (and so durable, module docs) before it returns.
        self.write(|tx| {
            lock_session(tx, id)?;
            check_fence(tx, id, fence)?;
            // A statement after the lock: it sees every append committed before the lock was ours.
            let row = tx
                .query_typed_one(
                    "SELECT COALESCE(MAX(seq), 0) FROM log WHERE session_id = $1",
                    &[(&id, Type::TEXT)],
                )
                .map_err(db)?;
            let actual = to_u64("log length", col(&row, 0)?)?;
            if actual != expected_len {
                return Err(StoreError::Conflict {
                    expected: expected_len,
                    actual,
                });
            }
            let new_len = actual + records.len() as u64;
            to_i64("log length", new_len)?;
            if !records.is_empty() {
                let after = to_i64("log length", actual)?;
                tx.execute_typed(
                    "INSERT INTO log (session_id, seq, json)
                     SELECT $1, $2 + r.n, r.json FROM unnest($3::text[]) WITH ORDINALITY AS r(json, n)",
                    &[
                        (&id, Type::TEXT),
                        (&after, Type::INT8),
                        (&records, Type::TEXT_ARRAY),
                    ],
                )
                .map_err(db)?;
            }
            Ok(new_len)
        })
    }

    fn log(&self, id: &str, after: u64) -> Result<Vec<LogRecord>, StoreError> {
        let after = i64::try_from(after).unwrap_or(i64::MAX);
        // One statement, one snapshot: no row at all when the session does not exist.
        let rows = self.query(
            "SELECT l.seq, l.json FROM sessions s
             LEFT JOIN log l ON l.session_id = s.id AND l.seq > $2
             WHERE s.id = $1 ORDER BY l.seq",
            &[(&id, Type::TEXT), (&after, Type::INT8)],
        )?;
        if rows.is_empty() {
            return Err(not_found(id));
        }
        let mut out = Vec::with_capacity(rows.len());
        for r in &rows {
            let seq: Option<i64> = col(r, 0)?;
            let json: Option<String> = col(r, 1)?;
            if let (Some(seq), Some(json)) = (seq, json) {
                out.push(LogRecord {
                    seq: to_u64("log seq", seq)?,
                    json,
                });
            }
        }
        Ok(out)
    }

    fn log_len(&self, id: &str) -> Result<u64, StoreError> {
        let rows = self.query(
            "SELECT (SELECT COALESCE(MAX(seq), 0) FROM log WHERE session_id = s.id)
             FROM sessions s WHERE s.id = $1",
            &[(&id, Type::TEXT)],
        )?;
        let row = rows.first().ok_or_else(|| not_found(id))?;
        to_u64("log length", col(row, 0)?)
    }

    fn idle_since(&self, before_ms: i64) -> Result<Vec<String>, StoreError> {
        self.query(
            "SELECT id FROM sessions WHERE last_access_ms < $1 ORDER BY last_access_ms, id",
            &[(&before_ms, Type::INT8)],
        )?
        .iter()
        .map(|r| col(r, 0))
        .collect()
    }

    fn usage(&self) -> Result<StoreUsage, StoreError> {
        let rows = self.query(
            "SELECT (SELECT COUNT(*) FROM sessions),
                    (SELECT COALESCE(SUM(octet_length(data) + octet_length(meta_json)), 0)::bigint
                     FROM blobs),
                    (SELECT COALESCE(SUM(octet_length(json)), 0)::bigint FROM log)",
            &[],
        )?;
        let row = rows
            .first()
            .ok_or_else(|| StoreError::Backend("usage query returned no row".into()))?;
        Ok(StoreUsage {
            sessions: to_u64("session count", col(row, 0)?)?,
            stored_bytes: to_u64("stored bytes", col(row, 1)?)?
                + to_u64("stored bytes", col(row, 2)?)?,
        })
    }

    fn claim(&self, id: &str, replica: &Replica, ttl_ms: u64) -> Result<Claim, StoreError> {
        let claim = self.write(|tx| {
            lock_session(tx, id)?;
            let token = match lease_row(tx, id)? {
                Some((holder, token, true, remaining_ms)) if !replica.succeeds(&holder) => {
                    return Ok(Claim::Held(Lease {
                        holder,
                        token,
                        remaining_ms,
                    }));
                }
                Some((holder, token, _, _)) if holder.id == replica.id => token,
                Some((_, token, _, _)) => token + 1,
                None => 1,
            };
            let token_i64 = to_i64("lease token", token)?;
            let ttl = ttl(ttl_ms);
            tx.execute_typed(
                "INSERT INTO leases
                   (session_id, holder_id, holder_grpc, holder_http, token, expires_at)
                 VALUES ($1, $2, $3, $4, $5, clock_timestamp() + $6 * interval '1 millisecond')
                 ON CONFLICT (session_id) DO UPDATE SET
                   holder_id = excluded.holder_id, holder_grpc = excluded.holder_grpc,
                   holder_http = excluded.holder_http, token = excluded.token,
                   expires_at = excluded.expires_at",
                &[
                    (&id, Type::TEXT),
                    (&replica.id, Type::TEXT),
                    (&replica.grpc, Type::TEXT),
                    (&replica.http, Type::TEXT),
                    (&token_i64, Type::INT8),
                    (&ttl, Type::INT8),
                ],
            )
            .map_err(db)?;
            Ok(Claim::Granted { token })
        })?;
        if let Claim::Granted { token } = claim {
            self.fences().insert(id.to_owned(), token);
        }
        Ok(claim)
    }

    fn renew(
        &self,
        replica_id: &str,
        ids: &[String],
        ttl_ms: u64,
    ) -> Result<Vec<String>, StoreError> {
        let held: Vec<(String, u64)> = {
            let fences = self.fences();
            ids.iter()
                .filter_map(|id| fences.get(id).map(|&t| (id.clone(), t)))
                .collect()
        };
        let held_ids: Vec<&str> = held.iter().map(|(id, _)| id.as_str()).collect();
        let tokens: Vec<i64> = held
            .iter()
            .map(|(_, t)| to_i64("lease token", *t))
            .collect::<Result<_, _>>()?;
        let ttl = ttl(ttl_ms);
        // The rows are locked in id order, so that overlapping renewals cannot deadlock.
        let renewed: Vec<String> = if held.is_empty() {
            Vec::new()
        } else {
            self.query(
                "WITH mine AS (
                   SELECT l.session_id FROM leases l
                   JOIN unnest($2::text[], $3::bigint[]) AS u(id, token)
                     ON l.session_id = u.id AND l.token = u.token
                   WHERE l.holder_id = $1 ORDER BY l.session_id FOR UPDATE OF l
                 )
                 UPDATE leases SET expires_at = clock_timestamp() + $4 * interval '1 millisecond'
                 FROM mine WHERE leases.session_id = mine.session_id
                 RETURNING leases.session_id",
                &[
                    (&replica_id, Type::TEXT),
                    (&held_ids, Type::TEXT_ARRAY),
                    (&tokens, Type::INT8_ARRAY),
                    (&ttl, Type::INT8),
                ],
            )?
            .iter()
            .map(|r| col(r, 0))
            .collect::<Result<_, _>>()?
        };
        let mut lost = Vec::new();
        for id in ids {
            if renewed.contains(id) {
                continue;
            }
            // The token stays: this handle's writes to a lost session remain fenced.
            lost.push(id.clone());
        }
        Ok(lost)
    }

    fn release(&self, id: &str, replica_id: &str) -> Result<bool, StoreError> {
        let n = self
            .conn()?
            .execute_typed(
                "UPDATE leases SET expires_at = clock_timestamp()
                 WHERE session_id = $1 AND holder_id = $2 AND expires_at > clock_timestamp()",
                &[(&id, Type::TEXT), (&replica_id, Type::TEXT)],
            )
            .map_err(db)?;
        self.fences().remove(id);
        Ok(n > 0)
    }

    fn lease(&self, id: &str) -> Result<Option<Lease>, StoreError> {
        let mut c = self.conn()?;
        let mut tx = begin(&mut c)?;
        let exists = tx
            .query_typed_opt("SELECT 1 FROM sessions WHERE id = $1", &[(&id, Type::TEXT)])
            .map_err(db)?
            .is_some();
        if !exists {
            return Err(not_found(id));
        }
        let lease = match lease_row(&mut tx, id)? {
            Some((holder, token, true, remaining_ms)) => Some(Lease {
                holder,
                token,
                remaining_ms,
            }),
            _ => None,
        };
        tx.commit().map_err(db)?;
        Ok(lease)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(url: &str) -> Result<Target, StoreError> {
        Target::parse(url, None)
    }

    #[test]
    fn ssl_modes_are_parsed() {
        for (mode, want) in [
            ("disable", SslMode::Disable),
            ("prefer", SslMode::Prefer),
            ("require", SslMode::Require),
        ] {
            let t = parse(&format!(
                "postgres://u@db.example:6543/resecta?sslmode={mode}"
            ))
            .unwrap();
            assert_eq!(t.config.get_ssl_mode(), want);
            assert_eq!(
                t.desc,
                format!("postgres://u@db.example:6543/resecta (sslmode={mode})")
            );
        }
        let t = parse("postgresql://u@h/d").unwrap();
        assert_eq!(t.config.get_ssl_mode(), SslMode::Prefer);
        assert!(t.desc.ends_with("(sslmode=prefer)"), "{}", t.desc);
        // Other parameters still reach tokio-postgres.
        let t =
            parse("postgres://u@h/d?connect_timeout=3&sslmode=require&application_name=x").unwrap();
        assert_eq!(
            t.config.get_connect_timeout(),
            Some(&Duration::from_secs(3))
        );
        assert_eq!(t.config.get_application_name(), Some("x"));
        assert_eq!(t.config.get_ssl_mode(), SslMode::Require);
    }

    #[test]
    fn bad_urls_say_why() {
        let msg = |url: &str| parse(url).err().unwrap().to_string();
        assert!(msg("postgres://u@h/d?sslmode=allow").contains("sslmode"));
        assert!(msg("mysql://u@h/d").contains("postgres://"));
        let m = msg("postgres://u@h/d?sslmode=verify-full");
        assert!(m.contains("sslrootcert"), "{m}");
        let m = msg("postgres://u@h/d?sslmode=verify-ca&sslrootcert=/nonexistent/ca.pem");
        assert!(m.contains("/nonexistent/ca.pem"), "{m}");
        let m = msg("postgres://u@h/d?bogus=1");
        assert!(m.contains("bogus"), "{m}");
    }

    #[test]
    fn passwords_are_scrubbed() {
        assert_eq!(
            url_passwords("postgres://u:s%40cret@h:1/d"),
            ["s%40cret", "s@cret"]
        );
        assert!(url_passwords("postgres://u@h/d").is_empty());
        let t = Target::parse("postgres://u:hunter22@h/d", Some("other-secret".into())).unwrap();
        assert_eq!(t.config.get_password(), Some(&b"other-secret"[..]));
        assert!(!t.desc.contains("hunter22") && !t.desc.contains("other-secret"));
        assert_eq!(
            scrub("a hunter22 b other-secret".into(), &t.secrets),
            "a *** b ***"
        );
        // A parse error after the user info does not show it.
        let e = Target::parse("postgres://u:hunter22@h:notaport/d", None)
            .err()
            .unwrap();
        assert!(!e.to_string().contains("hunter22"), "{e}");
    }
}
