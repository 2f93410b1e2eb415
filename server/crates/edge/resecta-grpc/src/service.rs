//! `resecta.v1.PlanningService` over [`resecta_session::Service`]: every RPC translates its
//! request with [`resecta_face::convert`], calls the operation once and translates the answer.

use std::pin::Pin;
use std::sync::Arc;

use futures_util::{Stream, StreamExt};
use resecta_api::MAX_CHUNK_BYTES;
use resecta_api::v1 as pb;
use resecta_api::v1::planning_service_server::PlanningService;
use resecta_session::Service;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use resecta_face::shutdown::{SHUTTING_DOWN, ShutdownSignal, until_shutdown};
use resecta_face::upload::Upload;
use resecta_face::{WireError, convert};

use crate::error::{OrStatus, face_status, session_status, wire_status};

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

/// The gRPC planning service: the operation layer plus what only this face knows.
#[derive(Debug, Clone)]
pub struct Planning {
    service: Arc<Service>,
    /// Ends `Watch` and `Reconstruct` streams with `UNAVAILABLE` when the server shuts down.
    shutdown: Option<ShutdownSignal>,
}

impl Planning {
    pub fn new(service: Arc<Service>) -> Self {
        Self {
            service,
            shutdown: None,
        }
    }

    /// Ends the long-lived streams (`Watch`, `Reconstruct`) with `UNAVAILABLE` once `signal`
    /// turns `true` (or its sender is dropped), so that graceful shutdown does not wait for them.
    #[must_use]
    pub fn with_shutdown(mut self, signal: ShutdownSignal) -> Self {
        self.shutdown = Some(signal);
        self
    }
}

fn missing_surface() -> Status {
    wire_status(&WireError::invalid(
        "surface",
        "is required (model or resection)",
    ))
}

/// The status that ends a stream when the server shuts down.
fn unavailable<T>() -> Result<T, Status> {
    Err(Status::unavailable(SHUTTING_DOWN))
}

#[tonic::async_trait]
impl PlanningService for Planning {
    async fn get_server_info(
        &self,
        _request: Request<pb::GetServerInfoRequest>,
    ) -> Result<Response<pb::GetServerInfoResponse>, Status> {
        Ok(Response::new(resecta_face::info::server_info(
            &self.service,
        )))
    }

    async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::CreateSessionResponse>, Status> {
        let s = self
            .service
            .create_session(&request.get_ref().display_name)
            .await
            .or_status()?;
        Ok(Response::new(pb::CreateSessionResponse {
            session: Some(convert::session(&s)),
        }))
    }

    async fn list_sessions(
        &self,
        _request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        let sessions = self.service.list_sessions().await.or_status()?;
        Ok(Response::new(pb::ListSessionsResponse {
            sessions: sessions.iter().map(convert::session).collect(),
        }))
    }

    async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::GetSessionResponse>, Status> {
        let s = self
            .service
            .get_session(&request.get_ref().session_id)
            .await
            .or_status()?;
        Ok(Response::new(pb::GetSessionResponse {
            session: Some(convert::session(&s)),
        }))
    }

    async fn delete_session(
        &self,
        request: Request<pb::DeleteSessionRequest>,
    ) -> Result<Response<pb::DeleteSessionResponse>, Status> {
        self.service
            .delete_session(&request.get_ref().session_id)
            .await
            .or_status()?;
        Ok(Response::new(pb::DeleteSessionResponse {}))
    }

    async fn upload_label_map(
        &self,
        request: Request<Streaming<pb::UploadLabelMapRequest>>,
    ) -> Result<Response<pb::UploadLabelMapResponse>, Status> {
        let mut chunks = request.into_inner();
        let first = chunks.message().await?.ok_or_else(|| {
            wire_status(&WireError::bad_chunk(
                "header",
                "the upload stream is empty",
            ))
        })?;
        let max = self.service.config().max_upload_bytes;
        let mut upload = Upload::start(first.header.as_ref(), max).or_status()?;
        // An unknown session fails before any data is taken in.
        self.service
            .get_session(&upload.session_id)
            .await
            .or_status()?;
        // The upload holds the memory budget as its bytes arrive, until the label map is
        // decoded and loaded.
        let mut memory = self.service.admit_upload().or_status()?;
        memory.grow(first.data.len() as u64).or_status()?;
        upload.push(first, true).or_status()?;
        while let Some(chunk) = chunks.message().await? {
            memory.grow(chunk.data.len() as u64).or_status()?;
            upload.push(chunk, false).or_status()?;
        }
        let (id, source, roles) = upload.finish().or_status()?;
        let summary = self
            .service
            .upload_label_map(&id, source, roles)
            .await
            .or_status()?;
        Ok(Response::new(pb::UploadLabelMapResponse {
            label_map: Some(convert::label_map(&summary)),
        }))
    }

    type ReconstructStream = BoxStream<pb::ReconstructResponse>;

    async fn reconstruct(
        &self,
        request: Request<pb::ReconstructRequest>,
    ) -> Result<Response<Self::ReconstructStream>, Status> {
        let r = request.into_inner();
        let options = convert::reconstruct_options(&r).or_status()?;
        // Dropping the stream (the client cancelled) drops the receiver, which cancels the work.
        let events = self
            .service
            .reconstruct(&r.session_id, options)
            .await
            .or_status()?;
        let stream = ReceiverStream::new(events).map(|e| match e {
            Ok(e) => Ok(convert::reconstruct_event(e)),
            Err(e) => Err(session_status(&e)),
        });
        let stream = until_shutdown(stream, self.shutdown.clone(), unavailable);
        Ok(Response::new(Box::pin(stream)))
    }

    async fn edit(
        &self,
        request: Request<pb::EditRequest>,
    ) -> Result<Response<pb::EditResponse>, Status> {
        let r = request.into_inner();
        let op = convert::edit(r.edit.as_ref()).or_status()?;
        let out = self
            .service
            .edit(&r.session_id, r.base_version, op)
            .await
            .or_status()?;
        Ok(Response::new(convert::edit_response(out)))
    }

    async fn get_volumes(
        &self,
        request: Request<pb::GetVolumesRequest>,
    ) -> Result<Response<pb::GetVolumesResponse>, Status> {
        let id = &request.get_ref().session_id;
        let v = self.service.volumes(id).await.or_status()?;
        Ok(Response::new(pb::GetVolumesResponse {
            plan_version: v.plan_version,
            volumes: Some(convert::volumes(&v.value)),
        }))
    }

    async fn export_plan(
        &self,
        request: Request<pb::ExportPlanRequest>,
    ) -> Result<Response<pb::ExportPlanResponse>, Status> {
        let id = &request.get_ref().session_id;
        let plan = self.service.export_plan(id).await.or_status()?;
        Ok(Response::new(pb::ExportPlanResponse {
            plan_version: plan.plan_version,
            plan_json: plan.value,
        }))
    }

    async fn import_plan(
        &self,
        request: Request<pb::ImportPlanRequest>,
    ) -> Result<Response<pb::ImportPlanResponse>, Status> {
        let r = request.get_ref();
        let plan_version = self
            .service
            .import_plan(&r.session_id, &r.plan_json, r.base_version)
            .await
            .or_status()?;
        Ok(Response::new(pb::ImportPlanResponse { plan_version }))
    }

    type ExportModelStream = BoxStream<pb::ExportModelResponse>;

    async fn export_model(
        &self,
        request: Request<pb::ExportModelRequest>,
    ) -> Result<Response<Self::ExportModelStream>, Status> {
        use pb::export_model_request::Surface;
        let r = request.into_inner();
        let name = match &r.surface {
            Some(Surface::Model(n) | Surface::Resection(n)) => n,
            None => return Err(missing_surface()),
        };
        let format = convert::mesh_format(r.format).or_status()?;
        let file = self
            .service
            .export_model(&r.session_id, name, format)
            .await
            .or_status()?;
        let total_bytes = file.len() as u64;
        let chunks = file.len().div_ceil(MAX_CHUNK_BYTES).max(1);
        let stream = futures_util::stream::iter((0..chunks).map(move |k| {
            let start = k * MAX_CHUNK_BYTES;
            let end = (start + MAX_CHUNK_BYTES).min(file.len());
            Ok(pb::ExportModelResponse {
                total_bytes: if k == 0 { total_bytes } else { 0 },
                data: file[start..end].to_vec(),
            })
        }));
        Ok(Response::new(Box::pin(stream)))
    }

    async fn get_slices(
        &self,
        request: Request<pb::GetSlicesRequest>,
    ) -> Result<Response<pb::GetSlicesResponse>, Status> {
        use pb::get_slices_request::Surface;
        let r = request.get_ref();
        let at = convert::slice_positions(r).or_status()?;
        let name = match &r.surface {
            Some(Surface::Resection(n)) => n,
            Some(Surface::Model(_)) => return Err(wire_status(&convert::model_slices())),
            None => return Err(missing_surface()),
        };
        let slices = self
            .service
            .slices(&r.session_id, name, at)
            .await
            .or_status()?;
        Ok(Response::new(convert::slices(&slices)))
    }

    async fn get_label_slice(
        &self,
        request: Request<pb::GetLabelSliceRequest>,
    ) -> Result<Response<pb::GetLabelSliceResponse>, Status> {
        let r = request.get_ref();
        let (axis, position, pixel) = convert::label_slice_request(r).or_status()?;
        let slice = self
            .service
            .label_slice(&r.session_id, axis, position, pixel)
            .await
            .or_status()?;
        Ok(Response::new(convert::label_slice(&slice)))
    }

    async fn get_resectogram(
        &self,
        request: Request<pb::GetResectogramRequest>,
    ) -> Result<Response<pb::GetResectogramResponse>, Status> {
        let r = request.get_ref();
        let (name, width, height) = convert::resectogram_request(r).or_status()?;
        let g = self
            .service
            .resectogram(&r.session_id, &name, width, height)
            .await
            .or_status()?;
        Ok(Response::new(convert::resectogram(
            g.plan_version,
            &g.value,
        )))
    }

    async fn get_risk_map(
        &self,
        request: Request<pb::GetRiskMapRequest>,
    ) -> Result<Response<pb::GetRiskMapResponse>, Status> {
        let r = request.get_ref();
        let m = self.service.risk_map(&r.session_id).await.or_status()?;
        Ok(Response::new(
            convert::risk_map(m.plan_version, &m.value).or_status()?,
        ))
    }

    async fn reconstruct_points(
        &self,
        request: Request<pb::ReconstructPointsRequest>,
    ) -> Result<Response<pb::ReconstructPointsResponse>, Status> {
        let cloud = convert::point_cloud(request.into_inner()).or_status()?;
        let surface = self.service.reconstruct_points(cloud).await.or_status()?;
        Ok(Response::new(
            convert::point_cloud_surface(surface).or_status()?,
        ))
    }

    type WatchStream = BoxStream<pb::WatchResponse>;

    async fn watch(
        &self,
        request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchStream>, Status> {
        let r = request.into_inner();
        resecta_face::watch::check_payloads(&self.service, &r).or_status()?;
        let stream =
            resecta_face::watch::watch(Arc::clone(&self.service), r.session_id, r.since_seq)
                .await
                .or_status()?
                .map(|m| m.map_err(|e| face_status(&e)));
        let stream = until_shutdown(stream, self.shutdown.clone(), unavailable);
        Ok(Response::new(Box::pin(stream)))
    }
}
