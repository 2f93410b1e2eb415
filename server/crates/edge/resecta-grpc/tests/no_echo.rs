//! No gRPC status carries client text (issue #19): over a real server and client, requests that
//! carry [`MARKER`] in ids, names, header values and uploaded files fail, and neither the status
//! message, nor its details (`grpc-status-details-bin`), nor any other metadata holds it. A
//! 10 KB session id is NOT_FOUND (echoed, it overflowed the client's metadata limit).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;

use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_api::v1::{self as pb, edit_request::Edit, upload_label_map_request::Header};
use resecta_auth::AccessPolicy;
use resecta_grpc::{MAX_MESSAGE_BYTES, error_info, grpc_routes};
use resecta_session::{Service, ServiceConfig};
use resecta_store::{MemoryStore, StoreOptions};
use tokio_stream::wrappers::TcpListenerStream;
use tonic::transport::Channel;
use tonic::{Code, Request, Status};

const MARKER: &str = "PATIENTMARKER";

type Client = PlanningServiceClient<Channel>;

async fn serve() -> Client {
    let service = Arc::new(Service::new(
        Arc::new(MemoryStore::new(StoreOptions::default())),
        ServiceConfig::default(),
    ));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(
        tonic::transport::Server::builder()
            .add_routes(grpc_routes(service, AccessPolicy::open()))
            .serve_with_incoming(TcpListenerStream::new(listener)),
    );
    let channel = Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    PlanningServiceClient::new(channel).max_decoding_message_size(MAX_MESSAGE_BYTES)
}

fn req<T>(msg: T) -> Request<T> {
    let mut r = Request::new(msg);
    r.metadata_mut()
        .insert(resecta_api::API_VERSION_HEADER, "v1".parse().unwrap());
    r
}

/// The refusal of `r`, checked: `code`, an `ErrorInfo`, and no marker anywhere in the status
/// (message, details, metadata). Returns the message.
fn refused<T: std::fmt::Debug>(case: &str, r: Result<T, Status>, code: Code) -> String {
    let s = r.expect_err(case);
    assert_eq!(s.code(), code, "{case}: {s:?}");
    assert!(error_info(&s).is_some(), "{case}: no ErrorInfo");
    let message = s.message().to_owned();
    assert!(
        !message.contains(MARKER),
        "{case}: the message echoes: {message}"
    );
    let details = String::from_utf8_lossy(s.details()).into_owned();
    assert!(!details.contains(MARKER), "{case}: the details echo");
    for kv in s.metadata().iter() {
        let text = format!("{kv:?}");
        assert!(!text.contains(MARKER), "{case}: metadata echoes: {text}");
    }
    let head: http::Response<tonic::body::Body> = s.clone().into_http();
    for (name, value) in head.headers() {
        assert!(
            !String::from_utf8_lossy(value.as_bytes()).contains(MARKER),
            "{case}: header {name} echoes"
        );
    }
    message
}

fn nhdr() -> Vec<u8> {
    format!(
        "NRRD0004\n# {MARKER}\ntype: {MARKER}\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\
         content: {MARKER}\ndata file: {MARKER}.raw\n"
    )
    .into_bytes()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn statuses_never_carry_client_text() {
    let mut c = serve().await;
    let id = c
        .create_session(req(pb::CreateSessionRequest {
            display_name: format!("{MARKER} liver"),
        }))
        .await
        .unwrap()
        .into_inner()
        .session
        .unwrap()
        .id;

    let long = format!("{MARKER}{}", "x".repeat(10_000));
    let m = refused(
        "10 KB id",
        c.get_session(req(pb::GetSessionRequest {
            session_id: long.clone(),
        }))
        .await,
        Code::NotFound,
    );
    assert!(m.len() < 100, "{m}");
    refused(
        "10 KB id, delete",
        c.delete_session(req(pb::DeleteSessionRequest {
            session_id: long.clone(),
        }))
        .await,
        Code::NotFound,
    );
    refused(
        "typed id",
        c.get_session(req(pb::GetSessionRequest {
            session_id: format!("Jane {MARKER}"),
        }))
        .await,
        Code::NotFound,
    );
    refused(
        "display name",
        c.create_session(req(pb::CreateSessionRequest {
            display_name: format!("{MARKER}\u{7}"),
        }))
        .await,
        Code::InvalidArgument,
    );
    let mut version = Request::new(pb::ListSessionsRequest::default());
    version.metadata_mut().insert(
        resecta_api::API_VERSION_HEADER,
        format!("v2-{MARKER}").parse().unwrap(),
    );
    refused(
        "version header",
        c.list_sessions(version).await,
        Code::FailedPrecondition,
    );

    let data = nhdr();
    let upload = vec![
        pb::UploadLabelMapRequest {
            header: Some(Header::File(pb::FileLabelMapHeader {
                session_id: id.clone(),
                format: pb::LabelMapFormat::Nrrd as i32,
                roles: None,
                total_bytes: data.len() as u64,
            })),
            data: Vec::new(),
        },
        pb::UploadLabelMapRequest { header: None, data },
    ];
    refused(
        "nhdr",
        c.upload_label_map(req(tokio_stream::iter(upload))).await,
        Code::InvalidArgument,
    );

    let m = refused(
        "edit before a label map, unknown resection",
        c.edit(req(pb::EditRequest {
            session_id: id.clone(),
            base_version: 0,
            edit: Some(Edit::SetMargin(pb::SetMargin {
                name: MARKER.into(),
                margin_mm: 5.0,
            })),
        }))
        .await,
        Code::FailedPrecondition,
    );
    assert!(m.contains("label map"), "{m}");
    refused(
        "edit on a 10 KB id",
        c.edit(req(pb::EditRequest {
            session_id: long.clone(),
            base_version: 0,
            edit: Some(Edit::Undo(pb::Undo {})),
        }))
        .await,
        Code::NotFound,
    );
    refused(
        "export on a 10 KB id",
        c.export_model(req(pb::ExportModelRequest {
            session_id: long,
            surface: Some(pb::export_model_request::Surface::Resection(MARKER.into())),
            format: pb::ModelFormat::Stl as i32,
        }))
        .await,
        Code::NotFound,
    );
    refused(
        "plan",
        c.import_plan(req(pb::ImportPlanRequest {
            session_id: id,
            plan_json: format!("{{\"format\": \"{MARKER}\"}}"),
            base_version: 0,
        }))
        .await,
        Code::InvalidArgument,
    );
}
