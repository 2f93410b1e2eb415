//! Both faces are one API: on one server, every RPC of `PlanningService` and its HTTP route are
//! called side by side with the same request, and the answers are equal after the proto JSON
//! mapping (the gRPC answer serialised by pbjson, the HTTP body parsed). The HTTP request bodies
//! are the pbjson serialisation of the very gRPC request messages.
// Test code; the JSON comparisons treat every other kind of value alike.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::wildcard_enum_match_arm
)]

mod common;

use std::sync::Arc;

use axum::body::Body;
use common::*;
use futures_util::StreamExt;
use http::StatusCode;
use resecta_api::v1 as pb;
use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_auth::AccessPolicy;
use resecta_grpc::{MAX_MESSAGE_BYTES, grpc_routes};
use resecta_http::{HttpOptions, router};
use resecta_session::Service;
use resecta_store::{MemoryStore, StoreOptions};
use serde::Serialize;
use serde_json::{Value, json};
use tonic::transport::Channel;

type Client = PlanningServiceClient<Channel>;

struct Faces {
    http: std::net::SocketAddr,
    grpc: Client,
}

async fn both() -> Faces {
    let service = Arc::new(Service::new(
        Arc::new(MemoryStore::new(StoreOptions::default())),
        config(),
    ));
    let app = router(
        Arc::clone(&service),
        AccessPolicy::open(),
        HttpOptions::default(),
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let http = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let routes = grpc_routes(service, AccessPolicy::open());
    tokio::spawn(
        tonic::transport::Server::builder()
            .add_routes(routes)
            .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
    );
    let channel = Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let grpc = PlanningServiceClient::new(channel).max_decoding_message_size(MAX_MESSAGE_BYTES);
    Faces { http, grpc }
}

/// A message's proto JSON (pbjson), as text and read back (as an HTTP client reads it: a
/// `float` then has its shortest decimal form, as on the wire).
fn pj(m: &impl Serialize) -> Value {
    serde_json::from_str(&serde_json::to_string(m).unwrap()).unwrap()
}

/// Fields that differ between two sessions with the same history, or between two calls (wall
/// times among them).
const VOLATILE: [&str; 9] = [
    "id",
    "sessionId",
    "createdMs",
    "lastAccessMs",
    "elapsedS",
    "seq",
    "normalsS",
    "solveS",
    "surfaceS",
];

fn masked(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(
            m.iter()
                .filter(|(k, _)| !VOLATILE.contains(&k.as_str()))
                .map(|(k, v)| (k.clone(), masked(v)))
                .collect(),
        ),
        Value::Array(a) => Value::Array(a.iter().map(masked).collect()),
        other => other.clone(),
    }
}

/// The first place where `a` and `b` differ (numbers within a relative 1e-9: parallel sums may
/// round differently), as a JSON pointer with both values.
fn difference(path: &str, a: &Value, b: &Value) -> Option<String> {
    let short = |v: &Value| v.to_string().chars().take(120).collect::<String>();
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            ((x - y).abs() > 1e-9 * x.abs().max(y.abs()).max(1.0))
                .then(|| format!("{path}: {x} vs {y}"))
        }
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                (Some(v), Some(w)) => difference(&format!("{path}/{k}"), v, w),
                (v, w) => Some(format!("{path}/{k}: {v:?} vs {w:?}")),
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(k, (v, w))| difference(&format!("{path}/{k}"), v, w)),
        _ => (a != b).then(|| format!("{path}: {} vs {}", short(a), short(b))),
    }
}

fn assert_same(what: &str, grpc: &Value, http: &Value) {
    if let Some(d) = difference("", &masked(grpc), &masked(http)) {
        panic!("{what}: gRPC and HTTP differ at {d}");
    }
}

async fn http_json(addr: std::net::SocketAddr, method: &str, path: &str, body: &Value) -> Value {
    let a = send(addr, json_request(method, path, body)).await;
    assert!(
        a.status.is_success(),
        "{method} {path}: {}",
        String::from_utf8_lossy(&a.body)
    );
    a.json()
}

/// The data events of a server-sent event stream, until it ends.
async fn http_events(addr: std::net::SocketAddr, req: http::Request<Body>, n: usize) -> Vec<Value> {
    let mut r = SseReader::new(send_raw(addr, req).await.unwrap());
    let mut out = Vec::new();
    while out.len() < n {
        let Some(e) = r.next_event().await else { break };
        assert_ne!(e.event.as_deref(), Some("error"), "{}", e.data);
        out.push(e.json());
    }
    out
}

fn init(id: &str, base: u64) -> pb::EditRequest {
    pb::EditRequest {
        session_id: id.into(),
        base_version: base,
        edit: Some(pb::edit_request::Edit::InitFromEndPoint(
            pb::InitFromEndPoint {
                name: "r1".into(),
                end_point: Some(pb::Vec3 {
                    x: -30.0,
                    y: 0.0,
                    z: 0.0,
                }),
                ..pb::InitFromEndPoint::default()
            },
        )),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_rpc_answers_the_same_on_both_faces() {
    let Faces { http, mut grpc } = both().await;
    let labels = phantom();
    let mut seen = Vec::new();
    let mut walked = |rpc: &str| seen.push(rpc.to_owned());

    // GetServerInfo == GET /v1/info, exactly.
    walked("GetServerInfo");
    let g = grpc
        .get_server_info(pb::GetServerInfoRequest {})
        .await
        .unwrap()
        .into_inner();
    let h = get(http, "/v1/info").await.json();
    assert_eq!(pj(&g), h);
    assert!(h["limits"]["maxMemoryBytes"].is_string(), "{h}");
    // The plan and upload limits are the constants the validation uses, on both faces.
    {
        use resecta_face::info::limits as k;
        let l = g.limits.as_ref().unwrap();
        let sides = (l.min_control_points as usize, l.max_control_points as usize);
        assert_eq!(sides, (k::MIN_CONTROL_POINTS, k::MAX_CONTROL_POINTS));
        let samples = (l.min_resolution as usize, l.max_resolution as usize);
        assert_eq!(samples, (k::MIN_RESOLUTION, k::MAX_RESOLUTION));
        assert_eq!(l.max_resections as usize, k::MAX_RESECTIONS);
        assert_eq!(
            (l.max_margin_mm, l.max_band_mm),
            (k::MAX_MARGIN_MM, k::MAX_MARGIN_MM)
        );
        assert_eq!(l.max_name_bytes as usize, k::MAX_NAME_LEN);
        assert_eq!(l.max_coordinate_mm, k::MAX_COORDINATE_MM);
        assert_eq!(l.max_rotation_deg, k::MAX_ANGLE_DEG);
        assert_eq!(l.max_display_name_chars as usize, k::MAX_DISPLAY_NAME);
        assert_eq!(l.max_plan_bytes as usize, k::MAX_PLAN_BYTES);
        assert_eq!(l.min_psr_depth..=l.max_psr_depth, k::PSR_DEPTHS);
        assert_eq!(l.min_spacing_mm..=l.max_spacing_mm, k::SPACING_MM);
        assert_eq!(
            (l.max_extent_mm, l.max_origin_mm),
            (k::MAX_EXTENT_MM, k::MAX_ORIGIN_MM)
        );
        assert_eq!(l.max_label_slice_side as usize, k::MAX_LABEL_SLICE_SIDE);
        assert_eq!(l.max_label_slice_pixel_mm, k::MAX_LABEL_SLICE_PIXEL_MM);
        assert_eq!(l.max_resectogram_side as usize, k::MAX_RESECTOGRAM_SIDE);
        let idle = config().idle_expiry.map_or(0, |d| d.as_secs());
        assert!(idle > 0);
        assert_eq!(l.session_idle_timeout_s, idle);
    }

    // One session per face, with the same history from here on.
    walked("CreateSession");
    let create = pb::CreateSessionRequest {
        display_name: "Side by side".into(),
    };
    let g = grpc
        .create_session(create.clone())
        .await
        .unwrap()
        .into_inner();
    let h = send(http, json_request("POST", "/v1/sessions", &pj(&create))).await;
    assert_eq!(h.status, StatusCode::CREATED);
    let h = h.json();
    assert_same("CreateSession", &pj(&g), &h);
    let (a, b) = (
        g.session.unwrap().id,
        h["session"]["id"].as_str().unwrap().to_owned(),
    );

    walked("GetSession");
    let g = grpc
        .get_session(pb::GetSessionRequest {
            session_id: a.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(http, &format!("/v1/sessions/{a}")).await.json();
    assert_same("GetSession", &pj(&g), &h);
    assert_eq!(h["session"]["id"], a.as_str());

    walked("ListSessions");
    let g = grpc
        .list_sessions(pb::ListSessionsRequest {})
        .await
        .unwrap()
        .into_inner();
    let h = get(http, "/v1/sessions").await.json();
    assert_same("ListSessions", &pj(&g), &h);
    assert_eq!(h["sessions"].as_array().unwrap().len(), 2);

    // UploadLabelMap: chunks on gRPC, one body on HTTP (the header's proto JSON in the query).
    walked("UploadLabelMap");
    let data = raw_bytes(&labels);
    let header: pb::RawLabelMapHeader = serde_json::from_value(raw_header(&labels)).unwrap();
    let first = pb::UploadLabelMapRequest {
        header: Some(pb::upload_label_map_request::Header::Raw(
            pb::RawLabelMapHeader {
                session_id: a.clone(),
                total_bytes: data.len() as u64,
                ..header.clone()
            },
        )),
        data: Vec::new(),
    };
    let rest = data.chunks(1 << 20).map(|c| pb::UploadLabelMapRequest {
        header: None,
        data: c.to_vec(),
    });
    let chunks: Vec<_> = std::iter::once(first).chain(rest).collect();
    let g = grpc
        .upload_label_map(tokio_stream::iter(chunks))
        .await
        .unwrap()
        .into_inner();
    let q = format!("raw={}", encode(&pj(&header).to_string()));
    let h = send(
        http,
        request("PUT", &format!("/v1/sessions/{b}/label-map?{q}"), data),
    )
    .await;
    assert_eq!(
        h.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&h.body)
    );
    assert_same("UploadLabelMap", &pj(&g), &h.json());

    // Reconstruct: the same events (MCSD: quick), streamed.
    walked("Reconstruct");
    let recon = |id: &str| pb::ReconstructRequest {
        session_id: id.into(),
        method: pb::ReconstructionMethod::Mcsd as i32,
        options: None,
    };
    let g: Vec<Value> = grpc
        .reconstruct(recon(&a))
        .await
        .unwrap()
        .into_inner()
        .map(|m| pj(&m.unwrap()))
        .collect()
        .await;
    let h = http_events(
        http,
        json_request(
            "POST",
            &format!("/v1/sessions/{b}/reconstruct"),
            &pj(&recon(&b)),
        ),
        usize::MAX,
    )
    .await;
    // Progress events are as many as the work reports; models and `done` are the answer.
    let answer = |events: &[Value]| -> Vec<Value> {
        events
            .iter()
            .filter(|e| e.get("progress").is_none())
            .cloned()
            .collect()
    };
    assert_same("Reconstruct", &json!(answer(&g)), &json!(answer(&h)));
    assert!(h.last().unwrap()["done"].is_object());

    // Edit: the HTTP body is the gRPC request's proto JSON, session id and all.
    walked("Edit");
    let drag = |id: &str, base| pb::EditRequest {
        session_id: id.into(),
        base_version: base,
        edit: Some(pb::edit_request::Edit::SetControlPoint(
            pb::SetControlPoint {
                name: "r1".into(),
                i: 1,
                j: 2,
                point: Some(pb::Vec3 {
                    x: -8.0,
                    y: 5.0,
                    z: 4.0,
                }),
            },
        )),
    };
    let mut added = None;
    for base in 1..=5u64 {
        let (ga, hb) = match base {
            1 => (init(&a, 1), init(&b, 1)),
            2 => (drag(&a, 2), drag(&b, 2)),
            // Adds back the resection an answer held, under another name.
            3 => {
                let mut r: pb::Resection = added.clone().unwrap();
                r.name = "r2".into();
                let add = |id: &str| pb::EditRequest {
                    session_id: id.into(),
                    base_version: 3,
                    edit: Some(pb::edit_request::Edit::AddResection(pb::AddResection {
                        resection: Some(r.clone()),
                    })),
                };
                (add(&a), add(&b))
            }
            4 => {
                let undo = |id: &str| pb::EditRequest {
                    session_id: id.into(),
                    base_version: 4,
                    edit: Some(pb::edit_request::Edit::Undo(pb::Undo {})),
                };
                (undo(&a), undo(&b))
            }
            // A stale version: the same refusal on both faces.
            _ => (drag(&a, 1), drag(&b, 1)),
        };
        let body = pj(&hb);
        if base == 1 {
            assert_eq!(
                body,
                json!({"sessionId": b, "baseVersion": "1",
                       "initFromEndPoint": {"name": "r1", "endPoint": {"x": -30.0}}})
            );
        }
        let g = grpc.edit(ga).await;
        let h = send(
            http,
            json_request("POST", &format!("/v1/sessions/{b}/edits"), &body),
        )
        .await;
        match g {
            Ok(g) => {
                let g = g.into_inner();
                assert_eq!(
                    h.status,
                    StatusCode::OK,
                    "{}",
                    String::from_utf8_lossy(&h.body)
                );
                assert_same(&format!("Edit {base}"), &pj(&g), &h.json());
                added = g.resections.first().and_then(|r| r.resection.clone());
            }
            Err(status) => {
                assert_eq!(status.code(), tonic::Code::Aborted);
                let info = resecta_grpc::error_info(&status).unwrap();
                let p = h.problem(409, "STALE_VERSION");
                assert_eq!(info.code, "STALE_VERSION");
                assert_eq!(
                    p["current_version"],
                    json!(info.current_plan_version.unwrap())
                );
            }
        }
    }

    walked("GetVolumes");
    let g = grpc
        .get_volumes(pb::GetVolumesRequest {
            session_id: a.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(http, &format!("/v1/sessions/{b}/volumes")).await.json();
    assert_same("GetVolumes", &pj(&g), &h);

    walked("ExportPlan");
    let g = grpc
        .export_plan(pb::ExportPlanRequest {
            session_id: a.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(http, &format!("/v1/sessions/{b}/plan")).await.json();
    assert_same("ExportPlan", &pj(&g), &h);

    walked("ImportPlan");
    let import = |id: &str| pb::ImportPlanRequest {
        session_id: id.into(),
        plan_json: g.plan_json.clone(),
        base_version: g.plan_version,
    };
    let gi = grpc.import_plan(import(&a)).await.unwrap().into_inner();
    let h = http_json(
        http,
        "PUT",
        &format!("/v1/sessions/{b}/plan"),
        &pj(&import(&b)),
    )
    .await;
    assert_same("ImportPlan", &pj(&gi), &h);

    // ExportModel: chunks on gRPC, the file as the body on HTTP; the same bytes.
    walked("ExportModel");
    let g: Vec<u8> = grpc
        .export_model(pb::ExportModelRequest {
            session_id: a.clone(),
            surface: Some(pb::export_model_request::Surface::Resection("r1".into())),
            format: pb::ModelFormat::Stl as i32,
        })
        .await
        .unwrap()
        .into_inner()
        .map(|c| c.unwrap().data)
        .concat()
        .await;
    let h = get(
        http,
        &format!("/v1/sessions/{b}/models/r1?format=MODEL_FORMAT_STL"),
    )
    .await;
    assert_eq!(h.status, StatusCode::OK);
    assert!(!g.is_empty());
    assert_eq!(g, h.body.to_vec());

    walked("GetSlices");
    let g = grpc
        .get_slices(pb::GetSlicesRequest {
            session_id: a.clone(),
            surface: Some(pb::get_slices_request::Surface::Resection("r1".into())),
            axial: Some(0.0),
            coronal: Some(0.0),
            sagittal: None,
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(
        http,
        &format!("/v1/sessions/{b}/slices?resection=r1&axial=0&coronal=0"),
    )
    .await
    .json();
    assert_same("GetSlices", &pj(&g), &h);
    assert!(h["axial"].as_array().is_some_and(|a| !a.is_empty()), "{h}");

    walked("GetLabelSlice");
    let g = grpc
        .get_label_slice(pb::GetLabelSliceRequest {
            session_id: a.clone(),
            axis: pb::SliceAxis::Coronal.into(),
            position_mm: 0.0,
            pixel_mm: Some(2.0),
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(
        http,
        &format!("/v1/sessions/{b}/label-slice?axis=SLICE_AXIS_CORONAL&positionMm=0&pixelMm=2"),
    )
    .await
    .json();
    assert_same("GetLabelSlice", &pj(&g), &h);
    assert!(
        g.labels.chunks(2).any(|l| l != [0, 0]),
        "the plane cuts the liver"
    );

    walked("GetResectogram");
    let g = grpc
        .get_resectogram(pb::GetResectogramRequest {
            session_id: a.clone(),
            resection: "r1".into(),
            width: 40,
            height: 30,
        })
        .await
        .unwrap()
        .into_inner();
    let h = get(
        http,
        &format!("/v1/sessions/{b}/resectogram?resection=r1&width=40&height=30"),
    )
    .await
    .json();
    assert_same("GetResectogram", &pj(&g), &h);
    assert_eq!((g.classes.len(), g.territories.len()), (1200, 1200));
    assert!(g.classes.iter().any(|&c| c > 0), "the cut meets the liver");

    walked("GetRiskMap");
    let g = grpc
        .get_risk_map(pb::GetRiskMapRequest {
            session_id: a.clone(),
        })
        .await;
    let h = get(http, &format!("/v1/sessions/{b}/risk-map")).await;
    match g {
        Ok(g) => {
            let g = g.into_inner();
            assert_same("GetRiskMap", &pj(&g), &h.json());
            let n: u32 = g.dims.iter().product();
            let classes = zstd::bulk::decompress(&g.classes_zstd, n as usize).unwrap();
            assert_eq!(classes.len(), n as usize);
            assert!(classes.contains(&1), "a functional remnant");
        }
        Err(status) => {
            // The small phantom's cut may leave no complete plan: refused alike.
            assert_eq!(status.code(), tonic::Code::FailedPrecondition, "{status:?}");
            assert_eq!(h.status, StatusCode::CONFLICT);
        }
    }

    // Watch: the first snapshot (its parts) of each session.
    walked("Watch");
    let mut gw = grpc
        .watch(pb::WatchRequest {
            session_id: a.clone(),
            ..pb::WatchRequest::default()
        })
        .await
        .unwrap()
        .into_inner();
    let g = pj(&gw.next().await.unwrap().unwrap());
    let h = http_events(
        http,
        request("GET", &format!("/v1/sessions/{b}/watch"), Body::empty()),
        1,
    )
    .await;
    assert!(g["snapshot"]["complete"] == json!(true), "one part");
    // Volumes are recomputed in the background: a snapshot may come before or after them.
    let without_volumes = |mut v: Value| {
        v["snapshot"].as_object_mut().unwrap().remove("volumes");
        v
    };
    assert_same("Watch", &without_volumes(g), &without_volumes(h[0].clone()));

    // ReconstructPoints: no session; a small sphere of points without normals.
    walked("ReconstructPoints");
    let cloud = pb::ReconstructPointsRequest {
        positions: (0..300)
            .flat_map(|k| {
                let z = 1.0 - 2.0 * (k as f64 + 0.5) / 300.0;
                let (r, t) = ((1.0 - z * z).sqrt(), 2.399_963_229_728_653 * k as f64);
                [12.0 * r * t.cos(), 12.0 * r * t.sin(), 12.0 * z]
            })
            .collect(),
        depth: 5,
        ..pb::ReconstructPointsRequest::default()
    };
    let g = grpc
        .reconstruct_points(cloud.clone())
        .await
        .unwrap()
        .into_inner();
    let h = http_json(http, "POST", "/v1/point-clouds/reconstruct", &pj(&cloud)).await;
    assert_same("ReconstructPoints", &pj(&g), &h);
    let report = g.report.as_ref().unwrap();
    assert_eq!(
        (report.points, report.depth, report.neighbours),
        (300, 5, 10)
    );
    assert_eq!(report.normals, pb::NormalSource::Estimated as i32);
    assert!(g.vertex_count > 100 && g.mesh.starts_with(b"RSMS"), "{g:?}");
    // Refused alike, naming the field.
    let bad = pb::ReconstructPointsRequest {
        positions: vec![1.0; 13],
        ..pb::ReconstructPointsRequest::default()
    };
    let status = grpc.reconstruct_points(bad.clone()).await.unwrap_err();
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    let h = send(
        http,
        json_request("POST", "/v1/point-clouds/reconstruct", &pj(&bad)),
    )
    .await;
    assert_eq!(h.status, StatusCode::BAD_REQUEST);
    assert_eq!(h.json()["detail"], status.message());

    walked("DeleteSession");
    let g = grpc
        .delete_session(pb::DeleteSessionRequest {
            session_id: a.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    let h = send(
        http,
        request("DELETE", &format!("/v1/sessions/{b}"), Body::empty()),
    )
    .await;
    assert_eq!(pj(&g), h.json());

    // Every RPC of the service was walked, each once.
    let mut rpcs: Vec<String> = resecta_http::routes()
        .iter()
        .filter_map(|r| r.rpc.map(str::to_owned))
        .collect();
    rpcs.sort();
    seen.sort();
    assert_eq!(seen, rpcs);
}
