//! The HTTP/JSON face of the planning server: every RPC of `resecta.v1.PlanningService` as a
//! route under `/v1/`, whose bodies are that RPC's messages in the canonical protobuf JSON mapping
//! (`resecta_api`'s pbjson serde impls) and whose requests reach [`resecta_session::Service`]
//! through the conversions the gRPC face uses too (`resecta-face`), so both faces are one API.
//! The session id comes from the path; the rest of a POST/PUT body is exactly the request
//! message's JSON, and the fields of a GET route's request message are its query parameters.
//! Streamed answers are server-sent events whose data are the streamed messages; errors are
//! RFC 9457 problem documents; the OpenAPI 3.1 document at `GET /v1/openapi.json` is generated
//! from the route table and the descriptors.
//!
//! [`router`] builds the whole face; the server process binds it (plain or TLS). Every `/v1/`
//! route but `GET /v1/info` and `GET /v1/openapi.json` passes the [`AccessPolicy`] (bearer token
//! and `resecta-api-version`); `/healthz`, `/readyz` and `/metrics` are open. Every response carries an
//! `x-request-id` (the client's, or a fresh UUID), and every request is traced (method, matched
//! route, status, latency, request id) and counted in `resecta_http_requests_total{route,status}`.
//! Bodies, display names and file names are never logged.
//!
//! | route | RPC | body / query → answer |
//! |---|---|---|
//! | `GET /`, `GET /app.js`, … | — | the browser client ([`resecta_web`]: every file of its bundle) |
//! | `GET /healthz`, `GET /readyz`, `GET /metrics` | — | liveness; readiness (503 while draining or when the store does not answer); Prometheus text (when [`HttpOptions::metrics`]) |
//! | `GET /v1/openapi.json` | — | the OpenAPI document |
//! | `GET /v1/info` | `GetServerInfo` | → `GetServerInfoResponse` |
//! | `POST /v1/sessions` | `CreateSession` | `CreateSessionRequest` → 201 `CreateSessionResponse` |
//! | `GET /v1/sessions` | `ListSessions` | → `ListSessionsResponse` |
//! | `GET`, `DELETE /v1/sessions/{id}` | `GetSession`, `DeleteSession` | → `GetSessionResponse`, `DeleteSessionResponse` |
//! | `PUT /v1/sessions/{id}/label-map?raw=…` / `?file=…` | `UploadLabelMap` | header JSON in the query, the data as the body → `UploadLabelMapResponse` |
//! | `POST /v1/sessions/{id}/reconstruct` | `Reconstruct` | `ReconstructRequest` → SSE of `ReconstructResponse` (`progress`, `model`, `done`); disconnecting cancels |
//! | `POST /v1/sessions/{id}/edits` | `Edit` | `EditRequest` → `EditResponse` |
//! | `GET /v1/sessions/{id}/volumes` | `GetVolumes` | → `GetVolumesResponse` |
//! | `GET`, `PUT /v1/sessions/{id}/plan` | `ExportPlan`, `ImportPlan` | → `ExportPlanResponse`; `ImportPlanRequest` → `ImportPlanResponse` |
//! | `GET /v1/sessions/{id}/models/{name}?format=MODEL_FORMAT_VTP` | `ExportModel` | → the mesh file as the body |
//! | `GET /v1/sessions/{id}/slices?resection=…&axial=…` | `GetSlices` | → `GetSlicesResponse` |
//! | `GET /v1/sessions/{id}/label-slice?axis=…&positionMm=…` | `GetLabelSlice` | → `GetLabelSliceResponse` |
//! | `GET /v1/sessions/{id}/resectogram?resection=…&width=…&height=…` | `GetResectogram` | → `GetResectogramResponse` |
//! | `GET /v1/sessions/{id}/risk-map` | `GetRiskMap` | → `GetRiskMapResponse` |
//! | `POST /v1/point-clouds/reconstruct` | `ReconstructPoints` | `ReconstructPointsRequest` → `ReconstructPointsResponse` (no session) |
//! | `GET /v1/sessions/{id}/watch?sinceSeq=…` | `Watch` | → SSE of `WatchResponse` (`snapshot`, `delta`, `volumes`), `id` = seq, `Last-Event-ID` resumes |
//!
//! Errors map [`resecta_session::ErrorKind`] and `resecta_face::WireError` once (see
//! [`Problem`]): 400, 404, 409 (exists, stale version with `current_version`, precondition),
//! resource exhausted 413 when it answers an upload (bytes, voxels, the memory they need) and 429
//! otherwise (sessions, resections), 499 cancelled, 500 internal, 501 unsupported; 401 with
//! `WWW-Authenticate: Bearer`; 400 `API_VERSION_MISMATCH`. Bodies over their limit (JSON
//! [`MAX_JSON_BYTES`], uploads `max_upload_bytes`) get 413 from `Content-Length` before any byte
//! is read, or as soon as a chunked body passes the limit.

mod extract;
mod handlers;
mod openapi;
mod problem;
mod proto;
mod wire;

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::{MatchedPath, Request, State};
use axum::handler::Handler;
use axum::http::{HeaderName, Method, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{MethodFilter, MethodRouter, on};
use resecta_auth::{API_VERSION_HEADER, AccessPolicy};
use resecta_session::Service;
use tower::ServiceBuilder;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;
use tracing::Span;

pub use openapi::document_text as openapi_document;
pub use problem::{PROBLEM_JSON, Problem};

/// Renders the process' Prometheus metrics (text exposition format).
pub type MetricsRender = Arc<dyn Fn() -> String + Send + Sync>;

/// JSON request bodies, at most (docs/server.md: 16 MiB).
pub const MAX_JSON_BYTES: u64 = 16 << 20;

/// Request ids longer than this, or not printable ASCII, are replaced by a fresh one.
const MAX_REQUEST_ID: usize = 64;

const X_REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// Options of the HTTP face. Label-map uploads are bounded by the service's
/// `ServiceConfig::max_upload_bytes`.
#[derive(Clone)]
pub struct HttpOptions {
    /// Served at `GET /metrics` when present (else that route does not exist).
    pub metrics: Option<MetricsRender>,
    /// Largest JSON body (edits, sessions, plan documents), bytes.
    pub max_json_bytes: u64,
    /// Interval of the keep-alive comments on server-sent event streams.
    pub keep_alive: Duration,
    /// The server's shutdown signal (`true`: shutting down; a dropped sender counts too). Open
    /// server-sent event streams (watch, reconstruct) then end with an `error` event holding a
    /// 503 `UNAVAILABLE` problem, so that graceful shutdown does not wait for them. `None`:
    /// streams end only by themselves.
    pub shutdown: Option<tokio::sync::watch::Receiver<bool>>,
}

impl Default for HttpOptions {
    fn default() -> Self {
        Self {
            metrics: None,
            max_json_bytes: MAX_JSON_BYTES,
            keep_alive: Duration::from_secs(15),
            shutdown: None,
        }
    }
}

impl std::fmt::Debug for HttpOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HttpOptions")
            .field("metrics", &self.metrics.is_some())
            .field("max_json_bytes", &self.max_json_bytes)
            .field("keep_alive", &self.keep_alive)
            .field("shutdown", &self.shutdown.is_some())
            .finish()
    }
}

/// What the handlers share.
#[derive(Clone)]
struct App {
    service: Arc<Service>,
    metrics: Option<MetricsRender>,
    max_json_bytes: u64,
    keep_alive: Duration,
    shutdown: Option<tokio::sync::watch::Receiver<bool>>,
}

/// The methods the face uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verb {
    Get,
    Post,
    Put,
    Delete,
}

impl Verb {
    fn filter(self) -> MethodFilter {
        match self {
            Self::Get => MethodFilter::GET,
            Self::Post => MethodFilter::POST,
            Self::Put => MethodFilter::PUT,
            Self::Delete => MethodFilter::DELETE,
        }
    }

    fn method(self) -> Method {
        match self {
            Self::Get => Method::GET,
            Self::Post => Method::POST,
            Self::Put => Method::PUT,
            Self::Delete => Method::DELETE,
        }
    }
}

const METRICS_PATH: &str = "/metrics";

/// One row of the route table.
struct Route {
    verb: Verb,
    path: &'static str,
    /// Passes the access policy.
    guarded: bool,
    /// The `PlanningService` RPC the route is (`None`: health, metrics, the document).
    rpc: Option<&'static str>,
    handler: MethodRouter<App>,
}

fn route<H: Handler<T, App>, T: 'static>(
    verb: Verb,
    path: &'static str,
    rpc: Option<&'static str>,
    handler: H,
) -> Route {
    Route {
        verb,
        path,
        // Health, metrics, the document and the server info are open.
        guarded: rpc.is_some_and(|r| r != "GetServerInfo"),
        rpc,
        handler: on(verb.filter(), handler),
    }
}

/// The route table: the router is built from it, and [`routes`] lists it (the OpenAPI document
/// is generated from it; the tests walk it beside the gRPC face).
fn table() -> Vec<Route> {
    use Verb::{Delete, Get, Post, Put};
    use handlers as h;
    const S: &str = "/v1/sessions/{id}";
    vec![
        route(Get, "/healthz", None, h::healthz),
        route(Get, "/readyz", None, h::readyz),
        route(Get, METRICS_PATH, None, h::metrics),
        route(Get, "/v1/openapi.json", None, h::openapi),
        route(Get, "/v1/info", Some("GetServerInfo"), h::info),
        route(
            Post,
            "/v1/sessions",
            Some("CreateSession"),
            h::create_session,
        ),
        route(Get, "/v1/sessions", Some("ListSessions"), h::list_sessions),
        route(Get, S, Some("GetSession"), h::get_session),
        route(Delete, S, Some("DeleteSession"), h::delete_session),
        route(
            Put,
            "/v1/sessions/{id}/label-map",
            Some("UploadLabelMap"),
            h::upload_label_map,
        ),
        route(
            Post,
            "/v1/sessions/{id}/reconstruct",
            Some("Reconstruct"),
            h::reconstruct,
        ),
        route(Post, "/v1/sessions/{id}/edits", Some("Edit"), h::edit),
        route(
            Get,
            "/v1/sessions/{id}/volumes",
            Some("GetVolumes"),
            h::volumes,
        ),
        route(
            Get,
            "/v1/sessions/{id}/plan",
            Some("ExportPlan"),
            h::export_plan,
        ),
        route(
            Put,
            "/v1/sessions/{id}/plan",
            Some("ImportPlan"),
            h::import_plan,
        ),
        route(
            Get,
            "/v1/sessions/{id}/models/{name}",
            Some("ExportModel"),
            h::export_model,
        ),
        route(
            Get,
            "/v1/sessions/{id}/slices",
            Some("GetSlices"),
            h::slices,
        ),
        route(
            Get,
            "/v1/sessions/{id}/label-slice",
            Some("GetLabelSlice"),
            h::label_slice,
        ),
        route(
            Get,
            "/v1/sessions/{id}/resectogram",
            Some("GetResectogram"),
            h::resectogram,
        ),
        route(
            Get,
            "/v1/sessions/{id}/risk-map",
            Some("GetRiskMap"),
            h::risk_map,
        ),
        route(Get, "/v1/sessions/{id}/watch", Some("Watch"), h::watch),
        route(
            Post,
            "/v1/point-clouds/reconstruct",
            Some("ReconstructPoints"),
            h::reconstruct_points,
        ),
    ]
}

/// One route of the face.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RouteInfo {
    pub method: Method,
    /// The path in OpenAPI template syntax.
    pub path: &'static str,
    /// The `PlanningService` RPC it is, if any.
    pub rpc: Option<&'static str>,
}

/// Every route; `/metrics` exists only when [`HttpOptions::metrics`] is given.
pub fn routes() -> Vec<RouteInfo> {
    table()
        .into_iter()
        .map(|r| RouteInfo {
            method: r.verb.method(),
            path: r.path,
            rpc: r.rpc,
        })
        .collect()
}

/// The HTTP face over `service`, guarded by `policy`.
pub fn router(service: Arc<Service>, policy: AccessPolicy, options: HttpOptions) -> Router {
    let app = App {
        service,
        metrics: options.metrics,
        max_json_bytes: options.max_json_bytes,
        keep_alive: options.keep_alive,
        shutdown: options.shutdown,
    };
    let (mut open, mut guarded) = (Router::new(), Router::new());
    for r in table() {
        if r.path == METRICS_PATH && app.metrics.is_none() {
            continue;
        }
        if r.guarded {
            guarded = guarded.route(r.path, r.handler);
        } else {
            open = open.route(r.path, r.handler);
        }
    }
    let guarded = guarded.route_layer(middleware::from_fn_with_state(Arc::new(policy), access));
    // The browser client: static files that carry no data, so open like the document.
    open.merge(resecta_web::router())
        .merge(guarded)
        .fallback(handlers::no_route)
        .method_not_allowed_fallback(handlers::method_not_allowed)
        .with_state(app)
        .layer(
            ServiceBuilder::new()
                .layer(middleware::map_request(sanitize_request_id))
                .layer(SetRequestIdLayer::new(X_REQUEST_ID, MakeRequestUuid))
                .layer(PropagateRequestIdLayer::new(X_REQUEST_ID))
                .layer(
                    TraceLayer::new_for_http()
                        .make_span_with(make_span)
                        .on_response(on_response),
                )
                .layer(middleware::from_fn(count)),
        )
}

/// Applies the access policy to the `authorization` and `resecta-api-version` headers. A request
/// that passes marks its connection authenticated ([`resecta_conn::Conn`], when the server put
/// one into the extensions): no longer subject to the handshake timeout nor evicted as
/// unauthenticated.
async fn access(State(policy): State<Arc<AccessPolicy>>, req: Request, next: Next) -> Response {
    let verdict = {
        let header = |name: &str| {
            req.headers()
                .get(name)
                .map(|v| v.to_str().unwrap_or("\u{fffd}"))
        };
        policy.check(
            header(header::AUTHORIZATION.as_str()),
            header(API_VERSION_HEADER),
        )
    };
    match verdict {
        Ok(()) => {
            if let Some(conn) = req.extensions().get::<resecta_conn::Conn>() {
                conn.mark_authenticated();
            }
            next.run(req).await
        }
        Err(e) => Problem::from(e).into_response(),
    }
}

/// Drops a client request id that is too long or not printable ASCII (a fresh one replaces it).
async fn sanitize_request_id(mut req: Request) -> Request {
    let ok = req.headers().get(&X_REQUEST_ID).is_none_or(|v| {
        let b = v.as_bytes();
        !b.is_empty() && b.len() <= MAX_REQUEST_ID && b.iter().all(|c| c.is_ascii_graphic())
    });
    if !ok {
        req.headers_mut().remove(&X_REQUEST_ID);
    }
    req
}

fn route_of<B>(req: &http::Request<B>) -> &str {
    req.extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", MatchedPath::as_str)
}

fn make_span<B>(req: &http::Request<B>) -> Span {
    let id = req
        .headers()
        .get(&X_REQUEST_ID)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    tracing::info_span!(
        "http",
        method = %req.method(),
        route = route_of(req),
        request_id = id,
        status = tracing::field::Empty,
        latency_ms = tracing::field::Empty,
    )
}

fn on_response<B>(res: &http::Response<B>, latency: Duration, span: &Span) {
    span.record("status", res.status().as_u16());
    span.record("latency_ms", latency.as_secs_f64() * 1e3);
    tracing::info!(parent: span, "response");
}

/// Counts the request in `resecta_http_requests_total{route,status}`.
async fn count(req: Request, next: Next) -> Response {
    let route = route_of(&req).to_owned();
    let res = next.run(req).await;
    metrics::counter!(
        "resecta_http_requests_total",
        "route" => route,
        "status" => res.status().as_str().to_owned()
    )
    .increment(1);
    res
}
