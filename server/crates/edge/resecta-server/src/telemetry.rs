//! Logs, metrics and TLS material of the process.

use std::sync::OnceLock;
use std::time::Duration;

use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};
use tracing_subscriber::EnvFilter;

use crate::config::TlsFiles;
use crate::error::ServerError;

/// The GPU stack's crates, which log every driver call at debug: kept at `warn` unless
/// `RUST_LOG` names them.
const GPU_STACK: [&str; 3] = ["wgpu_hal", "wgpu_core", "naga"];

/// Logs to stderr, filtered by `RUST_LOG` (default `info`; the GPU stack at `warn` unless it
/// names them), as text or JSON lines.
pub fn init_tracing(json: bool) {
    let wanted = std::env::var("RUST_LOG").unwrap_or_default();
    let mut filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    for name in GPU_STACK.iter().filter(|n| !wanted.contains(*n)) {
        if let Ok(directive) = format!("{name}=warn").parse() {
            filter = filter.add_directive(directive);
        }
    }
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false);
    // A second initialisation (tests) keeps the first subscriber.
    let _ = if json {
        fmt.json().try_init()
    } else {
        fmt.try_init()
    };
}

/// Latency buckets (seconds) for the edit and volumetry histograms: 0.25 ms … 5 s.
const BUCKETS: &[f64] = &[
    0.000_25, 0.000_5, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0,
];

/// The process-wide Prometheus recorder, installed on first use (`None` if another recorder
/// was installed first).
pub fn metrics_handle() -> Option<&'static PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            PrometheusBuilder::new()
                .set_buckets_for_metric(Matcher::Suffix("_seconds".into()), BUCKETS)
                .ok()?
                .install_recorder()
                .ok()
        })
        .as_ref()
}

/// The tracing span of one gRPC call: method and request id (set by the request-id layer from
/// the client's `x-request-id`, or new). Never request contents, and a path only when it names
/// a method the server serves (a path is the client's text).
pub fn grpc_span<B>(req: &http::Request<B>) -> tracing::Span {
    let id = req
        .headers()
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("-");
    let method = resecta_grpc::error::method_for_logs(req.uri().path());
    tracing::info_span!("grpc", method, request_id = %id)
}

/// Logs the end of a gRPC call's response head: its status (`ok` when it comes in the
/// trailers, as for successful calls) and latency.
pub fn grpc_response<B>(res: &http::Response<B>, latency: Duration, _span: &tracing::Span) {
    let status = res
        .headers()
        .get("grpc-status")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("ok");
    tracing::info!(
        grpc_status = status,
        latency_ms = latency.as_secs_f64() * 1e3,
        "response"
    );
}

/// A client's `x-request-id` when it is short printable ASCII; otherwise the layer makes one.
pub fn sane_request_id<B>(mut req: http::Request<B>) -> http::Request<B> {
    let ok = req
        .headers()
        .get("x-request-id")
        .is_some_and(|v| v.len() <= 64 && v.as_bytes().iter().all(|b| b.is_ascii_graphic()));
    if !ok {
        req.headers_mut().remove("x-request-id");
    }
    req
}

/// TLS set-up of both faces from one certificate chain and key.
#[derive(Clone)]
pub(crate) struct LoadedTls {
    pub grpc: tonic::transport::ServerTlsConfig,
    pub http: axum_server::tls_rustls::RustlsConfig,
}

pub(crate) async fn load_tls(files: &TlsFiles) -> Result<LoadedTls, ServerError> {
    let _ = rustls::crypto::ring::default_provider().install_default();
    let read = |p: &std::path::Path| {
        std::fs::read(p).map_err(|e| ServerError::Tls(format!("{}: {e}", p.display())))
    };
    let cert = read(&files.cert)?;
    let key = read(&files.key)?;
    let http = axum_server::tls_rustls::RustlsConfig::from_pem(cert.clone(), key.clone())
        .await
        .map_err(|e| {
            ServerError::Tls(format!(
                "certificate {} / key {}: {e}",
                files.cert.display(),
                files.key.display()
            ))
        })?;
    let grpc = tonic::transport::ServerTlsConfig::new()
        .identity(tonic::transport::Identity::from_pem(cert, key));
    Ok(LoadedTls { grpc, http })
}
