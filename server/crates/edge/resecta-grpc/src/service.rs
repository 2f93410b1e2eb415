//! `resecta.v1.PlanningService` over [`resecta_session::Service`]: every RPC translates its
//! request with [`crate::convert`], calls the operation once and translates the answer.

use std::pin::Pin;
use std::sync::Arc;

use futures_util::{Stream, StreamExt};
use resecta_api::MAX_CHUNK_BYTES;
use resecta_api::v1 as pb;
use resecta_api::v1::planning_service_server::PlanningService;
use resecta_session::Service;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use crate::MAX_MESSAGE_BYTES;
use crate::convert;
use crate::error::{OrStatus, WireError, session_status};
use crate::shutdown::{ShutdownSignal, until_shutdown};
use crate::upload::Upload;

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
    WireError::invalid("surface", "is required (model or resection)").into()
}

fn saturating_u32(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

#[tonic::async_trait]
impl PlanningService for Planning {
    async fn get_server_info(
        &self,
        _request: Request<pb::GetServerInfoRequest>,
    ) -> Result<Response<pb::GetServerInfoResponse>, Status> {
        let info = self.service.info();
        let config = self.service.config();
        Ok(Response::new(pb::GetServerInfoResponse {
            server_version: info.version.to_owned(),
            api_version: info.api_version.to_owned(),
            capabilities: info.capabilities,
            limits: Some(pb::ServerLimits {
                max_voxels: info.limits.max_voxels,
                max_sessions: saturating_u32(info.limits.max_sessions),
                max_upload_bytes: info.limits.max_upload_bytes,
                max_chunk_bytes: saturating_u32(MAX_CHUNK_BYTES),
                max_message_bytes: saturating_u32(MAX_MESSAGE_BYTES),
                max_resections: saturating_u32(resecta_plan::MAX_RESECTIONS),
                max_control_points: saturating_u32(resecta_bezier::MAX_CONTROL_POINTS),
                max_resolution: saturating_u32(resecta_plan::resection::MAX_RESOLUTION),
                session_idle_timeout_s: config.idle_expiry.map_or(0, |d| d.as_secs()),
            }),
        }))
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
        let first = chunks
            .message()
            .await?
            .ok_or_else(|| WireError::bad_chunk("header", "the upload stream is empty"))?;
        let max = self.service.config().max_upload_bytes;
        let mut upload = Upload::start(first.header.as_ref(), max)?;
        // An unknown session fails before any data is taken in.
        self.service
            .get_session(&upload.session_id)
            .await
            .or_status()?;
        upload.push(first, true)?;
        while let Some(chunk) = chunks.message().await? {
            upload.push(chunk, false)?;
        }
        let (id, source, roles) = upload.finish()?;
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
        let options = convert::reconstruct_options(&r)?;
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
        let stream = until_shutdown(stream, self.shutdown.clone());
        Ok(Response::new(Box::pin(stream)))
    }

    async fn edit(
        &self,
        request: Request<pb::EditRequest>,
    ) -> Result<Response<pb::EditResponse>, Status> {
        let r = request.into_inner();
        let op = convert::edit(r.edit.as_ref())?;
        let out = self
            .service
            .edit(&r.session_id, r.base_version, op)
            .await
            .or_status()?;
        let answer = pb::EditResponse {
            plan_version: out.plan_version,
            resections: out
                .resections
                .iter()
                .map(|r| pb::ResectionStatus {
                    resection: Some(convert::resection(&r.resection)),
                    verdict: r.verdict.as_ref().map(convert::verdict),
                })
                .collect(),
            removed: out.removed,
        };
        Ok(Response::new(answer))
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
        let format = convert::mesh_format(r.format)?;
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
        let at = convert::slice_positions(r)?;
        let name = match &r.surface {
            Some(Surface::Resection(n)) => n,
            Some(Surface::Model(_)) => {
                return Err(WireError::Unsupported {
                    field: "model".into(),
                    message: "slices of models are not supported yet; ask for a resection".into(),
                }
                .into());
            }
            None => return Err(missing_surface()),
        };
        let slices = self
            .service
            .slices(&r.session_id, name, at)
            .await
            .or_status()?;
        Ok(Response::new(convert::slices(&slices)))
    }

    type WatchStream = BoxStream<pb::WatchResponse>;

    async fn watch(
        &self,
        request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchStream>, Status> {
        let r = request.into_inner();
        let encode = &self.service.config().encode;
        let refuse = |field: &str, what: &str| -> Status {
            WireError::Precondition {
                field: field.to_owned(),
                message: format!(
                    "this server sends {what} mesh payloads; the client must accept them"
                ),
            }
            .into()
        };
        if encode.zstd_level.is_some() && !r.allow_zstd {
            return Err(refuse("allow_zstd", "zstd-compressed"));
        }
        if encode.quantise.is_some() && !r.allow_quantized {
            return Err(refuse("allow_quantized", "quantised"));
        }
        let stream =
            crate::watch::watch(Arc::clone(&self.service), r.session_id, r.since_seq).await?;
        let stream = until_shutdown(stream, self.shutdown.clone());
        Ok(Response::new(Box::pin(stream)))
    }
}
