//! One handler per route: decode the request, call [`resecta_session::Service`], encode the
//! answer. No operation logic lives here.

use std::convert::Infallible;
use std::str::FromStr;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use futures_util::stream;
use resecta_geom::{Real, RoleMap};
use resecta_io::mesh::MeshFormat;
use resecta_plan::SlicePositions;
use resecta_session::api::{
    DataType, EditOp, FileFormat, LabelMapSource, RawLabelMap, ReconOptions,
};
use serde::{Deserialize, Serialize};

use crate::App;
use crate::extract::{Json, OptionalJson, Path, Query, read_body};
use crate::problem::Problem;
use crate::wire;

type Answer<T> = Result<T, Problem>;
type JsonAnswer<T> = Answer<axum::Json<T>>;

/// The OpenAPI 3.1 document of this face.
pub const OPENAPI: &str = include_str!("openapi.json");

pub async fn healthz() -> &'static str {
    "ok\n"
}

pub async fn metrics(State(app): State<App>) -> Answer<Response> {
    let render = app
        .metrics
        .as_ref()
        .ok_or_else(|| Problem::new(StatusCode::NOT_FOUND, "NO_ROUTE", "no metrics here"))?;
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        render(),
    )
        .into_response())
}

pub async fn openapi() -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        OPENAPI,
    )
        .into_response()
}

pub async fn info(State(app): State<App>) -> axum::Json<resecta_session::api::ServerInfo> {
    axum::Json(app.service.info())
}

// ---- sessions ------------------------------------------------------------------------------

#[derive(Debug, Deserialize)]
pub struct CreateSession {
    display_name: String,
}

pub async fn create_session(
    State(app): State<App>,
    Json(req): Json<CreateSession>,
) -> Answer<Response> {
    let info = app.service.create_session(&req.display_name).await?;
    let location = HeaderValue::from_str(&format!("/v1/sessions/{}", info.id))
        .map_err(|e| Problem::from(resecta_session::SessionError::Internal(e.to_string())))?;
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        axum::Json(info),
    )
        .into_response())
}

#[derive(Debug, Serialize)]
pub struct SessionList {
    sessions: Vec<resecta_session::api::SessionInfo>,
}

pub async fn list_sessions(State(app): State<App>) -> JsonAnswer<SessionList> {
    let sessions = app.service.list_sessions().await?;
    Ok(axum::Json(SessionList { sessions }))
}

pub async fn get_session(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<resecta_session::api::SessionInfo> {
    Ok(axum::Json(app.service.get_session(&id).await?))
}

pub async fn delete_session(State(app): State<App>, Path(id): Path<String>) -> Answer<StatusCode> {
    app.service.delete_session(&id).await?;
    Ok(StatusCode::NO_CONTENT)
}

// ---- label maps ----------------------------------------------------------------------------

/// What the body of a label-map upload is.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UploadFormat {
    /// Raw little-endian voxels; the geometry comes in the query.
    Raw,
    /// An image file, its format told from its first bytes.
    #[default]
    Auto,
    Nifti,
    Nrrd,
    SegNrrd,
    MetaImage,
}

#[derive(Debug, Deserialize)]
pub struct UploadQuery {
    #[serde(default)]
    format: UploadFormat,
    /// `i,j,k` voxel counts (raw).
    dims: Option<String>,
    /// `i,j,k` voxel size, mm (raw).
    spacing: Option<String>,
    /// `r,a,s` of voxel (0, 0, 0), mm (raw; default 0,0,0).
    origin: Option<String>,
    /// 9 row-major values (raw; default identity).
    direction: Option<String>,
    /// u8 | u16 | i16 | u32 | i32 (raw).
    data_type: Option<DataType>,
    /// The role map as JSON, e.g. `{"parenchyma":[1],"tumor":[2]}` (default: 1 parenchyma,
    /// 2 tumour, 3 portal, 4 hepatic).
    roles: Option<String>,
}

/// `N` comma-separated numbers of the query parameter `name`.
fn numbers<T: FromStr + Copy + Default, const N: usize>(
    name: &str,
    value: Option<&str>,
    default: Option<[T; N]>,
) -> Answer<[T; N]> {
    let bad = || Problem::invalid(format!("{name} must be {N} comma-separated numbers"));
    let Some(value) = value else {
        return default.ok_or_else(|| Problem::invalid(format!("{name} is required")));
    };
    let mut out = [T::default(); N];
    let mut parts = value.split(',');
    for slot in &mut out {
        *slot = parts
            .next()
            .and_then(|p| p.trim().parse().ok())
            .ok_or_else(bad)?;
    }
    match parts.next() {
        Some(_) => Err(bad()),
        None => Ok(out),
    }
}

/// A label-map upload as its query describes it, before the body is read.
enum Header {
    Raw {
        dims: [usize; 3],
        spacing: [Real; 3],
        origin: [Real; 3],
        direction: [Real; 9],
        data_type: DataType,
    },
    File(FileFormat),
}

impl Header {
    fn with(self, data: Vec<u8>) -> LabelMapSource {
        match self {
            Self::Raw {
                dims,
                spacing,
                origin,
                direction,
                data_type,
            } => LabelMapSource::Raw(RawLabelMap {
                dims,
                spacing,
                origin,
                direction,
                data_type,
                data,
            }),
            Self::File(format) => LabelMapSource::File {
                format,
                bytes: data,
            },
        }
    }
}

impl UploadQuery {
    fn header(&self) -> Answer<(Header, RoleMap)> {
        let roles = match &self.roles {
            None => RoleMap::default(),
            Some(json) => {
                serde_json::from_str(json).map_err(|e| Problem::invalid(format!("roles: {e}")))?
            }
        };
        let header = match self.format {
            UploadFormat::Raw => Header::Raw {
                dims: numbers("dims", self.dims.as_deref(), None)?,
                spacing: numbers("spacing", self.spacing.as_deref(), None)?,
                origin: numbers("origin", self.origin.as_deref(), Some([0.0; 3]))?,
                direction: numbers(
                    "direction",
                    self.direction.as_deref(),
                    Some([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
                )?,
                data_type: self
                    .data_type
                    .ok_or_else(|| Problem::invalid("data_type is required"))?,
            },
            UploadFormat::Auto => Header::File(FileFormat::Auto),
            UploadFormat::Nifti => Header::File(FileFormat::Nifti),
            UploadFormat::Nrrd => Header::File(FileFormat::Nrrd),
            UploadFormat::SegNrrd => Header::File(FileFormat::SegNrrd),
            UploadFormat::MetaImage => Header::File(FileFormat::MetaImage),
        };
        Ok((header, roles))
    }
}

/// Checks the query and the session, then reads the body within the service's upload limit
/// (refusing more while it streams), then loads it.
pub async fn upload_label_map(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(query): Query<UploadQuery>,
    req: Request,
) -> JsonAnswer<resecta_session::api::LabelMapSummary> {
    let (header, roles) = query.header()?;
    app.service.get_session(&id).await?;
    let (parts, body) = req.into_parts();
    let limit = app.service.config().max_upload_bytes;
    let bytes = read_body(&parts.headers, body, limit).await?;
    let summary = app
        .service
        .upload_label_map(&id, header.with(bytes.into()), roles)
        .await?;
    Ok(axum::Json(summary))
}

// ---- reconstruction and edits --------------------------------------------------------------

/// The problem of a stream ended by the server's shutdown.
fn shutting_down() -> Problem {
    Problem::new(
        StatusCode::SERVICE_UNAVAILABLE,
        "UNAVAILABLE",
        "the server is shutting down; reconnect later",
    )
}

/// Completes once `signal` says the server is shutting down (never without a signal).
async fn stopping(signal: Option<tokio::sync::watch::Receiver<bool>>) {
    match signal {
        // Err: the sender is gone, which also means the server is going away.
        Some(mut rx) => drop(rx.wait_for(|s| *s).await),
        None => std::future::pending::<()>().await,
    }
}

/// `events`, ended by an `error` event (503 `UNAVAILABLE`) once the server shuts down; `events`
/// is dropped then, which cancels whatever feeds it.
fn until_shutdown(
    events: impl Stream<Item = Event> + Send + 'static,
    signal: Option<tokio::sync::watch::Receiver<bool>>,
) -> impl Stream<Item = Event> + Send + 'static {
    use futures_util::StreamExt;
    use futures_util::future::{self, Either};
    type Events = std::pin::Pin<Box<dyn Stream<Item = Event> + Send>>;
    type Stop = std::pin::Pin<Box<dyn Future<Output = ()> + Send>>;
    let events: Events = Box::pin(events);
    let stop: Stop = Box::pin(stopping(signal));
    stream::unfold(Some((events, stop)), |state| async move {
        let (mut events, mut stop) = state?;
        let next = match future::select(events.next(), stop.as_mut()).await {
            Either::Left((event, _)) => Some(event),
            Either::Right(((), _)) => None,
        };
        match next {
            Some(Some(event)) => Some((event, Some((events, stop)))),
            Some(None) => None,
            None => {
                drop(events);
                Some((wire::error_event(&shutting_down()), None))
            }
        }
    })
}

/// A server-sent event stream with keep-alive comments, ended when the server shuts down.
fn sse<S: Stream<Item = Event> + Send + 'static>(
    app: &App,
    events: S,
) -> Sse<impl Stream<Item = Result<Event, Infallible>> + use<S>> {
    use futures_util::StreamExt;
    let events = until_shutdown(events, app.shutdown.clone());
    Sse::new(events.map(Ok)).keep_alive(KeepAlive::new().interval(app.keep_alive))
}

/// Starts the reconstruction with the options of the body (empty: the defaults) and streams its
/// events; a client that goes away cancels it.
pub async fn reconstruct(
    State(app): State<App>,
    Path(id): Path<String>,
    OptionalJson(options): OptionalJson<ReconOptions>,
) -> Answer<impl IntoResponse> {
    let rx = app.service.reconstruct(&id, options).await?;
    let events = stream::unfold(Some(rx), |rx| async move {
        let mut rx = rx?;
        match rx.recv().await? {
            Ok(e) => Some((wire::reconstruct_event(&e), Some(rx))),
            Err(e) => Some((wire::error_event(&Problem::from(e)), None)),
        }
    });
    Ok(sse(&app, events))
}

#[derive(Debug, Deserialize)]
pub struct EditRequest {
    /// The plan version the client saw; 0 (or absent): unchecked.
    #[serde(default)]
    base_version: u64,
    edit: EditOp,
}

pub async fn edit(
    State(app): State<App>,
    Path(id): Path<String>,
    Json(req): Json<EditRequest>,
) -> JsonAnswer<resecta_session::api::EditOutcome> {
    Ok(axum::Json(
        app.service.edit(&id, req.base_version, req.edit).await?,
    ))
}

/// Volumes with the plan version they belong to (as gRPC's `GetVolumesResponse`).
#[derive(Debug, Serialize)]
pub struct VersionedVolumes {
    plan_version: u64,
    volumes: resecta_plan::VolumeReport,
}

pub async fn volumes(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<VersionedVolumes> {
    let v = app.service.volumes(&id).await?;
    Ok(axum::Json(VersionedVolumes {
        plan_version: v.plan_version,
        volumes: v.value,
    }))
}

// ---- plans, models, slices -----------------------------------------------------------------

pub async fn export_plan(State(app): State<App>, Path(id): Path<String>) -> Answer<Response> {
    let plan = app.service.export_plan(&id).await?;
    Ok((
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            ),
            (
                header::HeaderName::from_static("resecta-plan-version"),
                HeaderValue::from(plan.plan_version),
            ),
        ],
        plan.value,
    )
        .into_response())
}

#[derive(Debug, Deserialize)]
pub struct VersionQuery {
    #[serde(default)]
    base_version: u64,
}

#[derive(Debug, Serialize)]
pub struct PlanVersion {
    plan_version: u64,
}

pub async fn import_plan(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<VersionQuery>,
    headers: HeaderMap,
    body: Body,
) -> JsonAnswer<PlanVersion> {
    let bytes = read_body(&headers, body, app.max_json_bytes).await?;
    let json = std::str::from_utf8(&bytes)
        .map_err(|_| Problem::invalid("the plan document is not UTF-8"))?;
    let plan_version = app.service.import_plan(&id, json, q.base_version).await?;
    Ok(axum::Json(PlanVersion { plan_version }))
}

#[derive(Debug, Default, Clone, Copy, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelFormat {
    #[default]
    Vtp,
    Vtk,
    Stl,
    Ply,
    Obj,
}

#[derive(Debug, Deserialize)]
pub struct ModelQuery {
    #[serde(default)]
    format: ModelFormat,
}

pub async fn export_model(
    State(app): State<App>,
    Path((id, name)): Path<(String, String)>,
    Query(q): Query<ModelQuery>,
) -> Answer<Response> {
    let (format, media) = match q.format {
        ModelFormat::Vtp => (MeshFormat::Vtp, "application/xml"),
        ModelFormat::Vtk => (MeshFormat::Vtk, "application/octet-stream"),
        ModelFormat::Stl => (MeshFormat::Stl, "model/stl"),
        ModelFormat::Ply => (MeshFormat::Ply, "application/octet-stream"),
        ModelFormat::Obj => (MeshFormat::Obj, "model/obj"),
    };
    let bytes = app.service.export_model(&id, &name, format).await?;
    Ok((
        [(header::CONTENT_TYPE, HeaderValue::from_static(media))],
        bytes,
    )
        .into_response())
}

#[derive(Debug, Deserialize)]
pub struct SliceQuery {
    /// The resection to intersect.
    resection: String,
    axial: Option<Real>,
    coronal: Option<Real>,
    sagittal: Option<Real>,
}

pub async fn slices(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<SliceQuery>,
) -> JsonAnswer<wire::Slices> {
    let at = SlicePositions {
        axial: q.axial,
        coronal: q.coronal,
        sagittal: q.sagittal,
    };
    let s = app.service.slices(&id, &q.resection, at).await?;
    Ok(axum::Json(wire::Slices::from(&s)))
}

// ---- watch ---------------------------------------------------------------------------------

#[derive(Debug, Deserialize)]
pub struct WatchQuery {
    since_seq: Option<u64>,
}

/// The session's events as server-sent events (`id` = seq). `Last-Event-ID` (an automatic
/// reconnect) takes precedence over `since_seq`. The session's stream is pulled as the client
/// reads, so a slow client falls behind and then gets a snapshot; nothing is buffered here.
pub async fn watch(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<WatchQuery>,
    headers: HeaderMap,
) -> Answer<impl IntoResponse> {
    let last = match headers.get("last-event-id") {
        None => None,
        Some(v) => Some(
            v.to_str()
                .ok()
                .and_then(|s| s.trim().parse::<u64>().ok())
                .ok_or_else(|| Problem::invalid("Last-Event-ID must be a sequence number"))?,
        ),
    };
    let w = app.service.watch(&id, last.or(q.since_seq)).await?;
    let events = stream::unfold(Some((w, id)), |state| async move {
        let (mut w, id) = state?;
        match w.next().await {
            Some(Ok(e)) => Some((wire::watch_event(&e), Some((w, id)))),
            Some(Err(e)) => Some((wire::error_event(&Problem::from(e)), None)),
            // The hub closes when the session is deleted or expires, as on the gRPC face.
            None => {
                let gone = Problem::from(resecta_session::SessionError::UnknownSession(id));
                Some((wire::error_event(&gone), None))
            }
        }
    });
    Ok(sse(&app, events))
}

// ---- fallbacks -----------------------------------------------------------------------------

pub async fn no_route(req: Request) -> Problem {
    Problem::new(
        StatusCode::NOT_FOUND,
        "NO_ROUTE",
        format!("no route {} {}", req.method(), req.uri().path()),
    )
}

pub async fn method_not_allowed(req: Request) -> Problem {
    Problem::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "METHOD_NOT_ALLOWED",
        format!("{} is not allowed on {}", req.method(), req.uri().path()),
    )
}
