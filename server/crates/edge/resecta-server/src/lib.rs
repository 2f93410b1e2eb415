//! The planning server process (`resecta serve`): one [`resecta_session::Service`] over the
//! configured store, served on two faces — gRPC ([`resecta_grpc`]) and HTTP/JSON
//! ([`resecta_http`]) — with the same access policy, optional TLS on both, Prometheus metrics,
//! request tracing, idle-session expiry, connection hygiene ([`resecta_conn`]: handshake and idle
//! timeouts, connection caps, HTTP/2 limits), the compute backend (`--gpu`: the sessions'
//! surfaces on a GPU through `resecta-gpu`'s engine) and, on request, the demo patient. No
//! algorithm lives here: this crate wires listeners to the operation layer.

mod compute;
mod config;
mod demo;
mod error;
mod telemetry;

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum_server::accept::DefaultAcceptor;
use resecta_conn::{Admission, AdmitOn, ConnAcceptor, ConnIncoming, ConnLayer, ConnLimits};
use resecta_session::Service;
use resecta_store::{MemoryStore, PostgresStore, SessionStore, SqliteStore, StoreOptions};
use serde::Serialize;
use tokio::sync::watch;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;

pub use compute::{GpuMode, configure_compute};
pub use config::{
    DEFAULT_GRPC, DEFAULT_HTTP, ReplicaSettings, ServeArgs, ServerConfig, StoreSpec, TlsFiles,
};
pub use demo::{DEMO_SESSION_NAME, seed_demo};
pub use error::ServerError;
pub use telemetry::{init_tracing, metrics_handle};

/// Where the faces listen, as printed on start-up.
#[derive(Debug, Clone, Serialize)]
pub struct Bound {
    pub grpc: SocketAddr,
    pub http: SocketAddr,
    pub tls: bool,
    /// The browser client's address (on this machine when the HTTP face listens on every
    /// interface).
    pub page: String,
}

/// The page's URL on the HTTP face at `http`.
fn page_url(http: SocketAddr, tls: bool) -> String {
    let mut at = http;
    if at.ip().is_unspecified() {
        at.set_ip(if at.is_ipv4() {
            std::net::Ipv4Addr::LOCALHOST.into()
        } else {
            std::net::Ipv6Addr::LOCALHOST.into()
        });
    }
    format!("{}://{at}/", if tls { "https" } else { "http" })
}

/// The session store the configuration names.
pub fn open_store(config: &ServerConfig) -> Result<Arc<dyn SessionStore>, ServerError> {
    Ok(match &config.store {
        StoreSpec::Sqlite(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| {
                ServerError::Config(format!("data directory {}: {e}", dir.display()))
            })?;
            Arc::new(SqliteStore::open(dir, StoreOptions::default())?)
        }
        StoreSpec::Postgres { url, password } => Arc::new(PostgresStore::open(
            url,
            password.clone(),
            StoreOptions::default(),
        )?),
        StoreSpec::Memory => Arc::new(MemoryStore::new(StoreOptions::default())),
    })
}

async fn bind(addr: SocketAddr) -> Result<tokio::net::TcpListener, ServerError> {
    tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| ServerError::Bind { addr, source })
}

fn serve_error(face: &'static str) -> impl Fn(String) -> ServerError {
    move |message| ServerError::Serve { face, message }
}

/// Runs the server until `shutdown` completes: binds both faces, calls `on_bound` with their
/// addresses, serves, and drains in-flight requests on the way out.
pub async fn run(
    config: ServerConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
    on_bound: impl FnOnce(Bound),
) -> Result<(), ServerError> {
    let tls = match &config.tls {
        Some(files) => Some(telemetry::load_tls(files).await?),
        None => None,
    };
    let grpc_listener = bind(config.grpc).await?;
    let http_listener = bind(config.http).await?;
    let local = |l: &tokio::net::TcpListener, addr| {
        l.local_addr()
            .map_err(|source| ServerError::Bind { addr, source })
    };
    let http_at = local(&http_listener, config.http)?;
    let bound = Bound {
        grpc: local(&grpc_listener, config.grpc)?,
        http: http_at,
        tls: tls.is_some(),
        page: page_url(http_at, tls.is_some()),
    };

    let mut service_config = config.service.clone();
    configure_compute(config.gpu, &mut service_config)?;
    service_config.replica = config
        .replica
        .as_ref()
        .map(|r| r.replica(bound.grpc, bound.http, bound.tls));
    // The PostgreSQL driver runs its own runtime per connection: opened off this one.
    let opened = {
        let config = config.clone();
        tokio::task::spawn_blocking(move || open_store(&config))
            .await
            .map_err(|e| ServerError::Config(format!("opening the store: {e}")))??
    };
    let service = Arc::new(Service::new(opened, service_config));
    // Stored sessions come back while the faces start: most recently used first.
    service.restore_in_background();

    // Connections of both faces: admitted by an authenticated request (any request without a
    // token), timed out and capped together.
    let limits = &config.connections;
    let admit_on = if config.access.requires_token() {
        AdmitOn::Authenticated
    } else {
        AdmitOn::AnyRequest
    };
    let admission = Admission::start(limits.clone(), admit_on);

    let (stop_tx, stop_rx) = watch::channel(false);
    let stopped = move |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };

    // gRPC face. Keep-alive pings keep live connections from looking idle (they are bytes);
    // without a stream limit tonic would leave HTTP/2 streams per connection unbounded.
    let mut builder = tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(limits.http2_keepalive_interval()))
        .max_concurrent_streams(limits.http2_max_concurrent_streams)
        .http2_max_header_list_size(limits.http2_max_header_list_bytes)
        .http2_max_pending_accept_reset_streams(Some(limits.http2_max_pending_accept_reset_streams))
        .http2_max_local_error_reset_streams(Some(MAX_LOCAL_ERROR_RESET_STREAMS));
    if let Some(t) = &tls {
        builder = builder
            .tls_config(t.grpc.clone().timeout(limits.handshake_timeout))
            .map_err(|e| ServerError::Tls(e.to_string()))?;
    }
    // Watch and Reconstruct streams end with UNAVAILABLE on shutdown: tonic's graceful
    // shutdown waits for every open call, and a watch never ends by itself.
    let routes = resecta_grpc::grpc_routes_until(
        Arc::clone(&service),
        config.access.clone(),
        stop_rx.clone(),
    );
    // Small messages (edit answers, deltas of small surfaces) must not wait for Nagle's delayed
    // ACK: 40 ms per edit otherwise.
    let incoming = ConnIncoming::new(
        tonic::transport::server::TcpIncoming::from(grpc_listener).with_nodelay(Some(true)),
        Arc::clone(&admission),
        "grpc",
    );
    // Request ids: the client's `x-request-id` (if sane) or a new one, echoed in the response
    // metadata and carried by the call's log span, as on the HTTP face.
    let layers = tower::ServiceBuilder::new()
        // Each call counts in flight on its connection (and admits it when there is no token).
        .layer(ConnLayer)
        .map_request(telemetry::sane_request_id)
        .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
        .layer(PropagateRequestIdLayer::x_request_id())
        .layer(
            TraceLayer::new_for_grpc()
                .make_span_with(telemetry::grpc_span)
                .on_response(telemetry::grpc_response)
                // Client errors are logged once, with their status, by `grpc_response`.
                .on_failure(()),
        );
    let grpc = tokio::spawn(
        builder
            .layer(layers)
            .add_routes(routes)
            .serve_with_incoming_shutdown(incoming, stopped(stop_rx.clone())),
    );

    // HTTP face.
    let render = metrics_handle().map(|h| {
        let f: Arc<dyn Fn() -> String + Send + Sync> = Arc::new(move || h.render());
        f
    });
    let router = resecta_http::router(
        Arc::clone(&service),
        config.access.clone(),
        resecta_http::HttpOptions {
            metrics: render,
            shutdown: Some(stop_rx.clone()),
            // Keep-alive comments keep open event streams from looking idle.
            keep_alive: limits.sse_keepalive_interval(),
            ..resecta_http::HttpOptions::default()
        },
    );
    let handle = axum_server::Handle::new();
    let std_listener = http_listener
        .into_std()
        .map_err(|source| ServerError::Bind {
            addr: bound.http,
            source,
        })?;
    let app = router.into_make_service();
    let server = axum_server::from_tcp(std_listener).map_err(|source| ServerError::Bind {
        addr: bound.http,
        source,
    })?;
    // The connection acceptor sets TCP_NODELAY, below TLS when there is TLS.
    let http = match &tls {
        Some(t) => {
            let tls = axum_server::tls_rustls::RustlsAcceptor::new(t.http.clone())
                .handshake_timeout(limits.handshake_timeout)
                .acceptor(DefaultAcceptor::new());
            let mut server = server
                .acceptor(ConnAcceptor::new(tls, Arc::clone(&admission), "http"))
                .handle(handle.clone());
            http_limits(server.http_builder(), limits);
            tokio::spawn(async move { server.serve(app).await })
        }
        None => {
            let acceptor = DefaultAcceptor::new();
            let mut server = server
                .acceptor(ConnAcceptor::new(acceptor, Arc::clone(&admission), "http"))
                .handle(handle.clone());
            http_limits(server.http_builder(), limits);
            tokio::spawn(async move { server.serve(app).await })
        }
    };

    // Upkeep: idle expiry and the metrics exporter's histograms; session leases (replicas),
    // renewed until they are released after the faces have drained.
    let upkeep = tokio::spawn(upkeep(Arc::clone(&service), stop_rx.clone()));
    let leases = service
        .replica()
        .map(|r| tokio::spawn(keep_leases(Arc::clone(&service), r.lease / 3)));
    if config.demo {
        let s = Arc::clone(&service);
        tokio::spawn(async move {
            match seed_demo(&s).await {
                Ok(id) => tracing::info!(session = %id, "demo patient ready"),
                Err(e) => tracing::error!(error = %e, "demo patient failed"),
            }
        });
    }
    if let Some(r) = service.replica() {
        tracing::info!(replica = %r.replica.id, grpc = %r.replica.grpc, http = %r.replica.http,
            lease_ms = r.lease.as_millis() as u64, "replica of a shared store");
    }
    tracing::info!(grpc = %bound.grpc, http = %bound.http, tls = bound.tls, page = %bound.page,
        auth = config.access.requires_token(), durable = config.store.is_durable(),
        handshake_timeout_s = limits.handshake_timeout.as_secs_f64(),
        idle_timeout_s = limits.idle_timeout.as_secs_f64(), "listening");
    on_bound(bound);

    shutdown.await;
    tracing::info!("shutting down");
    service.begin_drain();
    // Streams end now (UNAVAILABLE / an `error` event), new connections are refused, and
    // in-flight unary calls get up to SHUTDOWN_GRACE to finish; then the faces are dropped.
    let _ = stop_tx.send(true);
    handle.graceful_shutdown(Some(SHUTDOWN_GRACE));
    let grpc = drain("gRPC", grpc).await?;
    let http = drain("HTTP", http).await?;
    upkeep.abort();
    if let Some(leases) = leases {
        // Calls have ended: other replicas may take the sessions over at once.
        match service.release_leases().await {
            Ok(n) => tracing::info!(sessions = n, "session leases released"),
            Err(e) => tracing::warn!(error = %e, "releasing session leases"),
        }
        leases.abort();
    }
    if let Some(grpc) = grpc {
        grpc.map_err(|e| serve_error("gRPC")(e.to_string()))?;
    }
    if let Some(http) = http {
        http.map_err(|e| serve_error("HTTP")(e.to_string()))?;
    }
    tracing::info!("stopped");
    Ok(())
}

/// HTTP/2 streams a client may make the server reset (malformed frames) before the connection
/// is closed: hyper's default, which tonic leaves unset (unbounded).
const MAX_LOCAL_ERROR_RESET_STREAMS: usize = 1024;

/// The HTTP face's protocol limits: HTTP/2 streams and headers as on the gRPC face, and every
/// HTTP/1 request head must be complete within the idle timeout of the connection being ready
/// for it (the first one also within the handshake timeout), however slowly its bytes trickle.
fn http_limits(
    builder: &mut hyper_util::server::conn::auto::Builder<hyper_util::rt::TokioExecutor>,
    limits: &ConnLimits,
) {
    builder
        .http1()
        .header_read_timeout(limits.idle_timeout)
        .http2()
        .max_concurrent_streams(limits.http2_max_concurrent_streams)
        .max_header_list_size(limits.http2_max_header_list_bytes)
        .max_pending_accept_reset_streams(limits.http2_max_pending_accept_reset_streams)
        .max_local_error_reset_streams(MAX_LOCAL_ERROR_RESET_STREAMS);
}

/// How long graceful shutdown waits for in-flight calls once streams have been ended.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// The face's outcome once it has drained, or `None` (logged) when it did not drain within
/// [`SHUTDOWN_GRACE`] and was dropped: a shutdown never hangs on a stuck call.
async fn drain<T>(
    face: &'static str,
    mut task: tokio::task::JoinHandle<T>,
) -> Result<Option<T>, ServerError> {
    // A little longer than the HTTP face's own grace, which closes its connections itself.
    match tokio::time::timeout(SHUTDOWN_GRACE + Duration::from_millis(500), &mut task).await {
        Ok(joined) => joined
            .map(Some)
            .map_err(|e| serve_error(face)(e.to_string())),
        Err(_) => {
            task.abort();
            tracing::warn!(
                face,
                grace_s = SHUTDOWN_GRACE.as_secs(),
                "calls still open after the shutdown grace period were dropped"
            );
            Ok(None)
        }
    }
}

/// Renews this replica's session leases every `period` (a third of the lease) until aborted.
async fn keep_leases(service: Arc<Service>, period: Duration) {
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        match service.renew_leases().await {
            Ok(0) => {}
            Ok(n) => tracing::warn!(sessions = n, "session leases lost to other replicas"),
            Err(e) => tracing::warn!(error = %e, "renewing session leases"),
        }
    }
}

async fn upkeep(service: Arc<Service>, mut stop: watch::Receiver<bool>) {
    let expiry = service.config().idle_expiry;
    let period = expiry.map_or(Duration::from_secs(60), |e| {
        (e / 4).clamp(Duration::from_secs(1), Duration::from_secs(60))
    });
    let mut tick = tokio::time::interval(period.min(Duration::from_secs(5)));
    let mut since_expiry = Duration::ZERO;
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stop.wait_for(|s| *s) => return,
        }
        if let Some(h) = metrics_handle() {
            h.run_upkeep();
        }
        since_expiry += tick.period();
        if expiry.is_some() && since_expiry >= period {
            since_expiry = Duration::ZERO;
            match service.expire_idle().await {
                Ok(0) => {}
                Ok(n) => tracing::info!(sessions = n, "idle sessions expired"),
                Err(e) => tracing::warn!(error = %e, "idle expiry failed"),
            }
        }
    }
}

/// Completes on Ctrl-C or SIGTERM.
pub async fn termination_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {}
        () = term => {}
    }
}
