//! One handler per route: take the RPC's request message (proto JSON body, path, query), call
//! [`resecta_session::Service`] through the conversions both faces share
//! ([`resecta_face::convert`]), answer with the RPC's response message. No operation logic
//! lives here.

use std::convert::Infallible;
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::{Stream, StreamExt, stream};
use resecta_api::v1 as pb;
use resecta_face::shutdown::until_shutdown;
use resecta_face::upload::Upload;
use resecta_face::{WireError, convert};

use crate::App;
use crate::extract::{Path, ProtoJson, ProtoQuery, proto_json, read_body};
use crate::problem::Problem;
use crate::wire;

type Answer<T> = Result<T, Problem>;
type JsonAnswer<T> = Answer<axum::Json<T>>;

pub async fn healthz() -> &'static str {
    "ok\n"
}

/// Readiness: 503 while the server drains or its store does not answer.
pub async fn readyz(State(app): State<App>) -> Answer<&'static str> {
    app.service
        .ready()
        .await
        .map_err(|e| Problem::new(StatusCode::SERVICE_UNAVAILABLE, "NOT_READY", e.to_string()))?;
    Ok("ready\n")
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
        crate::openapi::document_text(),
    )
        .into_response()
}

/// The session id of a request: the path's; a body or query naming another is refused.
fn session_id(body: &mut String, path: String) -> Answer<()> {
    if !body.is_empty() && *body != path {
        return Err(Problem::invalid(
            "sessionId: the body names another session than the path",
        ));
    }
    *body = path;
    Ok(())
}

pub async fn info(State(app): State<App>) -> axum::Json<pb::GetServerInfoResponse> {
    axum::Json(resecta_face::info::server_info(&app.service))
}

// ---- sessions ------------------------------------------------------------------------------

pub async fn create_session(
    State(app): State<App>,
    ProtoJson(req): ProtoJson<pb::CreateSessionRequest>,
) -> Answer<Response> {
    let info = app.service.create_session(&req.display_name).await?;
    let location = HeaderValue::from_str(&format!("/v1/sessions/{}", info.id))
        .map_err(|e| Problem::from(resecta_session::SessionError::Internal(e.to_string())))?;
    let answer = pb::CreateSessionResponse {
        session: Some(convert::session(&info)),
    };
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        axum::Json(answer),
    )
        .into_response())
}

pub async fn list_sessions(State(app): State<App>) -> JsonAnswer<pb::ListSessionsResponse> {
    let sessions = app.service.list_sessions().await?;
    Ok(axum::Json(pb::ListSessionsResponse {
        sessions: sessions.iter().map(convert::session).collect(),
    }))
}

pub async fn get_session(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<pb::GetSessionResponse> {
    let s = app.service.get_session(&id).await?;
    Ok(axum::Json(pb::GetSessionResponse {
        session: Some(convert::session(&s)),
    }))
}

pub async fn delete_session(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<pb::DeleteSessionResponse> {
    app.service.delete_session(&id).await?;
    Ok(axum::Json(pb::DeleteSessionResponse {}))
}

// ---- label maps ----------------------------------------------------------------------------

/// The upload's header: the proto JSON of `RawLabelMapHeader` (`raw=`) or `FileLabelMapHeader`
/// (`file=`) in the query; neither is a file whose format is told from its bytes.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    raw: Option<String>,
    file: Option<String>,
}

impl UploadQuery {
    fn header(&self) -> Answer<pb::upload_label_map_request::Header> {
        use pb::upload_label_map_request::Header;
        let parse = |name: &str, json: &str| -> Answer<Header> {
            let bad = |e: serde_json::Error| Problem::invalid(format!("{name}: {e}"));
            Ok(match name {
                "raw" => Header::Raw(proto_json(json.as_bytes()).map_err(bad)?),
                _ => Header::File(proto_json(json.as_bytes()).map_err(bad)?),
            })
        };
        match (&self.raw, &self.file) {
            (Some(_), Some(_)) => Err(Problem::invalid("give raw= or file=, not both")),
            (Some(raw), None) => parse("raw", raw),
            (None, Some(file)) => parse("file", file),
            (None, None) => Ok(Header::File(pb::FileLabelMapHeader {
                format: pb::LabelMapFormat::Auto as i32,
                ..pb::FileLabelMapHeader::default()
            })),
        }
    }
}

/// `UploadLabelMap` in one request: the header from the query, the data as the body (raw voxels,
/// i fastest, or the image file), read within the service's upload limit (refused while it
/// streams). `totalBytes` may be left out: it is the body's length.
pub async fn upload_label_map(
    State(app): State<App>,
    Path(id): Path<String>,
    crate::extract::Query(query): crate::extract::Query<UploadQuery>,
    req: Request,
) -> JsonAnswer<pb::UploadLabelMapResponse> {
    use pb::upload_label_map_request::Header;
    let mut header = query.header()?;
    app.service.get_session(&id).await?;
    let (parts, body) = req.into_parts();
    let limit = app.service.config().max_upload_bytes;
    // Held until the label map is decoded and loaded.
    let mut memory = app.service.admit_upload()?;
    let bytes = read_body(&parts.headers, body, limit, Some(&mut memory)).await?;
    let (session, total) = match &mut header {
        Header::Raw(h) => (&mut h.session_id, &mut h.total_bytes),
        Header::File(h) => (&mut h.session_id, &mut h.total_bytes),
    };
    session_id(session, id)?;
    if *total == 0 {
        *total = bytes.len() as u64;
    }
    let mut upload = Upload::start(Some(&header), limit)?;
    upload.append_owned(bytes.into())?;
    let (id, source, roles) = upload.finish()?;
    let summary = app.service.upload_label_map(&id, source, roles).await?;
    Ok(axum::Json(pb::UploadLabelMapResponse {
        label_map: Some(convert::label_map(&summary)),
    }))
}

// ---- reconstruction and edits --------------------------------------------------------------

/// The last event of a stream ended by the server's shutdown: 503 `UNAVAILABLE`.
fn shutting_down() -> Event {
    wire::error_event(&Problem::new(
        StatusCode::SERVICE_UNAVAILABLE,
        "UNAVAILABLE",
        resecta_face::SHUTTING_DOWN,
    ))
}

/// A server-sent event stream with keep-alive comments, ended when the server shuts down.
fn sse<S: Stream<Item = Event> + Send + 'static>(
    app: &App,
    events: S,
) -> Sse<impl Stream<Item = Result<Event, Infallible>> + use<S>> {
    let events = until_shutdown(events, app.shutdown.clone(), shutting_down);
    Sse::new(events.map(Ok)).keep_alive(KeepAlive::new().interval(app.keep_alive))
}

/// `Reconstruct`: the body is the `ReconstructRequest` (empty: the defaults); its events
/// stream as server-sent events; a client that goes away cancels it.
pub async fn reconstruct(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoJson(mut req): ProtoJson<pb::ReconstructRequest>,
) -> Answer<impl IntoResponse> {
    session_id(&mut req.session_id, id)?;
    let options = convert::reconstruct_options(&req)?;
    let rx = app.service.reconstruct(&req.session_id, options).await?;
    let events = stream::unfold(Some(rx), |rx| async move {
        let mut rx = rx?;
        match rx.recv().await? {
            Ok(e) => Some((
                wire::reconstruct_event(convert::reconstruct_event(e)),
                Some(rx),
            )),
            Err(e) => Some((wire::error_event(&Problem::from(e)), None)),
        }
    });
    Ok(sse(&app, events))
}

pub async fn edit(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoJson(mut req): ProtoJson<pb::EditRequest>,
) -> JsonAnswer<pb::EditResponse> {
    session_id(&mut req.session_id, id)?;
    let op = convert::edit(req.edit.as_ref())?;
    let out = app
        .service
        .edit(&req.session_id, req.base_version, op)
        .await?;
    Ok(axum::Json(convert::edit_response(out)))
}

pub async fn volumes(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<pb::GetVolumesResponse> {
    let v = app.service.volumes(&id).await?;
    Ok(axum::Json(pb::GetVolumesResponse {
        plan_version: v.plan_version,
        volumes: Some(convert::volumes(&v.value)),
    }))
}

// ---- plans, models, slices -----------------------------------------------------------------

pub async fn export_plan(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<pb::ExportPlanResponse> {
    let plan = app.service.export_plan(&id).await?;
    Ok(axum::Json(pb::ExportPlanResponse {
        plan_version: plan.plan_version,
        plan_json: plan.value,
    }))
}

pub async fn import_plan(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoJson(mut req): ProtoJson<pb::ImportPlanRequest>,
) -> JsonAnswer<pb::ImportPlanResponse> {
    session_id(&mut req.session_id, id)?;
    let plan_version = app
        .service
        .import_plan(&req.session_id, &req.plan_json, req.base_version)
        .await?;
    Ok(axum::Json(pb::ImportPlanResponse { plan_version }))
}

/// The media type of an exported mesh file of `format`.
pub fn model_media(format: pb::ModelFormat) -> &'static str {
    match format {
        pb::ModelFormat::Vtp => "application/xml",
        pb::ModelFormat::Stl => "model/stl",
        pb::ModelFormat::Obj => "model/obj",
        pb::ModelFormat::Vtk | pb::ModelFormat::Ply | pb::ModelFormat::Unspecified => {
            "application/octet-stream"
        }
    }
}

/// `ExportModel`: the whole file as the body (not base64 chunks); `{name}` is a model's or a
/// resection's name, the query the rest of the `ExportModelRequest` (`format`).
pub async fn export_model(
    State(app): State<App>,
    Path((id, name)): Path<(String, String)>,
    ProtoQuery(mut req): ProtoQuery<pb::ExportModelRequest>,
) -> Answer<Response> {
    session_id(&mut req.session_id, id)?;
    if req.surface.is_some() {
        return Err(Problem::invalid(
            "the surface is the path's {name}, not a query parameter",
        ));
    }
    let format = convert::mesh_format(req.format)?;
    let media = model_media(pb::ModelFormat::try_from(req.format).unwrap_or_default());
    let bytes = app
        .service
        .export_model(&req.session_id, &name, format)
        .await?;
    Ok((
        [(header::CONTENT_TYPE, HeaderValue::from_static(media))],
        bytes,
    )
        .into_response())
}

/// `GetSlices`: the query is the `GetSlicesRequest` (`resection=r1&axial=…`).
pub async fn slices(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoQuery(mut req): ProtoQuery<pb::GetSlicesRequest>,
) -> JsonAnswer<pb::GetSlicesResponse> {
    use pb::get_slices_request::Surface;
    session_id(&mut req.session_id, id)?;
    let at = convert::slice_positions(&req)?;
    let name = match &req.surface {
        Some(Surface::Resection(n)) => n,
        Some(Surface::Model(_)) => return Err(convert::model_slices().into()),
        None => {
            return Err(WireError::invalid("surface", "is required (model or resection)").into());
        }
    };
    let s = app.service.slices(&req.session_id, name, at).await?;
    Ok(axum::Json(convert::slices(&s)))
}

/// `GetLabelSlice`: the query is the `GetLabelSliceRequest`
/// (`axis=SLICE_AXIS_AXIAL&positionMm=…&pixelMm=…`); the labels come base64-encoded.
pub async fn label_slice(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoQuery(mut req): ProtoQuery<pb::GetLabelSliceRequest>,
) -> JsonAnswer<pb::GetLabelSliceResponse> {
    session_id(&mut req.session_id, id)?;
    let (axis, position, pixel) = convert::label_slice_request(&req)?;
    let s = app
        .service
        .label_slice(&req.session_id, axis, position, pixel)
        .await?;
    Ok(axum::Json(convert::label_slice(&s)))
}

/// `GetResectogram`: the query is the `GetResectogramRequest`
/// (`resection=r1&width=200&height=200`); the classes come base64-encoded.
pub async fn resectogram(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoQuery(mut req): ProtoQuery<pb::GetResectogramRequest>,
) -> JsonAnswer<pb::GetResectogramResponse> {
    session_id(&mut req.session_id, id)?;
    let (name, width, height) = convert::resectogram_request(&req)?;
    let g = app
        .service
        .resectogram(&req.session_id, &name, width, height)
        .await?;
    Ok(axum::Json(convert::resectogram(g.plan_version, &g.value)))
}

/// `GetRiskMap`: the classes and territories come base64-encoded zstd frames.
pub async fn risk_map(
    State(app): State<App>,
    Path(id): Path<String>,
) -> JsonAnswer<pb::GetRiskMapResponse> {
    let m = app.service.risk_map(&id).await?;
    Ok(axum::Json(convert::risk_map(m.plan_version, &m.value)?))
}

// ---- point clouds --------------------------------------------------------------------------

/// `ReconstructPoints`: the body is the `ReconstructPointsRequest` (positions and normals as
/// JSON arrays of numbers); the mesh comes base64-encoded. No session.
pub async fn reconstruct_points(
    State(app): State<App>,
    ProtoJson(req): ProtoJson<pb::ReconstructPointsRequest>,
) -> JsonAnswer<pb::ReconstructPointsResponse> {
    let cloud = convert::point_cloud(req)?;
    let surface = app.service.reconstruct_points(cloud).await?;
    Ok(axum::Json(convert::point_cloud_surface(surface)?))
}

// ---- watch ---------------------------------------------------------------------------------

/// `Watch` as server-sent events: the query is the `WatchRequest` (`sinceSeq`, `allowZstd`,
/// `allowQuantized`), each event's data a `WatchResponse` (`id` = its seq, `event` = snapshot |
/// delta | volumes). `Last-Event-ID` (an automatic reconnect) takes precedence over `sinceSeq`.
/// The session's stream is pulled as the client reads, so a slow client falls behind and then
/// gets a snapshot; nothing is buffered here.
pub async fn watch(
    State(app): State<App>,
    Path(id): Path<String>,
    ProtoQuery(mut req): ProtoQuery<pb::WatchRequest>,
    headers: HeaderMap,
) -> Answer<impl IntoResponse> {
    session_id(&mut req.session_id, id)?;
    if let Some(v) = headers.get("last-event-id") {
        req.since_seq = Some(
            v.to_str()
                .ok()
                .and_then(|s| s.trim().parse::<u64>().ok())
                .ok_or_else(|| Problem::invalid("Last-Event-ID must be a sequence number"))?,
        );
    }
    resecta_face::watch::check_payloads(&app.service, &req)?;
    let messages =
        resecta_face::watch::watch(Arc::clone(&app.service), req.session_id, req.since_seq).await?;
    // The stream ends after its first error (a deleted session: 404).
    let events = messages.map(|m| match m {
        Ok(m) => wire::watch_event(&m),
        Err(e) => wire::error_event(&Problem::from(e)),
    });
    Ok(sse(&app, events))
}

// ---- fallbacks -----------------------------------------------------------------------------

pub async fn no_route(req: Request) -> Problem {
    Problem::new(
        StatusCode::NOT_FOUND,
        "NO_ROUTE",
        format!(
            "no route {} {}",
            req.method(),
            crate::problem::path_for_messages(req.uri().path())
        ),
    )
}

pub async fn method_not_allowed(req: Request) -> Problem {
    Problem::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "METHOD_NOT_ALLOWED",
        format!(
            "{} is not allowed on {}",
            req.method(),
            crate::problem::path_for_messages(req.uri().path())
        ),
    )
}
