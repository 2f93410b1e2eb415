//! `resecta serve` configuration: flags override environment variables (clap reads both), which
//! override the TOML file named by `--config`, which overrides the defaults.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use resecta_auth::AccessPolicy;
use resecta_conn::ConnLimits;
use resecta_session::{ReplicaConfig, ServiceConfig};
use resecta_store::Replica;
use serde::Deserialize;

use crate::compute::GpuMode;
use crate::error::ServerError;

/// Default gRPC address (loopback).
pub const DEFAULT_GRPC: &str = "127.0.0.1:50051";
/// Default HTTP address (loopback).
pub const DEFAULT_HTTP: &str = "127.0.0.1:8080";
/// Largest configuration or token file read (bytes).
const MAX_CONFIG_FILE: u64 = 1 << 20;

/// Flags of `resecta serve` (each also read from its environment variable).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServeArgs {
    /// gRPC listen address [default: 127.0.0.1:50051; port 0 picks a free port].
    #[arg(long, env = "RESECTA_GRPC")]
    pub grpc: Option<SocketAddr>,
    /// HTTP listen address [default: 127.0.0.1:8080].
    #[arg(long, env = "RESECTA_HTTP")]
    pub http: Option<SocketAddr>,
    /// Directory of the durable session store (SQLite); sessions live in memory without it
    /// (`--store` wins over it).
    #[arg(long, env = "RESECTA_DATA_DIR")]
    pub data_dir: Option<PathBuf>,
    /// The session store: `memory`, `sqlite:DIR`, or `postgres://USER@HOST:PORT/DB` (with
    /// `?sslmode=require|verify-ca|verify-full&sslrootcert=CA.pem` for TLS) shared by replicas
    /// [default: --data-dir's SQLite, else memory; TOML `store`].
    #[arg(long, env = "RESECTA_STORE", hide_env_values = true)]
    pub store: Option<String>,
    /// File holding the database password (overrides one in the URL) [TOML
    /// `store_password_file`]; `RESECTA_STORE_PASSWORD` gives it directly.
    #[arg(long, env = "RESECTA_STORE_PASSWORD_FILE")]
    pub store_password_file: Option<PathBuf>,
    /// The database password (prefer the file).
    #[arg(
        long,
        env = "RESECTA_STORE_PASSWORD",
        hide_env_values = true,
        conflicts_with = "store_password_file"
    )]
    pub store_password: Option<String>,
    /// This replica's name among several sharing a store, unique among those running
    /// [default: the host name]; a restarted replica of the same name takes its sessions back
    /// at once. Setting it (or a PostgreSQL store) holds sessions under leases, one replica at
    /// a time.
    #[arg(long, env = "RESECTA_REPLICA_ID")]
    pub replica_id: Option<String>,
    /// `HOST:PORT` at which clients reach this replica's gRPC face [default: the host name
    /// and the gRPC port, or the listen address when it is not a wildcard].
    #[arg(long, env = "RESECTA_ADVERTISE_GRPC")]
    pub advertise_grpc: Option<String>,
    /// Base URL at which clients reach this replica's HTTP face [default as for gRPC].
    #[arg(long, env = "RESECTA_ADVERTISE_HTTP")]
    pub advertise_http: Option<String>,
    /// Milliseconds a replica's lease on a session lasts without renewal (renewed every third
    /// of it): a dead replica's sessions move after at most this long [default: 3000].
    #[arg(long, env = "RESECTA_LEASE_MS")]
    pub lease_ms: Option<u64>,
    /// Bearer token clients must send (at least 16 characters).
    #[arg(
        long,
        env = "RESECTA_TOKEN",
        hide_env_values = true,
        conflicts_with = "token_file"
    )]
    pub token: Option<String>,
    /// File holding the bearer token (e.g. a Docker secret).
    #[arg(long, env = "RESECTA_TOKEN_FILE")]
    pub token_file: Option<PathBuf>,
    /// PEM certificate chain for TLS on both faces (with --tls-key).
    #[arg(long, env = "RESECTA_TLS_CERT", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key for TLS.
    #[arg(long, env = "RESECTA_TLS_KEY", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Listen on a non-loopback address without a token (trusted networks only).
    #[arg(long, env = "RESECTA_INSECURE")]
    pub insecure: bool,
    /// Add the demo patient (a synthetic liver phantom) as a session, once per data directory.
    #[arg(long, env = "RESECTA_DEMO")]
    pub demo: bool,
    /// Logs as JSON lines (for collectors).
    #[arg(long, env = "RESECTA_LOG_JSON")]
    pub log_json: bool,
    /// TOML configuration file (limits live here).
    #[arg(long, env = "RESECTA_CONFIG")]
    pub config: Option<PathBuf>,
    /// Seconds a new connection has to carry an admitted (authenticated, with a token) request
    /// before it is closed [default: 10; TOML `[connections] handshake_timeout_s`].
    #[arg(long, value_name = "SECONDS", env = "RESECTA_HANDSHAKE_TIMEOUT")]
    pub handshake_timeout: Option<u64>,
    /// Seconds without a request in flight nor a byte either way after which a connection is
    /// closed [default: 60; TOML `[connections] idle_timeout_s`].
    #[arg(long, value_name = "SECONDS", env = "RESECTA_IDLE_TIMEOUT")]
    pub idle_timeout: Option<u64>,
    /// Where planners evaluate their surfaces: `off` (the CPU), `auto` (a hardware GPU adapter
    /// when there is one, else the CPU), `required` (any adapter, software ones included, or
    /// refuse to start) [default: off; TOML `gpu`].
    #[arg(long, value_enum, env = "RESECTA_GPU")]
    pub gpu: Option<GpuMode>,
}

/// The TOML file.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    grpc: Option<SocketAddr>,
    http: Option<SocketAddr>,
    data_dir: Option<PathBuf>,
    store: Option<String>,
    store_password_file: Option<PathBuf>,
    replica_id: Option<String>,
    advertise_grpc: Option<String>,
    advertise_http: Option<String>,
    lease_ms: Option<u64>,
    token_file: Option<PathBuf>,
    insecure: Option<bool>,
    demo: Option<bool>,
    gpu: Option<GpuMode>,
    tls: Option<TlsFiles>,
    #[serde(default)]
    limits: FileLimits,
    #[serde(default)]
    connections: FileConnections,
}

/// `[connections]`: see `resecta_conn::ConnLimits` (docs/connections.md).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConnections {
    handshake_timeout_s: Option<u64>,
    idle_timeout_s: Option<u64>,
    max_connections: Option<usize>,
    max_per_ip: Option<usize>,
    max_unauthenticated: Option<usize>,
    http2_max_concurrent_streams: Option<u32>,
    http2_max_header_list_bytes: Option<u32>,
    http2_max_pending_accept_reset_streams: Option<usize>,
}

impl FileConnections {
    /// The defaults overridden by the file, then by the flags.
    fn resolve(&self, args: &ServeArgs) -> Result<ConnLimits, ServerError> {
        let mut l = ConnLimits::default();
        let secs = Duration::from_secs;
        if let Some(s) = args.handshake_timeout.or(self.handshake_timeout_s) {
            l.handshake_timeout = secs(s);
        }
        if let Some(s) = args.idle_timeout.or(self.idle_timeout_s) {
            l.idle_timeout = secs(s);
        }
        if let Some(v) = self.max_connections {
            l.max_connections = v;
        }
        if let Some(v) = self.max_per_ip {
            l.max_per_ip = v;
        }
        if let Some(v) = self.max_unauthenticated {
            l.max_unauthenticated = v;
        }
        if let Some(v) = self.http2_max_concurrent_streams {
            l.http2_max_concurrent_streams = v;
        }
        if let Some(v) = self.http2_max_header_list_bytes {
            l.http2_max_header_list_bytes = v;
        }
        if let Some(v) = self.http2_max_pending_accept_reset_streams {
            l.http2_max_pending_accept_reset_streams = v;
        }
        l.validate()
            .map_err(|e| ServerError::Config(format!("[connections] {e}")))?;
        Ok(l)
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileLimits {
    max_sessions: Option<usize>,
    max_voxels: Option<u64>,
    max_upload_bytes: Option<u64>,
    max_memory_bytes: Option<u64>,
    /// Seconds; 0 never expires.
    idle_expiry_s: Option<u64>,
    /// Points of one ReconstructPoints cloud.
    max_cloud_points: Option<usize>,
    /// PSR depth of a ReconstructPoints cloud, 1..=10.
    max_cloud_depth: Option<u32>,
}

/// Certificate chain and key, PEM files.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsFiles {
    pub cert: PathBuf,
    pub key: PathBuf,
}

/// The session store a server uses.
#[derive(Clone, PartialEq, Eq)]
pub enum StoreSpec {
    Memory,
    Sqlite(PathBuf),
    /// A PostgreSQL URL and the password given apart from it.
    Postgres {
        url: String,
        password: Option<String>,
    },
}

// The URL may carry a password: Debug never shows it.
impl std::fmt::Debug for StoreSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Memory => f.write_str("Memory"),
            Self::Sqlite(dir) => f.debug_tuple("Sqlite").field(dir).finish(),
            Self::Postgres { .. } => f.write_str("Postgres { .. }"),
        }
    }
}

impl StoreSpec {
    fn parse(s: &str, password: Option<String>) -> Result<Self, ServerError> {
        if s == "memory" {
            Ok(Self::Memory)
        } else if let Some(dir) = s.strip_prefix("sqlite:") {
            if dir.is_empty() {
                return Err(ServerError::Config(
                    "store sqlite: needs a directory".into(),
                ));
            }
            Ok(Self::Sqlite(PathBuf::from(dir)))
        } else if s.starts_with("postgres://") || s.starts_with("postgresql://") {
            Ok(Self::Postgres {
                url: s.to_owned(),
                password,
            })
        } else {
            Err(ServerError::Config(
                "store must be `memory`, `sqlite:DIR` or a postgres:// URL".into(),
            ))
        }
    }

    /// Whether several replicas may share it.
    pub fn is_shared(&self) -> bool {
        matches!(self, Self::Postgres { .. })
    }

    /// Whether sessions outlive the process.
    pub fn is_durable(&self) -> bool {
        !matches!(self, Self::Memory)
    }
}

/// How this server runs as one replica of several sharing a store.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplicaSettings {
    /// Its name; a per-process suffix makes its id (`NAME@SUFFIX`). Names must be unique
    /// among the replicas running: a replica takes over at once the sessions that an earlier
    /// process of its name held.
    pub name: String,
    pub advertise_grpc: Option<String>,
    pub advertise_http: Option<String>,
    pub lease: Duration,
}

impl ReplicaSettings {
    /// This replica once its faces are bound at `grpc` and `http`: addresses not advertised
    /// explicitly are the bound ones, with the host name in place of a wildcard address.
    pub fn replica(&self, grpc: SocketAddr, http: SocketAddr, tls: bool) -> ReplicaConfig {
        let host = host_name();
        let reach = |a: SocketAddr| {
            if a.ip().is_unspecified() {
                format!("{host}:{}", a.port())
            } else {
                a.to_string()
            }
        };
        let scheme = if tls { "https" } else { "http" };
        ReplicaConfig {
            replica: Replica {
                id: format!(
                    "{}@{}",
                    self.name,
                    &uuid::Uuid::new_v4().simple().to_string()[..8]
                ),
                grpc: self.advertise_grpc.clone().unwrap_or_else(|| reach(grpc)),
                http: self
                    .advertise_http
                    .clone()
                    .unwrap_or_else(|| format!("{scheme}://{}", reach(http))),
            },
            lease: self.lease,
        }
    }
}

/// A resolved, validated server configuration.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    pub grpc: SocketAddr,
    pub http: SocketAddr,
    pub store: StoreSpec,
    /// Set when several replicas share the store (a PostgreSQL store, or `--replica-id`).
    pub replica: Option<ReplicaSettings>,
    pub access: AccessPolicy,
    pub tls: Option<TlsFiles>,
    pub demo: bool,
    pub log_json: bool,
    pub service: ServiceConfig,
    /// Timeouts and caps of both faces' connections.
    pub connections: ConnLimits,
    /// The compute backend asked for; [`crate::run`] sets the service's surface engine by it.
    pub gpu: GpuMode,
}

fn read_small(path: &Path, what: &str) -> Result<String, ServerError> {
    let bad = |m: String| ServerError::Config(format!("{what} {}: {m}", path.display()));
    let len = std::fs::metadata(path)
        .map_err(|e| bad(e.to_string()))?
        .len();
    if len > MAX_CONFIG_FILE {
        return Err(bad(format!("{len} bytes is larger than {MAX_CONFIG_FILE}")));
    }
    std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))
}

/// Shortest and longest session lease.
const MIN_LEASE: Duration = Duration::from_millis(300);
const MAX_LEASE: Duration = Duration::from_secs(600);

/// This machine's name (a pod's name in Kubernetes), or `localhost`.
fn host_name() -> String {
    std::env::var("HOSTNAME")
        .ok()
        .or_else(|| std::fs::read_to_string("/etc/hostname").ok())
        .map(|h| h.trim().to_owned())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".into())
}

/// Replica names appear in ids, logs and errors: 1 to 64 letters, digits and `-_.`.
fn check_replica_name(name: &str) -> Result<(), ServerError> {
    let ok = (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'));
    if ok {
        Ok(())
    } else {
        Err(ServerError::Config(
            "replica id must be 1 to 64 letters, digits or -_.".into(),
        ))
    }
}

fn parse_addr(s: &str) -> Result<SocketAddr, ServerError> {
    s.parse()
        .map_err(|e| ServerError::Config(format!("address {s:?}: {e}")))
}

impl ServerConfig {
    /// Resolves flags/environment (`args`) over the TOML file over the defaults, and checks that
    /// the server is not exposed without a token.
    pub fn resolve(args: &ServeArgs) -> Result<Self, ServerError> {
        let file: FileConfig = match &args.config {
            Some(p) => toml::from_str(&read_small(p, "config file")?)
                .map_err(|e| ServerError::Config(format!("config file {}: {e}", p.display())))?,
            None => FileConfig::default(),
        };
        let grpc = match args.grpc.or(file.grpc) {
            Some(a) => a,
            None => parse_addr(DEFAULT_GRPC)?,
        };
        let http = match args.http.or(file.http) {
            Some(a) => a,
            None => parse_addr(DEFAULT_HTTP)?,
        };
        let token = match (
            &args.token,
            args.token_file.as_ref().or(file.token_file.as_ref()),
        ) {
            (Some(t), _) => Some(t.clone()),
            (None, Some(f)) => Some(read_small(f, "token file")?),
            (None, None) => None,
        };
        let access = match token {
            Some(t) => AccessPolicy::with_token(&t)
                .map_err(|e| ServerError::Config(format!("token: {e}")))?,
            None => AccessPolicy::open(),
        };
        let insecure = args.insecure || file.insecure.unwrap_or(false);
        for addr in [grpc, http] {
            if !addr.ip().is_loopback() && !access.requires_token() && !insecure {
                return Err(ServerError::Config(format!(
                    "refusing to listen on {addr} without a bearer token: set --token or \
                     --token-file (RESECTA_TOKEN / RESECTA_TOKEN_FILE), or pass --insecure on a \
                     trusted network"
                )));
            }
        }
        if grpc.port() != 0 && grpc == http {
            return Err(ServerError::Config(format!(
                "the gRPC and HTTP faces need different addresses (both {grpc})"
            )));
        }
        let tls = match (&args.tls_cert, &args.tls_key) {
            (Some(cert), Some(key)) => Some(TlsFiles {
                cert: cert.clone(),
                key: key.clone(),
            }),
            _ => file.tls,
        };
        let connections = file.connections.resolve(args)?;
        let mut service = ServiceConfig::default();
        let l = &file.limits;
        if let Some(v) = l.max_sessions {
            service.max_sessions = v;
        }
        if let Some(v) = l.max_voxels {
            service.max_voxels = v;
        }
        if let Some(v) = l.max_upload_bytes {
            service.max_upload_bytes = v;
        }
        if let Some(v) = l.max_memory_bytes {
            service.max_memory_bytes = v;
        }
        if let Some(s) = l.idle_expiry_s {
            service.idle_expiry = (s > 0).then(|| Duration::from_secs(s));
        }
        if let Some(v) = l.max_cloud_points {
            service.max_cloud_points = v;
        }
        if let Some(v) = l.max_cloud_depth {
            let depths = resecta_session::api::PSR_DEPTHS;
            if !depths.contains(&v) {
                return Err(ServerError::Config(format!(
                    "[limits] max_cloud_depth {v} is outside {}..={}",
                    depths.start(),
                    depths.end()
                )));
            }
            service.max_cloud_depth = v;
        }
        if access.requires_token() {
            service.capabilities.push("auth".into());
        }
        if tls.is_some() {
            service.capabilities.push("tls".into());
        }
        let password = match (
            &args.store_password,
            args.store_password_file
                .as_ref()
                .or(file.store_password_file.as_ref()),
        ) {
            (Some(p), _) => Some(p.clone()),
            (None, Some(f)) => Some(read_small(f, "store password file")?.trim_end().to_owned()),
            (None, None) => None,
        };
        let store = match args.store.as_ref().or(file.store.as_ref()) {
            Some(s) => StoreSpec::parse(s, password)?,
            None => match args.data_dir.clone().or(file.data_dir) {
                Some(dir) => StoreSpec::Sqlite(dir),
                None => StoreSpec::Memory,
            },
        };
        let replica_name = args.replica_id.clone().or(file.replica_id);
        let replica = if store.is_shared() || replica_name.is_some() {
            let lease = Duration::from_millis(args.lease_ms.or(file.lease_ms).unwrap_or(
                u64::try_from(ReplicaConfig::DEFAULT_LEASE.as_millis()).unwrap_or(3000),
            ));
            if !(MIN_LEASE..=MAX_LEASE).contains(&lease) {
                return Err(ServerError::Config(format!(
                    "lease of {} ms is outside {}..={} ms",
                    lease.as_millis(),
                    MIN_LEASE.as_millis(),
                    MAX_LEASE.as_millis()
                )));
            }
            let name = replica_name.unwrap_or_else(host_name);
            check_replica_name(&name)?;
            service.capabilities.push("replicas".into());
            Some(ReplicaSettings {
                name,
                advertise_grpc: args.advertise_grpc.clone().or(file.advertise_grpc),
                advertise_http: args.advertise_http.clone().or(file.advertise_http),
                lease,
            })
        } else {
            None
        };
        Ok(Self {
            grpc,
            http,
            store,
            replica,
            access,
            tls,
            demo: args.demo || file.demo.unwrap_or(false),
            log_json: args.log_json,
            service,
            connections,
            gpu: args.gpu.or(file.gpu).unwrap_or_default(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn defaults_are_loopback_without_token() {
        let c = ServerConfig::resolve(&ServeArgs::default()).unwrap();
        assert_eq!(c.grpc.to_string(), DEFAULT_GRPC);
        assert_eq!(c.http.to_string(), DEFAULT_HTTP);
        assert!(!c.access.requires_token());
        assert!(c.store == StoreSpec::Memory && c.tls.is_none());
    }

    #[test]
    fn exposed_address_needs_a_token_or_insecure() {
        let mut a = ServeArgs {
            grpc: Some("0.0.0.0:50051".parse().unwrap()),
            ..ServeArgs::default()
        };
        let e = ServerConfig::resolve(&a).unwrap_err().to_string();
        assert!(e.contains("refusing to listen on 0.0.0.0:50051"), "{e}");
        a.insecure = true;
        assert!(ServerConfig::resolve(&a).is_ok());
        a.insecure = false;
        a.token = Some("short".into());
        let e = ServerConfig::resolve(&a).unwrap_err().to_string();
        assert!(e.contains("at least 16"), "{e}");
        a.token = Some("a-long-enough-token-1234".into());
        let c = ServerConfig::resolve(&a).unwrap();
        assert!(c.access.requires_token());
        assert!(c.service.capabilities.contains(&"auth".to_owned()));
    }

    #[test]
    fn flags_override_the_file_which_overrides_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let token = write(dir.path(), "token", "file-token-0123456789\n");
        let cfg = write(
            dir.path(),
            "c.toml",
            &format!(
                "grpc = \"0.0.0.0:6000\"\nhttp = \"127.0.0.1:6001\"\ntoken_file = {:?}\n\
                 [limits]\nmax_sessions = 3\nidle_expiry_s = 0\n",
                token.display().to_string()
            ),
        );
        let args = ServeArgs {
            config: Some(cfg),
            http: Some("127.0.0.1:7001".parse().unwrap()),
            ..ServeArgs::default()
        };
        let c = ServerConfig::resolve(&args).unwrap();
        assert_eq!(c.grpc.to_string(), "0.0.0.0:6000");
        assert_eq!(c.http.to_string(), "127.0.0.1:7001");
        assert!(c.access.requires_token());
        assert_eq!(
            c.access
                .check_authorization(Some("Bearer file-token-0123456789")),
            Ok(())
        );
        assert_eq!(c.service.max_sessions, 3);
        assert_eq!(c.service.idle_expiry, None);
    }

    #[test]
    fn point_cloud_limits_come_from_the_file_and_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let config = |text: &str| ServeArgs {
            config: Some(write(dir.path(), "c.toml", text)),
            ..ServeArgs::default()
        };
        let d = ServerConfig::resolve(&ServeArgs::default())
            .unwrap()
            .service;
        assert_eq!((d.max_cloud_points, d.max_cloud_depth), (1_000_000, 8));
        let c = ServerConfig::resolve(&config(
            "[limits]\nmax_cloud_points = 5000\nmax_cloud_depth = 6\n",
        ))
        .unwrap()
        .service;
        assert_eq!((c.max_cloud_points, c.max_cloud_depth), (5000, 6));
        for depth in [0, 11] {
            let e =
                ServerConfig::resolve(&config(&format!("[limits]\nmax_cloud_depth = {depth}\n")))
                    .unwrap_err()
                    .to_string();
            assert!(e.contains("max_cloud_depth") && e.contains("1..=10"), "{e}");
        }
    }

    #[test]
    fn connection_limits_from_file_and_flags_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = write(
            dir.path(),
            "c.toml",
            "[connections]\nhandshake_timeout_s = 3\nidle_timeout_s = 20\nmax_unauthenticated = 8\n\
             max_per_ip = 16\nhttp2_max_concurrent_streams = 50\n",
        );
        let mut args = ServeArgs {
            config: Some(cfg),
            ..ServeArgs::default()
        };
        let c = ServerConfig::resolve(&args).unwrap().connections;
        assert_eq!(c.handshake_timeout, Duration::from_secs(3));
        assert_eq!(c.idle_timeout, Duration::from_secs(20));
        assert_eq!((c.max_unauthenticated, c.max_per_ip), (8, 16));
        assert_eq!(c.http2_max_concurrent_streams, 50);
        assert_eq!(c.max_connections, ConnLimits::default().max_connections);
        args.idle_timeout = Some(90);
        let c = ServerConfig::resolve(&args).unwrap().connections;
        assert_eq!(c.idle_timeout, Duration::from_secs(90));
        assert_eq!(c.handshake_timeout, Duration::from_secs(3));
        args.handshake_timeout = Some(0);
        let e = ServerConfig::resolve(&args).unwrap_err().to_string();
        assert!(
            e.contains("[connections] handshake_timeout_s must be more than 0"),
            "{e}"
        );
        // Defaults without a file.
        let d = ServerConfig::resolve(&ServeArgs::default())
            .unwrap()
            .connections;
        assert_eq!(d, ConnLimits::default());
        for (text, key) in [
            (
                "[connections]\nmax_per_ip = 0\n",
                "max_per_ip must be at least 1",
            ),
            ("[connections]\nidle_timout_s = 5\n", "idle_timout_s"),
        ] {
            let args = ServeArgs {
                config: Some(write(dir.path(), "bad.toml", text)),
                ..ServeArgs::default()
            };
            let e = ServerConfig::resolve(&args).unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
        }
    }

    #[test]
    fn bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = write(
            dir.path(),
            "c.toml",
            "grpc = \"127.0.0.1:1\"\nmax_sesions = 3\n",
        );
        let args = ServeArgs {
            config: Some(cfg),
            ..ServeArgs::default()
        };
        let e = ServerConfig::resolve(&args).unwrap_err().to_string();
        assert!(e.contains("c.toml") && e.contains("max_sesions"), "{e}");
        let args = ServeArgs {
            config: Some(dir.path().join("missing.toml")),
            ..ServeArgs::default()
        };
        assert!(ServerConfig::resolve(&args).is_err());
        let args = ServeArgs {
            grpc: Some("127.0.0.1:7000".parse().unwrap()),
            http: Some("127.0.0.1:7000".parse().unwrap()),
            ..ServeArgs::default()
        };
        assert!(ServerConfig::resolve(&args).is_err());
    }

    #[test]
    fn the_gpu_mode_comes_from_the_flag_over_the_file_and_is_off_by_default() {
        assert_eq!(
            ServerConfig::resolve(&ServeArgs::default()).unwrap().gpu,
            GpuMode::Off
        );
        let dir = tempfile::tempdir().unwrap();
        let cfg = write(dir.path(), "c.toml", "gpu = \"auto\"\n");
        let mut args = ServeArgs {
            config: Some(cfg),
            ..ServeArgs::default()
        };
        assert_eq!(ServerConfig::resolve(&args).unwrap().gpu, GpuMode::Auto);
        args.gpu = Some(GpuMode::Required);
        assert_eq!(ServerConfig::resolve(&args).unwrap().gpu, GpuMode::Required);
        let bad = write(dir.path(), "bad.toml", "gpu = \"maybe\"\n");
        let e = ServerConfig::resolve(&ServeArgs {
            config: Some(bad),
            ..ServeArgs::default()
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("gpu"), "{e}");
    }

    #[test]
    fn gpu_off_leaves_the_cpu_engine_and_its_report() {
        let mut service = ServiceConfig::default();
        crate::configure_compute(GpuMode::Off, &mut service).unwrap();
        assert_eq!(service.compute_engine.backend(), "cpu");
        assert_eq!(service.compute.backend, "cpu");
        assert!(!service.capabilities.contains(&"gpu".to_owned()));
    }
}
