//! The HTTP face over real sockets: sessions, uploads, reconstruction and watch streams as
//! server-sent events, edits with versions, errors as problem documents, access, limits,
//! request ids, metrics, and the OpenAPI document against the router.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use axum::body::{Body, Bytes};
use base64::Engine;
use base64::engine::general_purpose::STANDARD;
use common::*;
use futures_util::StreamExt;
use http::StatusCode;
use resecta_auth::AccessPolicy;
use resecta_delta::{DecodeLimits, apply_delta, decode_mesh};
use resecta_http::HttpOptions;
use resecta_session::ServiceConfig;
use serde_json::{Value, json};

fn init_edit(base: u64) -> Value {
    json!({"baseVersion": base.to_string(), "initFromEndPoint": {"name": "r1", "endPoint": {"x": -30.0}}})
}

fn drag_edit(base: u64, point: Value) -> Value {
    json!({"baseVersion": base.to_string(), "setControlPoint": {"name": "r1", "i": 1, "j": 2, "point": point}})
}

fn xyz(x: f64, y: f64, z: f64) -> Value {
    json!({"x": x, "y": y, "z": z})
}

/// A uint64 of a proto JSON answer (a decimal string).
fn u64_of(v: &Value) -> u64 {
    v.as_str().unwrap_or("0").parse().unwrap()
}

async fn plan_version(addr: std::net::SocketAddr, id: &str) -> u64 {
    u64_of(&get(addr, &format!("/v1/sessions/{id}")).await.json()["session"]["planVersion"])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_crud_and_unknown_ids() {
    let s = open_server().await;
    let info = get(s.addr, "/v1/info").await;
    assert_eq!(info.status, StatusCode::OK);
    assert_eq!(info.json()["apiVersion"], "resecta.v1");
    // True to the configuration: PSR, MCSD and deltas; the default encoder neither compresses nor
    // quantises, and this server needs no token.
    let mut caps: Vec<String> =
        serde_json::from_value(info.json()["capabilities"].clone()).unwrap();
    caps.sort();
    assert_eq!(caps, ["mcsd", "psr", "watch-deltas"]);

    let created = post_json(s.addr, "/v1/sessions", &json!({"displayName": "Demo"})).await;
    assert_eq!(created.status, StatusCode::CREATED);
    let id = created.json()["session"]["id"].as_str().unwrap().to_owned();
    assert_eq!(created.headers["location"], format!("/v1/sessions/{id}"));
    assert_eq!(created.json()["session"]["state"], "SESSION_STATE_EMPTY");

    let list = get(s.addr, "/v1/sessions").await.json();
    assert_eq!(list["sessions"].as_array().unwrap().len(), 1);
    let one = get(s.addr, &format!("/v1/sessions/{id}")).await;
    assert_eq!(one.json()["session"]["displayName"], "Demo");

    let del = send(
        s.addr,
        request("DELETE", &format!("/v1/sessions/{id}"), Body::empty()),
    )
    .await;
    assert_eq!(del.status, StatusCode::OK);
    assert_eq!(del.json(), json!({}));
    get(s.addr, &format!("/v1/sessions/{id}"))
        .await
        .problem(404, "SESSION_NOT_FOUND");
    get(s.addr, "/v1/sessions/nope/volumes")
        .await
        .problem(404, "SESSION_NOT_FOUND");
    get(s.addr, "/v1/nothing").await.problem(404, "NO_ROUTE");
    send(s.addr, request("PATCH", "/v1/sessions", Body::empty()))
        .await
        .problem(405, "METHOD_NOT_ALLOWED");
    // Bad input of the operation layer: an empty display name.
    post_json(s.addr, "/v1/sessions", &json!({"displayName": ""}))
        .await
        .problem(400, "INVALID_ARGUMENT");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_json_and_bad_queries_are_problems() {
    let s = open_server().await;
    let a = send(
        s.addr,
        json_request("POST", "/v1/sessions", &json!(null)).map(|_| Body::from("{\"displayName\":")),
    )
    .await;
    let p = a.problem(400, "INVALID_ARGUMENT");
    assert!(
        p["detail"].as_str().unwrap().contains("request body"),
        "{p}"
    );
    post_json(s.addr, "/v1/sessions", &json!({"name": 3}))
        .await
        .problem(400, "INVALID_ARGUMENT");
    let id = create_session(s.addr, "Q").await;
    for q in [
        "watch?since_seq=abc",
        "watch?sinceSeq=1&nope=2",
        "watch?allowZstd=maybe",
        "models/x?format=gif",
        "models/x",
        "slices?resection=r1&axial=north",
    ] {
        get(s.addr, &format!("/v1/sessions/{id}/{q}"))
            .await
            .problem(400, "INVALID_ARGUMENT");
    }
    // The body naming another session than the path.
    post_json(
        s.addr,
        &format!("/v1/sessions/{id}/edits"),
        &json!({"sessionId": "other", "undo": {}}),
    )
    .await
    .problem(400, "INVALID_ARGUMENT");
    // No label map yet: failed precondition.
    get(s.addr, &format!("/v1/sessions/{id}/volumes"))
        .await
        .problem(409, "NO_LABEL_MAP");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_and_file_label_maps_upload() {
    let s = open_server().await;
    let labels = phantom();
    let id = create_session(s.addr, "Upload").await;
    let url = |q: &str| format!("/v1/sessions/{id}/label-map?{q}");

    // Geometry not matching the data length: 400, nothing loaded.
    let mut short = raw_bytes(&labels);
    short.pop();
    let p = send(s.addr, request("PUT", &url(&raw_query(&labels)), short))
        .await
        .problem(400, "INVALID_ARGUMENT");
    assert!(p["detail"].as_str().unwrap().contains("bytes"), "{p}");
    // Missing geometry, wrong lengths, NaN spacing, bad roles, malformed JSON: 400.
    let header = raw_header(&labels);
    let with = |key: &str, v: Value| {
        let mut h = header.clone();
        h[key] = v;
        format!("raw={}", encode(&h.to_string()))
    };
    for q in [
        format!("raw={}", encode(r#"{"dataType":"DATA_TYPE_UINT8"}"#)),
        with("dims", json!([1, 2, 3, 4])),
        with("spacing", json!(["NaN", 1.0, 1.0])),
        with("roles", json!({"tumor": [0]})),
        with("dataType", json!("DATA_TYPE_UNSPECIFIED")),
        "raw=%7Bnope".to_owned(),
        format!("{}&file=%7B%7D", raw_query(&labels)),
    ] {
        let a = send(s.addr, request("PUT", &url(&q), raw_bytes(&labels))).await;
        a.problem(400, "INVALID_ARGUMENT");
    }
    let info = get(s.addr, &format!("/v1/sessions/{id}")).await.json();
    assert_eq!(info["session"]["state"], "SESSION_STATE_EMPTY");
    assert_eq!(info["session"].get("planVersion"), None);

    // Raw voxels with explicit roles.
    let q = with(
        "roles",
        json!({"parenchyma": [1], "tumor": [2], "portal": [3], "hepatic": [4]}),
    );
    let a = send(s.addr, request("PUT", &url(&q), raw_bytes(&labels))).await;
    assert_eq!(
        a.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&a.body)
    );
    let summary = a.json()["labelMap"].clone();
    let dims: Vec<usize> = serde_json::from_value(summary["dims"].clone()).unwrap();
    assert_eq!(dims, labels.grid().dims());
    let counts = labels.value_counts();
    let one = summary["labels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| l["label"] == 1)
        .unwrap();
    assert_eq!(Some(u64_of(&one["voxels"])), counts.get(&1).copied());

    // The same label map as a NIfTI file (format told from its bytes).
    let nifti =
        resecta_io::nifti::nifti_bytes(&resecta_io::Image::from_label_map(&labels), true).unwrap();
    let a = send(
        s.addr,
        request("PUT", &format!("/v1/sessions/{id}/label-map"), nifti),
    )
    .await;
    assert_eq!(
        a.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&a.body)
    );
    // The same voxels per label (the file's spacing is f32, so the volumes differ a little).
    let voxels = |summary: &Value| -> Vec<(Value, Value)> {
        summary["labels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| (l["label"].clone(), l["voxels"].clone()))
            .collect()
    };
    assert_eq!(voxels(&a.json()["labelMap"]), voxels(&summary));
    assert_eq!(plan_version(s.addr, &id).await, 2);
    let nifti_query = format!("file={}", encode(r#"{"format":"LABEL_MAP_FORMAT_NIFTI"}"#));
    send(s.addr, request("PUT", &url(&nifti_query), "not an image"))
        .await
        .problem(400, "BAD_LABEL_MAP");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_bodies_are_refused_while_streaming() {
    let limit = 1 << 20;
    let s = serve(
        ServiceConfig {
            max_upload_bytes: limit,
            max_voxels: 1000,
            max_sessions: 1,
            ..config()
        },
        AccessPolicy::open(),
        HttpOptions {
            max_json_bytes: 1024,
            ..HttpOptions::default()
        },
    )
    .await;
    let id = create_session(s.addr, "Big").await;
    let url = format!("/v1/sessions/{id}/label-map");

    // A declared length beyond the limit: refused at once, although the body never comes.
    let pending = futures_util::stream::once(async { Ok::<_, std::io::Error>(Bytes::from("x")) })
        .chain(futures_util::stream::pending());
    let mut req = request("PUT", &url, Body::from_stream(pending));
    req.headers_mut()
        .insert("content-length", (10u64 << 30).to_string().parse().unwrap());
    let a = tokio::time::timeout(Duration::from_secs(10), send(s.addr, req))
        .await
        .expect("refused before the body arrives");
    let p = a.problem(413, "PAYLOAD_TOO_LARGE");
    assert!(p["detail"].as_str().unwrap().contains(&limit.to_string()));

    // A chunked body is refused as soon as it passes the limit, although it has not ended.
    let chunk = || Ok::<_, std::io::Error>(Bytes::from(vec![0u8; 64 << 10]));
    let past_limit = futures_util::stream::iter((0..17).map(move |_| chunk()))
        .chain(futures_util::stream::pending());
    let req = request("PUT", &url, Body::from_stream(past_limit));
    tokio::time::timeout(Duration::from_secs(10), send(s.addr, req))
        .await
        .expect("refused before the body ends")
        .problem(413, "PAYLOAD_TOO_LARGE");

    // A client that keeps sending is not read to its end. (Without a lingering close it may see
    // the connection reset instead of the 413, as with any server that stops reading.)
    let pulled = Arc::new(AtomicUsize::new(0));
    let counter = Arc::clone(&pulled);
    let flood = futures_util::stream::iter(0..4096).map(move |_| {
        counter.fetch_add(1, Ordering::Relaxed);
        chunk()
    });
    if let Ok(res) = send_raw(s.addr, request("PUT", &url, Body::from_stream(flood))).await {
        assert_eq!(res.status(), StatusCode::PAYLOAD_TOO_LARGE);
    }
    let n = pulled.load(Ordering::Relaxed);
    assert!(n < 1024, "the client sent {n} chunks of 64 KiB");

    // JSON bodies have their own limit.
    let big = json!({"displayName": "x".repeat(2000)});
    post_json(s.addr, "/v1/sessions", &big)
        .await
        .problem(413, "PAYLOAD_TOO_LARGE");
    assert_eq!(plan_version(s.addr, &id).await, 0);

    // Quotas: an upload beyond the voxel quota is too large (413); one session too many is 429.
    let labels = phantom();
    let q = format!("/v1/sessions/{id}/label-map?{}", raw_query(&labels));
    send(s.addr, request("PUT", &q, raw_bytes(&labels)))
        .await
        .problem(413, "VOXEL_QUOTA");
    post_json(s.addr, "/v1/sessions", &json!({"displayName": "Second"}))
        .await
        .problem(429, "SESSION_QUOTA");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconstruction_streams_progress_models_and_done() {
    let s = open_server().await;
    let id = create_session(s.addr, "Recon").await;
    send(
        s.addr,
        request(
            "POST",
            &format!("/v1/sessions/{id}/reconstruct"),
            Body::empty(),
        ),
    )
    .await
    .problem(409, "NO_LABEL_MAP");
    let id = loaded_session(s.addr).await;
    let res = send_raw(
        s.addr,
        request(
            "POST",
            &format!("/v1/sessions/{id}/reconstruct"),
            Body::empty(),
        ),
    )
    .await
    .unwrap();
    let mut events = SseReader::new(res);
    let (mut progress, mut models, mut done) = (0, Vec::new(), None);
    while let Some(e) = events.next_event().await {
        match e.event.as_deref() {
            Some("progress") => progress += 1,
            Some("model") => models.push(e.json()["model"]["name"].as_str().unwrap().to_owned()),
            Some("done") => done = Some(e.json()),
            other => panic!("unexpected event {other:?}: {}", e.data),
        }
    }
    let done = done.expect("a done event");
    assert!(progress > 0);
    let done = &done["done"];
    assert_eq!(done["modelCount"].as_u64(), Some(models.len() as u64));
    assert_eq!(done.get("dropped"), None);
    assert_eq!(done["minComponentMm3"], 10.0);
    assert!(models.contains(&"tumor_1".to_owned()), "{models:?}");
    assert_eq!(
        get(s.addr, &format!("/v1/sessions/{id}")).await.json()["session"]["state"],
        "SESSION_STATE_READY"
    );

    // Models export as files.
    let a = get(
        s.addr,
        &format!("/v1/sessions/{id}/models/tumor_1?format=MODEL_FORMAT_STL"),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK);
    assert_eq!(a.content_type(), "model/stl");
    let mesh =
        resecta_io::mesh::read_mesh_bytes(&a.body, resecta_io::mesh::MeshFormat::Stl, "t.stl")
            .unwrap();
    assert!(!mesh.triangles().is_empty());
    get(
        s.addr,
        &format!("/v1/sessions/{id}/models/nothing?format=MODEL_FORMAT_VTP"),
    )
    .await
    .problem(404, "MODEL_NOT_FOUND");
}

/// Reconstructs with `body` and returns the `model` events' models.
async fn reconstructed(addr: std::net::SocketAddr, id: &str, body: &Value) -> Vec<Value> {
    let res = send_raw(
        addr,
        json_request("POST", &format!("/v1/sessions/{id}/reconstruct"), body),
    )
    .await
    .unwrap();
    assert_eq!(res.status(), StatusCode::OK);
    let mut events = SseReader::new(res);
    let (mut models, mut done) = (Vec::new(), false);
    while let Some(e) = events.next_event().await {
        match e.event.as_deref() {
            Some("progress") => {}
            Some("model") => models.push(e.json()["model"].clone()),
            Some("done") => done = true,
            other => panic!("unexpected event {other:?}: {}", e.data),
        }
    }
    assert!(done);
    models
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconstruction_options_in_the_body_are_honoured_or_refused() {
    let s = open_server().await;
    let id = loaded_session(s.addr).await;
    let url = format!("/v1/sessions/{id}/reconstruct");
    // What is wrong is named, and what the client sent is not repeated (issue #19): an unknown
    // enum value or field name is the client's text.
    for (body, unsaid) in [
        (json!({"method": "marching"}), "marching"),
        (json!({"smoothness": 0.5}), "smoothness"),
    ] {
        let p = post_json(s.addr, &url, &body)
            .await
            .problem(400, "INVALID_ARGUMENT");
        let detail = p["detail"].as_str().unwrap();
        assert!(!detail.contains(unsaid), "{body}: {p}");
        assert!(
            detail.contains("unknown") && detail.contains("expected one of `"),
            "{body}: {p}"
        );
    }
    for (body, needle) in [
        (json!({"options": {"psrDepth": 0}}), "psr_depth"),
        (json!({"options": {"psrDepth": 11}}), "psr_depth"),
        (
            json!({"method": "RECONSTRUCTION_METHOD_MCSD", "options": {"smoothing": 1.5}}),
            "smoothing",
        ),
        (json!({"options": {"decimation": 1.0}}), "decimation"),
        (
            json!({"options": {"minComponentMm3": -1}}),
            "min_component_mm3",
        ),
        (json!({"options": {"splitComponents": "yes"}}), "bool"),
    ] {
        let p = post_json(s.addr, &url, &body)
            .await
            .problem(400, "INVALID_ARGUMENT");
        assert!(p.to_string().contains(needle), "{body}: {p}");
    }
    send(s.addr, request("POST", &url, "{not json"))
        .await
        .problem(400, "INVALID_ARGUMENT");
    let liver = |models: &[Value]| {
        models
            .iter()
            .find(|m| m["name"] == "parenchyma")
            .cloned()
            .expect("parenchyma")
    };
    // An empty JSON object is the defaults: PSR for the liver.
    let psr = liver(&reconstructed(s.addr, &id, &json!({})).await);
    assert_eq!(psr["method"], "RECONSTRUCTION_METHOD_PSR");
    let mcsd = reconstructed(
        s.addr,
        &id,
        &json!({"method": "RECONSTRUCTION_METHOD_MCSD", "options": {"smoothing": 0.3, "decimation": 0.5}}),
    )
    .await;
    assert!(
        mcsd.iter()
            .all(|m| m["method"] == "RECONSTRUCTION_METHOD_MCSD"),
        "{mcsd:?}"
    );
    let m = liver(&mcsd);
    let rel = m["volumeMl"].as_f64().unwrap() / psr["volumeMl"].as_f64().unwrap() - 1.0;
    assert!(rel.abs() < 0.05, "MCSD {m} vs PSR {psr}");
    let coarse = liver(
        &reconstructed(
            s.addr,
            &id,
            &json!({"method": "RECONSTRUCTION_METHOD_PSR", "options": {"psrDepth": 4}}),
        )
        .await,
    );
    assert_eq!(coarse["method"], "RECONSTRUCTION_METHOD_PSR");
    assert!(u64_of(&coarse["triangleCount"]) < u64_of(&psr["triangleCount"]));
    let split = reconstructed(
        s.addr,
        &id,
        &json!({"options": {"splitComponents": true, "minComponentMm3": 0}}),
    )
    .await;
    let names: Vec<_> = split.iter().map(|m| (&m["name"], &m["label"])).collect();
    assert_eq!(
        names,
        [
            (&json!("parenchyma"), &json!(1)),
            (&json!("tumor_1"), &json!(2)),
            (&json!("portal_1"), &json!(3))
        ]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn edits_stream_to_watchers_with_resume_and_versions() {
    let s = open_server().await;
    let id = loaded_session(s.addr).await;
    let watch_url = format!("/v1/sessions/{id}/watch");
    let mut w = SseReader::watch(s.addr, &id).await;
    let snap = w.next_event().await.unwrap();
    assert_eq!(snap.event.as_deref(), Some("snapshot"));
    let first: u64 = snap.id.as_deref().unwrap().parse().unwrap();
    assert_eq!(u64_of(&snap.json()["seq"]), first);
    assert!(snap.json()["snapshot"].is_object());

    // A new resection: a whole mesh in the delta.
    let out = post_json(s.addr, &format!("/v1/sessions/{id}/edits"), &init_edit(1)).await;
    assert_eq!(
        out.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&out.body)
    );
    assert_eq!(out.json()["planVersion"], "2");
    assert_eq!(out.json()["resections"][0]["resection"]["name"], "r1");
    assert_eq!(out.json().get("removed"), None);
    let e = next_delta(&mut w).await;
    let mut last: u64 = e.id.as_deref().unwrap().parse().unwrap();
    assert!(last > first);
    let update = &e.json()["delta"]["resections"][0];
    let bytes = STANDARD
        .decode(update["fullMesh"].as_str().unwrap())
        .unwrap();
    let (_, mut frame) = decode_mesh(&bytes, &DecodeLimits::default()).unwrap();

    // A drag: a delta against it.
    let out = post_json(
        s.addr,
        &format!("/v1/sessions/{id}/edits"),
        &drag_edit(2, xyz(-8.0, 5.0, 4.0)),
    )
    .await;
    assert_eq!(out.json()["planVersion"], "3");
    let e = next_delta(&mut w).await;
    let seq: u64 = e.id.as_deref().unwrap().parse().unwrap();
    assert!(seq > last);
    last = seq;
    let r1 = e.json()["delta"]["resections"][0].clone();
    assert_eq!(r1.get("fullMesh"), None);
    assert_eq!(r1["resection"]["controlPoints"][6], xyz(-8.0, 5.0, 4.0));
    let delta = STANDARD.decode(r1["meshDelta"].as_str().unwrap()).unwrap();
    apply_delta(&mut frame, &delta, &DecodeLimits::default()).unwrap();

    // A late snapshot equals the frame the deltas built.
    let mut late = SseReader::watch(s.addr, &id).await;
    let snap = late.next_event().await.unwrap().json();
    let mesh = STANDARD
        .decode(
            snap["snapshot"]["resections"][0]["fullMesh"]
                .as_str()
                .unwrap(),
        )
        .unwrap();
    assert_eq!(
        decode_mesh(&mesh, &DecodeLimits::default()).unwrap().1,
        frame
    );

    // Resume: Last-Event-ID wins over sinceSeq; what follows `first` comes, no snapshot.
    let mut req = request(
        "GET",
        &format!("{watch_url}?sinceSeq={last}"),
        Body::empty(),
    );
    req.headers_mut()
        .insert("last-event-id", first.to_string().parse().unwrap());
    let mut again = SseReader::new(send_raw(s.addr, req).await.unwrap());
    let e = again.next_event().await.unwrap();
    assert_eq!(e.id.as_deref(), Some((first + 1).to_string().as_str()));
    assert_eq!(e.event.as_deref(), Some("delta"));
    let req = request(
        "GET",
        &format!("{watch_url}?since_seq={first}"),
        Body::empty(),
    );
    let mut by_query = SseReader::new(send_raw(s.addr, req).await.unwrap());
    assert_eq!(
        by_query.next_event().await.unwrap().id.as_deref(),
        Some((first + 1).to_string().as_str())
    );

    // A stale base version: 409 with the current version; nothing changes.
    let p = post_json(
        s.addr,
        &format!("/v1/sessions/{id}/edits"),
        &drag_edit(2, xyz(-9.0, 5.0, 4.0)),
    )
    .await
    .problem(409, "STALE_VERSION");
    assert_eq!(p["current_version"], 3);

    // NaN (a string in proto JSON), an index out of the grid, a missing point, two operations
    // in one request: refused with 400, and the plan stays.
    for edit in [
        drag_edit(3, json!({"x": "NaN"})),
        drag_edit(3, json!({"x": "Infinity"})),
        json!({"baseVersion": "3", "setControlPoint": {"name": "r1", "i": 99, "j": 2, "point": xyz(0.0, 0.0, 0.0)}}),
        json!({"baseVersion": "3", "setControlPoint": {"name": "r1", "i": 1, "j": 2}}),
        json!({"baseVersion": "3", "undo": {}, "redo": {}}),
        json!({"baseVersion": "3"}),
    ] {
        post_json(s.addr, &format!("/v1/sessions/{id}/edits"), &edit)
            .await
            .problem(400, "INVALID_ARGUMENT");
    }
    let huge =
        r#"{"baseVersion":"3","setControlPoint":{"name":"r1","i":1,"j":2,"point":{"x":1e999}}}"#;
    let a = send(
        s.addr,
        request("POST", &format!("/v1/sessions/{id}/edits"), huge),
    )
    .await;
    a.problem(400, "INVALID_ARGUMENT");
    post_json(
        s.addr,
        &format!("/v1/sessions/{id}/edits"),
        &json!({"translate": {"name": "nope", "delta": xyz(1.0, 0.0, 0.0)}}),
    )
    .await
    .problem(404, "RESECTION_NOT_FOUND");
    assert_eq!(plan_version(s.addr, &id).await, 3);

    // Volumes, slices, plan export and import.
    let v = get(s.addr, &format!("/v1/sessions/{id}/volumes"))
        .await
        .json();
    assert_eq!(v["planVersion"], "3");
    assert_eq!(v["volumes"]["complete"], true);
    let sl = get(
        s.addr,
        &format!("/v1/sessions/{id}/slices?resection=r1&axial=0&coronal=0"),
    )
    .await;
    assert_eq!(
        sl.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&sl.body)
    );
    let contour = &sl.json()["axial"][0];
    let points = STANDARD
        .decode(contour["points"].as_str().unwrap())
        .unwrap();
    assert!(!points.is_empty() && points.len() % 12 == 0);
    assert_eq!(sl.json().get("sagittal"), None);
    let plan = get(s.addr, &format!("/v1/sessions/{id}/plan")).await;
    assert_eq!(plan.content_type(), "application/json");
    assert_eq!(plan.json()["planVersion"], "3");
    let document = plan.json()["planJson"].as_str().unwrap().to_owned();
    let doc: Value = serde_json::from_str(&document).unwrap();
    assert_eq!(doc["format"], "resecta-plan/1");
    let plan_url = format!("/v1/sessions/{id}/plan");
    let import = json!({"planJson": document, "baseVersion": "3"});
    let imported = send(s.addr, json_request("PUT", &plan_url, &import)).await;
    assert_eq!(imported.json()["planVersion"], "4");
    send(s.addr, json_request("PUT", &plan_url, &import))
        .await
        .problem(409, "STALE_VERSION");
    let bad = json!({"planJson": "{\"format\":\"x\"}"});
    send(s.addr, json_request("PUT", &plan_url, &bad))
        .await
        .problem(400, "BAD_PLAN");

    // Deleting the session ends the watch stream.
    send(
        s.addr,
        request("DELETE", &format!("/v1/sessions/{id}"), Body::empty()),
    )
    .await;
    let end = tokio::time::timeout(Duration::from_secs(10), async {
        let mut last = None;
        while let Some(e) = w.next_event().await {
            last = Some(e);
        }
        last
    })
    .await
    .expect("the stream ends");
    let last = end.expect("an error event last");
    assert_eq!(last.event.as_deref(), Some("error"));
    assert_eq!(last.json()["code"], "SESSION_NOT_FOUND");
}

/// The next `delta` event (volumes and models events are skipped).
async fn next_delta(w: &mut SseReader) -> Sse {
    loop {
        let e = w.next_event().await.expect("stream open");
        if e.event.as_deref() == Some("delta") {
            return e;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_and_api_versions_are_checked() {
    let s = serve(
        config(),
        AccessPolicy::with_token(TOKEN).unwrap(),
        HttpOptions::default(),
    )
    .await;
    let with = |mut r: http::Request<Body>, auth: Option<&str>, version: Option<&str>| {
        if let Some(a) = auth {
            r.headers_mut().insert("authorization", a.parse().unwrap());
        }
        if let Some(v) = version {
            r.headers_mut()
                .insert("resecta-api-version", v.parse().unwrap());
        }
        r
    };
    let missing = get(s.addr, "/v1/sessions").await;
    missing.problem(401, "UNAUTHENTICATED");
    assert!(
        missing.headers["www-authenticate"]
            .to_str()
            .unwrap()
            .starts_with("Bearer")
    );
    let wrong = send(
        s.addr,
        with(
            request("GET", "/v1/sessions", Body::empty()),
            Some("Bearer 0123456789abcdef-wrong"),
            None,
        ),
    )
    .await;
    wrong.problem(401, "UNAUTHENTICATED");
    let good = format!("Bearer {TOKEN}");
    let ok = send(
        s.addr,
        with(
            request("GET", "/v1/sessions", Body::empty()),
            Some(&good),
            Some("v1"),
        ),
    )
    .await;
    assert_eq!(ok.status, StatusCode::OK);
    let p = send(
        s.addr,
        with(
            request("GET", "/v1/sessions", Body::empty()),
            Some(&good),
            Some("v2"),
        ),
    )
    .await
    .problem(400, "API_VERSION_MISMATCH");
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("v2") && detail.contains("v1"), "{detail}");
    // Open routes.
    for path in ["/v1/info", "/v1/openapi.json", "/healthz"] {
        assert_eq!(get(s.addr, path).await.status, StatusCode::OK, "{path}");
    }
    // Server info answers whatever version the client speaks.
    let info = send(
        s.addr,
        with(request("GET", "/v1/info", Body::empty()), None, Some("v2")),
    )
    .await;
    assert_eq!(info.status, StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_ids_are_echoed_or_made() {
    let s = open_server().await;
    let mut req = request("GET", "/v1/info", Body::empty());
    req.headers_mut()
        .insert("x-request-id", "client-42".parse().unwrap());
    assert_eq!(send(s.addr, req).await.headers["x-request-id"], "client-42");
    // Made when absent (also on problems), and replaced when unreasonable.
    let a = get(s.addr, "/v1/sessions/none").await;
    let made = a.headers["x-request-id"].to_str().unwrap();
    assert_eq!(made.len(), 36, "{made}");
    let mut req = request("GET", "/healthz", Body::empty());
    req.headers_mut()
        .insert("x-request-id", "x".repeat(200).parse().unwrap());
    let id = send(s.addr, req).await.headers["x-request-id"].clone();
    assert_eq!(id.len(), 36);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_are_served_when_rendered() {
    let s = serve(
        config(),
        AccessPolicy::with_token(TOKEN).unwrap(),
        HttpOptions {
            metrics: Some(Arc::new(|| "resecta_up 1\n".to_owned())),
            ..HttpOptions::default()
        },
    )
    .await;
    let a = get(s.addr, "/metrics").await;
    assert_eq!(a.status, StatusCode::OK);
    assert!(a.content_type().starts_with("text/plain"));
    assert_eq!(a.body, "resecta_up 1\n");
    let s = open_server().await;
    get(s.addr, "/metrics").await.problem(404, "NO_ROUTE");
}

/// Requests are counted per matched route (never the raw path) and status, as the server
/// process exports them (other tests of this binary may add to the counts).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_are_counted_by_route_and_status() {
    let recorder = metrics_exporter_prometheus::PrometheusBuilder::new().build_recorder();
    let handle = recorder.handle();
    metrics::set_global_recorder(recorder).unwrap();
    let s = serve(
        config(),
        AccessPolicy::open(),
        HttpOptions {
            metrics: Some(Arc::new(move || handle.render())),
            ..HttpOptions::default()
        },
    )
    .await;
    get(s.addr, "/v1/sessions/abc")
        .await
        .problem(404, "SESSION_NOT_FOUND");
    get(s.addr, "/v1/elsewhere").await.problem(404, "NO_ROUTE");
    let text = String::from_utf8(get(s.addr, "/metrics").await.body.to_vec()).unwrap();
    for line in [
        r#"resecta_http_requests_total{route="/v1/sessions/{id}",status="404"} "#,
        r#"resecta_http_requests_total{route="unmatched",status="404"} "#,
    ] {
        assert!(text.contains(line), "{line} missing in\n{text}");
    }
    assert!(!text.contains("abc") && !text.contains("elsewhere"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watch_streams_send_keep_alives() {
    let s = serve(
        config(),
        AccessPolicy::open(),
        HttpOptions {
            keep_alive: Duration::from_millis(50),
            ..HttpOptions::default()
        },
    )
    .await;
    let id = create_session(s.addr, "Quiet").await;
    let mut w = SseReader::watch(s.addr, &id).await;
    assert_eq!(
        w.next_event().await.unwrap().event.as_deref(),
        Some("snapshot")
    );
    let mut comments = 0;
    while comments < 2 {
        comments += w.next().await.unwrap().comments;
    }
}

/// Every route of the router is documented with its method, every documented operation is
/// routed (probed on the real router: it answers something other than "no route"), every RPC of
/// `PlanningService` is one route whose operation is named after it, and its schemas are the
/// RPC's messages with the proto fields' JSON names.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_openapi_document_matches_the_router_and_the_protos() {
    let doc: Value = serde_json::from_str(resecta_http::openapi_document()).unwrap();
    assert_eq!(doc["openapi"], "3.1.0");
    let paths = doc["paths"].as_object().unwrap();
    let mut documented = Vec::new();
    for (path, item) in paths {
        for method in item.as_object().unwrap().keys() {
            documented.push((method.to_uppercase(), path.clone()));
        }
    }
    documented.sort();
    let mut routed: Vec<(String, String)> = resecta_http::routes()
        .into_iter()
        .map(|r| (r.method.to_string(), r.path.to_owned()))
        .collect();
    routed.sort();
    assert_eq!(routed, documented);

    // Every RPC is one route, documented as that RPC with its messages.
    let rpcs = rpc_names();
    let mut covered: Vec<&str> = resecta_http::routes()
        .iter()
        .filter_map(|r| r.rpc)
        .collect();
    covered.sort_unstable();
    let mut expected: Vec<&str> = rpcs.iter().map(String::as_str).collect();
    expected.sort_unstable();
    assert_eq!(covered, expected);
    for r in resecta_http::routes() {
        let Some(rpc) = r.rpc else { continue };
        let op = &doc["paths"][r.path][r.method.as_str().to_lowercase()];
        assert_eq!(op["operationId"], rpc, "{} {}", r.method, r.path);
        let text = op.to_string();
        let (input, output) = (format!("{rpc}Request"), format!("{rpc}Response"));
        assert!(
            rpc == "UploadLabelMap" || rpc == "ExportModel" || text.contains(&output),
            "{rpc}: {text}"
        );
        if r.method == http::Method::POST || r.method == http::Method::PUT {
            assert!(
                rpc == "UploadLabelMap" || text.contains(&input),
                "{rpc}: {text}"
            );
        }
    }
    // The edit request's schema: the proto's fields by their JSON names (but `sessionId`, which
    // the path gives), enums by name without the refused UNSPECIFIED, exactly one edit.
    let schemas = &doc["components"]["schemas"];
    let edit = &schemas["resecta.v1.EditRequest"];
    for field in ["baseVersion", "setControlPoint", "addResection", "undo"] {
        assert!(
            edit["properties"].get(field).is_some(),
            "EditRequest.{field}: {edit}"
        );
    }
    assert_eq!(edit["properties"].get("sessionId"), None, "{edit}");
    assert_eq!(edit["properties"]["baseVersion"]["format"], "uint64");
    assert_eq!(edit["oneOf"].as_array().unwrap().len(), 20, "{edit}");
    assert_eq!(
        schemas["resecta.v1.ControlGroup"]["enum"],
        json!([
            "CONTROL_GROUP_INNER",
            "CONTROL_GROUP_OUTER",
            "CONTROL_GROUP_ALL"
        ])
    );
    // UNSPECIFIED means PSR there: offered.
    assert_eq!(
        schemas["resecta.v1.ReconstructionMethod"]["enum"][0],
        "RECONSTRUCTION_METHOD_UNSPECIFIED"
    );

    // Every $ref resolves.
    let text = resecta_http::openapi_document();
    let refs: Vec<&str> = text.split("\"$ref\":\"#/").skip(1).collect();
    assert!(refs.len() > 20, "{} refs", refs.len());
    for r in refs {
        let pointer = format!("/{}", &r[..r.find('"').unwrap()]);
        assert!(doc.pointer(&pointer).is_some(), "dangling $ref {pointer}");
    }

    let s = serve(
        config(),
        AccessPolicy::open(),
        HttpOptions {
            metrics: Some(Arc::new(String::new)),
            ..HttpOptions::default()
        },
    )
    .await;
    for (method, path) in &documented {
        let concrete = path
            .replace("{id}", "no-such-session")
            .replace("{name}", "x");
        let a = send(s.addr, request(method, &concrete, Body::empty())).await;
        let problem = a.content_type() == "application/problem+json";
        let code = if problem {
            a.json()["code"].clone()
        } else {
            Value::Null
        };
        assert!(
            code != "NO_ROUTE" && code != "METHOD_NOT_ALLOWED",
            "{method} {path}: {code}"
        );
    }
}

/// The methods of `resecta.v1.PlanningService`, from the descriptor set.
fn rpc_names() -> Vec<String> {
    use prost::Message;
    let set = prost_types::FileDescriptorSet::decode(resecta_api::FILE_DESCRIPTOR_SET).unwrap();
    set.file
        .iter()
        .flat_map(|f| &f.service)
        .filter(|s| s.name() == "PlanningService")
        .flat_map(|s| &s.method)
        .map(|m| m.name().to_owned())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_watch_streams_with_an_unavailable_error_event() {
    let (stop, stopped) = tokio::sync::watch::channel(false);
    let s = serve(
        config(),
        AccessPolicy::open(),
        HttpOptions {
            shutdown: Some(stopped),
            ..HttpOptions::default()
        },
    )
    .await;
    let id = create_session(s.addr, "Shutdown").await;
    let mut w = SseReader::watch(s.addr, &id).await;
    assert_eq!(
        w.next_event().await.unwrap().event.as_deref(),
        Some("snapshot")
    );
    stop.send(true).unwrap();
    let end = tokio::time::timeout(Duration::from_secs(10), w.next_event())
        .await
        .expect("the stream ends in time")
        .expect("an error event");
    assert_eq!(end.event.as_deref(), Some("error"));
    assert_eq!(end.json()["status"], 503);
    assert_eq!(end.json()["code"], "UNAVAILABLE");
    let after = tokio::time::timeout(Duration::from_secs(10), w.next_event()).await;
    assert!(
        matches!(after, Ok(None)),
        "the stream ends after the error event"
    );
}

/// The document's schema at `pointer` (under `components/schemas/`).
fn schema_at<'a>(doc: &'a Value, pointer: &str) -> &'a Value {
    doc.pointer(&format!("/components/schemas/{pointer}"))
        .unwrap_or_else(|| panic!("no schema at {pointer}"))
}

/// The bounds the OpenAPI document states are the limits `GET /v1/info` reports (both from the
/// constants the server enforces), and the server answers a request at each bound and refuses
/// one just beyond it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_document_states_the_limits_the_server_reports_and_enforces() {
    let doc: Value = serde_json::from_str(resecta_http::openapi_document()).unwrap();
    let s = open_server().await;
    let limits = get(s.addr, "/v1/info").await.json()["limits"].clone();
    let v1 = "resecta.v1.";
    let stated = |pointer: &str| schema_at(&doc, &format!("{v1}{pointer}")).clone();
    let reported = |name: &str| limits[name].clone();
    let n = |v: Value| v.as_f64().unwrap();
    for (pointer, limit) in [
        ("Resection/properties/gridM/minimum", "minControlPoints"),
        ("Resection/properties/gridN/maximum", "maxControlPoints"),
        (
            "InitFromEndPoint/properties/gridM/maximum",
            "maxControlPoints",
        ),
        ("SetResolution/properties/ru/minimum", "minResolution"),
        ("SetResolution/properties/rv/maximum", "maxResolution"),
        ("Resection/properties/ru/maximum", "maxResolution"),
        ("SetMargin/properties/marginMm/maximum", "maxMarginMm"),
        ("SetBand/properties/bandMm/maximum", "maxBandMm"),
        ("Resection/properties/name/maxLength", "maxNameBytes"),
        ("InitFromPlane/properties/name/maxLength", "maxNameBytes"),
        ("Vec3/properties/x/maximum", "maxCoordinateMm"),
        ("Rotate/properties/angleDeg/maximum", "maxRotationDeg"),
        (
            "CreateSessionRequest/properties/displayName/maxLength",
            "maxDisplayNameChars",
        ),
        (
            "ReconstructOptions/properties/psrDepth/minimum",
            "minPsrDepth",
        ),
        (
            "ReconstructOptions/properties/psrDepth/maximum",
            "maxPsrDepth",
        ),
        (
            "RawLabelMapHeader/properties/spacing/items/minimum",
            "minSpacingMm",
        ),
        (
            "RawLabelMapHeader/properties/spacing/items/maximum",
            "maxSpacingMm",
        ),
        (
            "RawLabelMapHeader/properties/origin/items/maximum",
            "maxOriginMm",
        ),
        (
            "GetLabelSliceRequest/properties/pixelMm/maximum",
            "maxLabelSlicePixelMm",
        ),
    ] {
        assert_eq!(
            n(stated(pointer)),
            n(reported(limit)),
            "{pointer} vs {limit}"
        );
        assert!(n(reported(limit)) > 0.0, "{limit}: {limits}");
    }
    let plan = schema_at(&doc, "PlanDocument");
    assert_eq!(
        n(plan["properties"]["resections"]["maxItems"].clone()),
        n(reported("maxResections"))
    );
    assert_eq!(plan["additionalProperties"], false);
    assert_eq!(plan["required"], json!(["format", "roles"]));
    let doc_text = resecta_http::openapi_document();
    assert!(
        doc_text.contains(&format!("at most {} bytes", n(reported("maxPlanBytes")))),
        "the plan's size limit is said"
    );

    // Display names: 1..=max characters, no control characters.
    let max = n(reported("maxDisplayNameChars")) as usize;
    let create = |name: String| async move {
        post_json(s.addr, "/v1/sessions", &json!({ "displayName": name })).await
    };
    assert_eq!(create("é".repeat(max)).await.status, StatusCode::CREATED);
    create("é".repeat(max + 1))
        .await
        .problem(400, "INVALID_ARGUMENT");
    create(String::new()).await.problem(400, "INVALID_ARGUMENT");
    create("tab\there".into())
        .await
        .problem(400, "INVALID_ARGUMENT");
    let pattern = schema_at(
        &doc,
        "resecta.v1.CreateSessionRequest/properties/displayName/pattern",
    );
    assert_eq!(pattern, r"^[^\u0000-\u001F\u007F-\u009F]*$");
    // An empty body is an empty name: the document requires a body there.
    let op = &doc["paths"]["/v1/sessions"]["post"];
    assert_eq!(op["requestBody"]["required"], true);
    send(s.addr, request("POST", "/v1/sessions", Body::empty()))
        .await
        .problem(400, "INVALID_ARGUMENT");

    // PSR depths: the bounds are taken (409: no label map yet), beyond them refused (400).
    let id = create_session(s.addr, "Depths").await;
    let depth = |d: f64| {
        let id = id.clone();
        async move {
            post_json(
                s.addr,
                &format!("/v1/sessions/{id}/reconstruct"),
                &json!({"options": {"psrDepth": d}}),
            )
            .await
        }
    };
    let (lo, hi) = (n(reported("minPsrDepth")), n(reported("maxPsrDepth")));
    for d in [lo, hi] {
        depth(d).await.problem(409, "NO_LABEL_MAP");
    }
    for d in [lo - 1.0, hi + 1.0, lo + 0.5] {
        depth(d).await.problem(400, "INVALID_ARGUMENT");
    }
}

/// JSON does not tell `4.0` from `4`, nor does JSON Schema's `integer`: integer fields take
/// integral numbers written either way (as protobuf's JSON parsers do), and refuse fractions.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn integer_fields_take_integral_numbers_in_any_form() {
    let s = open_server().await;
    let id = create_session(s.addr, "Integral").await;
    let edits = format!("/v1/sessions/{id}/edits");
    for base in [json!(0.0), json!(0e3), json!("0"), json!(0)] {
        post_json(s.addr, &edits, &json!({"baseVersion": base, "undo": {}}))
            .await
            .problem(409, "NO_LABEL_MAP");
    }
    for base in [json!(0.5), json!(-1.0), json!(1e30)] {
        post_json(s.addr, &edits, &json!({"baseVersion": base, "undo": {}}))
            .await
            .problem(400, "INVALID_ARGUMENT");
    }
    // Nested messages and repeated fields too: an upload header's dims.
    let labels = phantom();
    let mut header = raw_header(&labels);
    header["dims"] = json!(labels.grid().dims().map(|d| d as f64));
    let a = send(
        s.addr,
        request(
            "PUT",
            &format!(
                "/v1/sessions/{id}/label-map?raw={}",
                encode(&header.to_string())
            ),
            raw_bytes(&labels),
        ),
    )
    .await;
    assert_eq!(
        a.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&a.body)
    );
}

/// `DATA_TYPE_INT8` uploads as UINT8 does when every voxel is ≥ 0, and is refused (naming the
/// negative labels) when one is not; the document offers it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int8_raw_uploads_are_taken_and_negative_labels_refused() {
    let doc: Value = serde_json::from_str(resecta_http::openapi_document()).unwrap();
    let types = schema_at(&doc, "resecta.v1.DataType/enum");
    assert!(
        types.as_array().unwrap().contains(&json!("DATA_TYPE_INT8")),
        "{types}"
    );
    let s = open_server().await;
    let labels = phantom();
    let upload = |data_type: &str, bytes: Vec<u8>| {
        let mut header = raw_header(&labels);
        header["dataType"] = json!(data_type);
        async move {
            let id = create_session(s.addr, "Int8").await;
            let q = format!("raw={}", encode(&header.to_string()));
            send(
                s.addr,
                request("PUT", &format!("/v1/sessions/{id}/label-map?{q}"), bytes),
            )
            .await
        }
    };
    let unsigned = upload("DATA_TYPE_UINT8", raw_bytes(&labels)).await;
    let signed = upload("DATA_TYPE_INT8", raw_bytes(&labels)).await;
    assert_eq!(
        signed.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&signed.body)
    );
    assert_eq!(signed.json()["labelMap"], unsigned.json()["labelMap"]);
    let mut negative = raw_bytes(&labels);
    negative[7] = 0xff; // −1
    let p = upload("DATA_TYPE_INT8", negative)
        .await
        .problem(400, "INVALID_ARGUMENT");
    assert!(p["detail"].as_str().unwrap().contains("negative"), "{p}");
}

/// The `PlanDocument` schema is what the plan reader takes: a plan at every bound it states is
/// read, one just beyond any bound, with an unknown field or without a required one is refused.
#[test]
fn the_plan_document_schema_is_what_plans_take() {
    let doc: Value = serde_json::from_str(resecta_http::openapi_document()).unwrap();
    let plan = schema_at(&doc, "PlanDocument");
    let r = &plan["properties"]["resections"]["items"]["properties"];
    let int = |v: &Value| v.as_u64().unwrap() as usize;
    let num = |v: &Value| v.as_f64().unwrap();
    let (g_lo, g_hi) = (
        int(&r["grid"]["items"]["minimum"]),
        int(&r["grid"]["items"]["maximum"]),
    );
    let (s_lo, s_hi) = (
        int(&r["resolution"]["items"]["minimum"]),
        int(&r["resolution"]["items"]["maximum"]),
    );
    let margin = num(&r["margin_mm"]["maximum"]);
    let band = num(&r["band_mm"]["maximum"]);
    let coordinate = num(&r["control_points"]["items"]["items"]["maximum"]);
    let name_max = int(&r["name"]["maxLength"]);
    let most = int(&plan["properties"]["resections"]["maxItems"]);
    assert_eq!(r["margin_mm"]["exclusiveMinimum"], 0);
    assert_eq!(num(&r["band_mm"]["minimum"]), 0.0);

    let resection = |name: String, grid: [usize; 2]| {
        json!({"name": name, "grid": grid,
               "control_points": vec![[coordinate, -coordinate, 0.0]; grid[0] * grid[1]],
               "margin_mm": margin, "band_mm": band, "resolution": [s_lo, s_hi],
               "target": {"labels": [2], "points": [[coordinate, 0.0, -coordinate]]}})
    };
    let document = |resections: Vec<Value>| {
        json!({"format": plan["properties"]["format"]["const"],
               "roles": {"parenchyma": [1], "tumor": [2], "vessel": [65535]},
               "resections": resections})
    };
    let reads = |v: &Value| resecta_plan::Plan::from_json(&v.to_string()).is_ok();
    let edge = resection("n".repeat(name_max), [g_lo, g_hi]);
    assert!(reads(&document(vec![edge.clone()])));
    let many = (0..most)
        .map(|k| resection(format!("r{k}"), [g_lo, g_lo]))
        .collect::<Vec<_>>();
    assert!(reads(&document(many.clone())));
    let mut too_many = many;
    too_many.push(resection("one more".into(), [g_lo, g_lo]));
    assert!(!reads(&document(too_many)));

    let beyond: Vec<(&str, Value)> = vec![
        ("grid", json!([g_lo - 1, g_lo])),
        ("grid", json!([g_lo, g_hi + 1])),
        ("resolution", json!([s_lo - 1, s_lo])),
        ("resolution", json!([s_lo, s_hi + 1])),
        ("margin_mm", json!(0.0)),
        ("margin_mm", json!(margin * (1.0 + 1e-12))),
        ("band_mm", json!(-1e-9)),
        ("band_mm", json!(band * (1.0 + 1e-12))),
        ("name", json!("")),
        ("name", json!(" \u{3000}\t")),
        ("name", json!("n".repeat(name_max + 1))),
        ("kind", json!("plane")),
        ("surprise", json!(1)),
        ("target", json!({"labels": [0]})),
        ("target", json!({"colour": "red"})),
        (
            "control_points",
            json!([[coordinate * (1.0 + 1e-12), 0.0, 0.0]]),
        ),
    ];
    for (key, value) in beyond {
        let mut r = edge.clone();
        r[key] = value.clone();
        if key == "control_points" {
            let mut points = edge["control_points"].as_array().unwrap().clone();
            points[0] = value[0].clone();
            r[key] = Value::Array(points);
        }
        assert!(!reads(&document(vec![r])), "{key} = {value} was read");
    }
    for required in ["format", "roles"] {
        let mut d = document(vec![]);
        d.as_object_mut().unwrap().remove(required);
        assert!(!reads(&d), "a plan without {required} was read");
    }
    // Without tumour labels no resection can be planned (and ImportPlan refuses the plan too:
    // its role map is not the label map's, which has some).
    let mut d = document(vec![resection("r".into(), [g_lo, g_lo])]);
    d["roles"] = json!({"parenchyma": [1]});
    assert!(!reads(&d), "a plan without tumour labels was read");
    let mut d = document(vec![]);
    d["roles"] = json!({"tumor": [2], "portal": []});
    assert!(!reads(&d), "an empty role was read");
    d["roles"] = json!({"tumor": [2]});
    assert!(reads(&d));
    d["extra"] = json!(true);
    assert!(!reads(&d), "an unknown field was read");
}

/// `ReconstructPoints` over HTTP: a cloud of points as JSON arrays → the mesh (base64 `RSMS`)
/// and its report; malformed clouds and clouds beyond the configured limits are 400 problems
/// naming the field or the limit; the document states the ranges.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn point_clouds_close_over_http_and_bad_ones_are_problems() {
    let s = serve(
        ServiceConfig {
            max_cloud_points: 1000,
            max_cloud_depth: 6,
            ..config()
        },
        AccessPolicy::open(),
        HttpOptions::default(),
    )
    .await;
    const PATH: &str = "/v1/point-clouds/reconstruct";
    let sphere = |n: usize| -> Vec<f64> {
        (0..n)
            .flat_map(|k| {
                let z = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
                let (r, t) = ((1.0 - z * z).sqrt(), 2.399_963_229_728_653 * k as f64);
                [15.0 * r * t.cos(), 15.0 * r * t.sin(), 15.0 * z]
            })
            .collect()
    };
    let a = post_json(s.addr, PATH, &json!({"positions": sphere(600), "depth": 5})).await;
    assert_eq!(
        a.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&a.body)
    );
    let v = a.json();
    let mesh = STANDARD.decode(v["mesh"].as_str().unwrap()).unwrap();
    let (topology, frame) = decode_mesh(&mesh, &DecodeLimits::default()).unwrap();
    assert_eq!(v["vertexCount"], frame.positions.len().to_string());
    assert_eq!(v["triangleCount"], topology.triangles.len().to_string());
    assert_eq!(v["report"]["normals"], "NORMAL_SOURCE_ESTIMATED");
    assert_eq!(v["report"]["points"], 600);
    assert_eq!(v["report"]["depth"], 5);
    // Malformed, or beyond this server's limits: 400 naming the field or the limit.
    let cases = [
        (json!({}), "0 distinct points given"),
        (
            json!({"positions": [1.0, 2.0]}),
            "positions: needs x, y, z per point",
        ),
        (
            json!({"positions": sphere(600), "normals": [0.0, 0.0, 1.0]}),
            "normals: must be empty or hold as many values as positions",
        ),
        (
            json!({"positions": sphere(1001)}),
            "max_cloud_points (1000)",
        ),
        (
            json!({"positions": sphere(600), "depth": 7}),
            "max_cloud_depth",
        ),
        (
            json!({"positions": sphere(600), "depth": 4_000_000_000u32}),
            "max_cloud_depth",
        ),
        (
            json!({"positions": sphere(600), "neighbours": 2}),
            "neighbours 2",
        ),
        (
            json!({"positions": [1e6, 0.0, 0.0]}),
            "positions[0]: must be within",
        ),
    ];
    for (body, expected) in cases {
        let a = post_json(s.addr, PATH, &body).await;
        assert_eq!(a.status, StatusCode::BAD_REQUEST, "{body}");
        assert_eq!(a.content_type(), "application/problem+json");
        let p = a.json();
        assert_eq!(p["code"], "INVALID_ARGUMENT", "{p}");
        let detail = p["detail"].as_str().unwrap();
        assert!(
            detail.contains(expected),
            "{detail} (expected {expected:?})"
        );
    }
    // The limits are reported, and the document states what a schema can.
    let limits = get(s.addr, "/v1/info").await.json()["limits"].clone();
    assert_eq!(
        (
            limits["maxCloudPoints"].clone(),
            limits["maxCloudDepth"].clone()
        ),
        (json!(1000), json!(6))
    );
    let doc: Value = serde_json::from_str(resecta_http::openapi_document()).unwrap();
    let op = &doc["paths"][PATH]["post"];
    assert_eq!(op["operationId"], "ReconstructPoints");
    assert_eq!(op["requestBody"]["required"], true);
    let schema = &doc["components"]["schemas"]["resecta.v1.ReconstructPointsRequest"];
    assert_eq!(schema["required"], json!(["positions"]));
    assert_eq!(schema["properties"]["positions"]["minItems"], 12);
    assert_eq!(schema["properties"]["neighbours"]["maximum"], 64);
    assert!(
        schema["description"]
            .as_str()
            .unwrap()
            .contains("max_cloud_depth")
    );
}
