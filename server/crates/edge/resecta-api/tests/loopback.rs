//! The generated server and client stubs talk over real loopback TCP: the version header,
//! a client-streamed upload of full 4 MiB chunks, a server stream, and an error carrying
//! `resecta.v1.ErrorInfo` in the `google.rpc.Status` details as proto/README.md prescribes.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

use std::pin::Pin;

use prost::Message;
use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_api::v1::planning_service_server::{PlanningService, PlanningServiceServer};
use resecta_api::v1::*;
use resecta_api::{API_VERSION_HEADER, API_VERSION_HEADER_VALUE, ERROR_INFO_TYPE_URL};
use tokio_stream::Stream;
use tonic::{Code, Request, Response, Status, Streaming};

/// `google.rpc.Status`, the payload of `grpc-status-details-bin`.
#[derive(Clone, PartialEq, Message)]
struct RpcStatus {
    #[prost(int32, tag = "1")]
    code: i32,
    #[prost(string, tag = "2")]
    message: String,
    #[prost(message, repeated, tag = "3")]
    details: Vec<prost_types::Any>,
}

fn error(code: Code, message: &str, info: ErrorInfo) -> Status {
    let details = RpcStatus {
        code: code as i32,
        message: message.into(),
        details: vec![prost_types::Any {
            type_url: ERROR_INFO_TYPE_URL.into(),
            value: info.encode_to_vec(),
        }],
    };
    Status::with_details(code, message, details.encode_to_vec().into())
}

fn error_info(status: &Status) -> ErrorInfo {
    let s = RpcStatus::decode(status.details()).unwrap();
    assert_eq!(s.code, status.code() as i32);
    let any = &s.details[0];
    assert_eq!(any.type_url, ERROR_INFO_TYPE_URL);
    ErrorInfo::decode(any.value.as_slice()).unwrap()
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

const PLAN_VERSION: u64 = 5;
const MESSAGE_LIMIT: usize = resecta_api::MAX_CHUNK_BYTES + (64 << 10);

struct Fake;

#[tonic::async_trait]
impl PlanningService for Fake {
    async fn get_server_info(
        &self,
        request: Request<GetServerInfoRequest>,
    ) -> Result<Response<GetServerInfoResponse>, Status> {
        let client = request
            .metadata()
            .get(API_VERSION_HEADER)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("");
        Ok(Response::new(GetServerInfoResponse {
            server_version: "test".into(),
            api_version: resecta_api::API_VERSION.into(),
            capabilities: vec![format!("client:{client}")],
            limits: Some(ServerLimits {
                max_chunk_bytes: resecta_api::MAX_CHUNK_BYTES as u32,
                max_message_bytes: MESSAGE_LIMIT as u32,
                ..Default::default()
            }),
            compute: None,
        }))
    }
    async fn create_session(
        &self,
        _: Request<CreateSessionRequest>,
    ) -> Result<Response<CreateSessionResponse>, Status> {
        Err(Status::unimplemented("create_session"))
    }
    async fn list_sessions(
        &self,
        _: Request<ListSessionsRequest>,
    ) -> Result<Response<ListSessionsResponse>, Status> {
        Err(Status::unimplemented("list_sessions"))
    }
    async fn get_session(
        &self,
        _: Request<GetSessionRequest>,
    ) -> Result<Response<GetSessionResponse>, Status> {
        Err(Status::unimplemented("get_session"))
    }
    async fn delete_session(
        &self,
        _: Request<DeleteSessionRequest>,
    ) -> Result<Response<DeleteSessionResponse>, Status> {
        Err(Status::unimplemented("delete_session"))
    }
    async fn upload_label_map(
        &self,
        request: Request<Streaming<UploadLabelMapRequest>>,
    ) -> Result<Response<UploadLabelMapResponse>, Status> {
        let mut chunks = request.into_inner();
        let Some(first) = chunks.message().await? else {
            return Err(Status::invalid_argument("empty upload"));
        };
        let Some(upload_label_map_request::Header::Raw(header)) = first.header else {
            return Err(error(
                Code::InvalidArgument,
                "the first chunk must carry a header",
                ErrorInfo {
                    code: "BAD_CHUNK".into(),
                    field: "header".into(),
                    current_plan_version: None,
                    replica: None,
                },
            ));
        };
        let mut received = first.data.len() as u64;
        let mut checksum = first.data.iter().map(|&b| u64::from(b)).sum::<u64>();
        while let Some(chunk) = chunks.message().await? {
            received += chunk.data.len() as u64;
            checksum += chunk.data.iter().map(|&b| u64::from(b)).sum::<u64>();
        }
        if received != header.total_bytes {
            return Err(Status::invalid_argument("length"));
        }
        Ok(Response::new(UploadLabelMapResponse {
            label_map: Some(LabelMapSummary {
                dims: header.dims,
                labels: vec![LabelCount {
                    label: 1,
                    voxels: checksum,
                    volume_ml: 0.0,
                }],
                ..Default::default()
            }),
        }))
    }
    type ReconstructStream = BoxStream<ReconstructResponse>;
    async fn reconstruct(
        &self,
        _: Request<ReconstructRequest>,
    ) -> Result<Response<Self::ReconstructStream>, Status> {
        Err(Status::unimplemented("reconstruct"))
    }
    async fn edit(&self, request: Request<EditRequest>) -> Result<Response<EditResponse>, Status> {
        let base = request.into_inner().base_version;
        if base != 0 && base != PLAN_VERSION {
            return Err(error(
                Code::Aborted,
                &format!("edit against plan version {base}, the plan is at {PLAN_VERSION}"),
                ErrorInfo {
                    code: "STALE_VERSION".into(),
                    field: "base_version".into(),
                    current_plan_version: Some(PLAN_VERSION),
                    replica: None,
                },
            ));
        }
        Ok(Response::new(EditResponse {
            plan_version: PLAN_VERSION + 1,
            ..Default::default()
        }))
    }
    async fn get_volumes(
        &self,
        _: Request<GetVolumesRequest>,
    ) -> Result<Response<GetVolumesResponse>, Status> {
        Err(Status::unimplemented("get_volumes"))
    }
    async fn export_plan(
        &self,
        _: Request<ExportPlanRequest>,
    ) -> Result<Response<ExportPlanResponse>, Status> {
        Err(Status::unimplemented("export_plan"))
    }
    async fn import_plan(
        &self,
        _: Request<ImportPlanRequest>,
    ) -> Result<Response<ImportPlanResponse>, Status> {
        Err(Status::unimplemented("import_plan"))
    }
    type ExportModelStream = BoxStream<ExportModelResponse>;
    async fn export_model(
        &self,
        _: Request<ExportModelRequest>,
    ) -> Result<Response<Self::ExportModelStream>, Status> {
        Err(Status::unimplemented("export_model"))
    }
    async fn get_slices(
        &self,
        _: Request<GetSlicesRequest>,
    ) -> Result<Response<GetSlicesResponse>, Status> {
        Err(Status::unimplemented("get_slices"))
    }
    async fn get_label_slice(
        &self,
        _: Request<GetLabelSliceRequest>,
    ) -> Result<Response<GetLabelSliceResponse>, Status> {
        Err(Status::unimplemented("get_label_slice"))
    }
    async fn get_resectogram(
        &self,
        _: Request<GetResectogramRequest>,
    ) -> Result<Response<GetResectogramResponse>, Status> {
        Err(Status::unimplemented("get_resectogram"))
    }
    async fn get_risk_map(
        &self,
        _: Request<GetRiskMapRequest>,
    ) -> Result<Response<GetRiskMapResponse>, Status> {
        Err(Status::unimplemented("get_risk_map"))
    }
    async fn reconstruct_points(
        &self,
        _: Request<ReconstructPointsRequest>,
    ) -> Result<Response<ReconstructPointsResponse>, Status> {
        Err(Status::unimplemented("reconstruct_points"))
    }
    type WatchStream = BoxStream<WatchResponse>;
    async fn watch(
        &self,
        request: Request<WatchRequest>,
    ) -> Result<Response<Self::WatchStream>, Status> {
        let since = request.into_inner().since_seq.unwrap_or(0);
        let events = (since + 1..=since + 3).map(|seq| {
            Ok(WatchResponse {
                seq,
                plan_version: seq,
                event: Some(watch_response::Event::Delta(Delta {
                    removed: vec![format!("r{seq}")],
                    ..Default::default()
                })),
            })
        });
        Ok(Response::new(Box::pin(tokio_stream::iter(events))))
    }
}

#[tokio::test]
async fn stubs_work_over_loopback() {
    let incoming =
        tonic::transport::server::TcpIncoming::bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = incoming.local_addr().unwrap();
    let service = PlanningServiceServer::new(Fake).max_decoding_message_size(MESSAGE_LIMIT);
    let server = tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(service)
            .serve_with_incoming(incoming),
    );
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut client = PlanningServiceClient::with_interceptor(channel, |mut r: Request<()>| {
        r.metadata_mut().insert(
            API_VERSION_HEADER,
            API_VERSION_HEADER_VALUE.parse().unwrap(),
        );
        Ok(r)
    });

    let info = client
        .get_server_info(GetServerInfoRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.api_version, "resecta.v1");
    assert_eq!(info.capabilities, ["client:v1"]);

    // Two full chunks and a short one: 8 MiB + 3 bytes.
    let full = resecta_api::MAX_CHUNK_BYTES;
    let total = 2 * full + 3;
    let chunk = |i: usize, len: usize| UploadLabelMapRequest {
        header: (i == 0).then(|| {
            upload_label_map_request::Header::Raw(RawLabelMapHeader {
                session_id: "s".into(),
                dims: vec![total as u32, 1, 1],
                total_bytes: total as u64,
                ..Default::default()
            })
        }),
        data: vec![(i + 1) as u8; len],
    };
    let chunks = vec![chunk(0, full), chunk(1, full), chunk(2, 3)];
    let summary = client
        .upload_label_map(tokio_stream::iter(chunks))
        .await
        .unwrap()
        .into_inner()
        .label_map
        .unwrap();
    assert_eq!(summary.dims, [total as u32, 1, 1]);
    assert_eq!(summary.labels[0].voxels, (full + 2 * full + 3 * 3) as u64);

    let headerless = vec![UploadLabelMapRequest {
        header: None,
        data: vec![0; 8],
    }];
    let err = client
        .upload_label_map(tokio_stream::iter(headerless))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert_eq!(error_info(&err).code, "BAD_CHUNK");

    let stale = EditRequest {
        session_id: "s".into(),
        base_version: PLAN_VERSION - 1,
        edit: Some(edit_request::Edit::Undo(Undo {})),
    };
    let err = client.edit(stale).await.unwrap_err();
    assert_eq!(err.code(), Code::Aborted);
    let info = error_info(&err);
    assert_eq!(info.code, "STALE_VERSION");
    assert_eq!(info.current_plan_version, Some(PLAN_VERSION));
    let fresh = EditRequest {
        base_version: PLAN_VERSION,
        edit: Some(edit_request::Edit::Redo(Redo {})),
        ..Default::default()
    };
    assert_eq!(
        client.edit(fresh).await.unwrap().into_inner().plan_version,
        PLAN_VERSION + 1
    );

    let mut watch = client
        .watch(WatchRequest {
            session_id: "s".into(),
            since_seq: Some(10),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let mut seqs = Vec::new();
    while let Some(event) = watch.message().await.unwrap() {
        seqs.push(event.seq);
    }
    assert_eq!(seqs, [11, 12, 13]);

    let err = client
        .get_slices(GetSlicesRequest::default())
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::Unimplemented);
    server.abort();
}
