//! A real server on 127.0.0.1:0 over the small phantom, and a minimal HTTP/1.1 client (hyper)
//! with a server-sent-events reader.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, dead_code)]

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::body::{Body, Bytes};
use futures_util::StreamExt;
use http::{HeaderMap, Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use resecta_auth::AccessPolicy;
use resecta_geom::LabelMap;
use resecta_http::{HttpOptions, router};
use resecta_phantom::{PhantomSpec, generate};
use resecta_session::{Service, ServiceConfig};
use resecta_store::{MemoryStore, StoreOptions};
use serde_json::Value;

pub const TOKEN: &str = "0123456789abcdef-test-token";

pub fn config() -> ServiceConfig {
    ServiceConfig {
        volumes_delay: Duration::from_millis(5),
        psr_depth: 6,
        ..ServiceConfig::default()
    }
}

pub struct Server {
    pub addr: SocketAddr,
    pub service: Arc<Service>,
}

pub async fn serve(config: ServiceConfig, policy: AccessPolicy, options: HttpOptions) -> Server {
    let service = Arc::new(Service::new(
        Arc::new(MemoryStore::new(StoreOptions::default())),
        config,
    ));
    let app = router(Arc::clone(&service), policy, options);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    Server { addr, service }
}

pub async fn open_server() -> Server {
    serve(config(), AccessPolicy::open(), HttpOptions::default()).await
}

pub fn phantom() -> LabelMap {
    generate(&PhantomSpec::small()).unwrap().labels
}

/// Sends `req` on a fresh connection; the response body streams.
pub async fn send_raw(addr: SocketAddr, req: Request<Body>) -> hyper::Result<Response<Body>> {
    let stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
        .await
        .unwrap();
    tokio::spawn(conn);
    let res = sender.send_request(req).await?;
    Ok(res.map(Body::new))
}

pub struct Answer {
    pub status: StatusCode,
    pub headers: HeaderMap,
    pub body: Bytes,
}

impl Answer {
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&self.body)))
    }

    pub fn content_type(&self) -> &str {
        self.headers
            .get(http::header::CONTENT_TYPE)
            .map_or("", |v| v.to_str().unwrap())
    }

    /// Asserts a problem document of `status` and `code`; returns it.
    pub fn problem(&self, status: u16, code: &str) -> Value {
        assert_eq!(
            self.status.as_u16(),
            status,
            "{}",
            String::from_utf8_lossy(&self.body)
        );
        assert_eq!(self.content_type(), "application/problem+json");
        let p = self.json();
        assert_eq!(p["code"], code, "{p}");
        assert_eq!(p["status"], status);
        assert!(p["type"].as_str().unwrap().ends_with(code));
        assert!(p["title"].is_string() && p["detail"].is_string());
        p
    }
}

pub async fn send(addr: SocketAddr, req: Request<Body>) -> Answer {
    let res = send_raw(addr, req).await.unwrap();
    let (parts, body) = res.into_parts();
    Answer {
        status: parts.status,
        headers: parts.headers,
        body: axum::body::to_bytes(body, usize::MAX).await.unwrap(),
    }
}

pub fn request(method: &str, path: &str, body: impl Into<Body>) -> Request<Body> {
    Request::builder()
        .method(method)
        .uri(path)
        .header("host", "localhost")
        .body(body.into())
        .unwrap()
}

pub fn json_request(method: &str, path: &str, body: &Value) -> Request<Body> {
    let mut r = request(method, path, body.to_string());
    r.headers_mut()
        .insert("content-type", "application/json".parse().unwrap());
    r
}

pub async fn get(addr: SocketAddr, path: &str) -> Answer {
    send(addr, request("GET", path, Body::empty())).await
}

pub async fn post_json(addr: SocketAddr, path: &str, body: &Value) -> Answer {
    send(addr, json_request("POST", path, body)).await
}

pub async fn create_session(addr: SocketAddr, name: &str) -> String {
    let a = post_json(
        addr,
        "/v1/sessions",
        &serde_json::json!({ "displayName": name }),
    )
    .await;
    assert_eq!(a.status, StatusCode::CREATED);
    a.json()["session"]["id"].as_str().unwrap().to_owned()
}

/// Percent-encodes a query value.
pub fn encode(v: &str) -> String {
    v.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// The `RawLabelMapHeader` of a label map (u8 voxels) as proto JSON.
pub fn raw_header(labels: &LabelMap) -> Value {
    let g = labels.grid();
    let d = g.direction();
    let o = g.origin();
    serde_json::json!({
        "dims": g.dims(),
        "spacing": g.spacing(),
        "origin": [o.x, o.y, o.z],
        "direction": (0..9).map(|n| d[(n / 3, n % 3)]).collect::<Vec<_>>(),
        "dataType": "DATA_TYPE_UINT8",
    })
}

/// The raw-upload query of a label map (u8 voxels).
pub fn raw_query(labels: &LabelMap) -> String {
    format!("raw={}", encode(&raw_header(labels).to_string()))
}

pub fn raw_bytes(labels: &LabelMap) -> Vec<u8> {
    labels.data().iter().map(|&v| v as u8).collect()
}

/// A session with the phantom loaded (plan version 1).
pub async fn loaded_session(addr: SocketAddr) -> String {
    let id = create_session(addr, "Phantom").await;
    let labels = phantom();
    let a = send(
        addr,
        request(
            "PUT",
            &format!("/v1/sessions/{id}/label-map?{}", raw_query(&labels)),
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
    id
}

/// One server-sent event.
#[derive(Debug, Default, Clone)]
pub struct Sse {
    pub id: Option<String>,
    pub event: Option<String>,
    pub data: String,
    /// Comment lines (keep-alives).
    pub comments: usize,
}

impl Sse {
    pub fn json(&self) -> Value {
        serde_json::from_str(&self.data).unwrap()
    }
}

/// Reads server-sent events from a streaming body.
pub struct SseReader {
    body: axum::body::BodyDataStream,
    buf: String,
}

impl SseReader {
    pub fn new(res: Response<Body>) -> Self {
        assert_eq!(res.status(), StatusCode::OK);
        let ct = res.headers()[http::header::CONTENT_TYPE].to_str().unwrap();
        assert!(ct.starts_with("text/event-stream"), "{ct}");
        Self {
            body: res.into_body().into_data_stream(),
            buf: String::new(),
        }
    }

    /// The watch stream of session `id` (from its snapshot).
    pub async fn watch(addr: SocketAddr, id: &str) -> Self {
        let path = format!("/v1/sessions/{id}/watch");
        Self::new(
            send_raw(addr, request("GET", &path, Body::empty()))
                .await
                .unwrap(),
        )
    }

    /// The next event (or comment block); `None` at the end of the stream.
    pub async fn next(&mut self) -> Option<Sse> {
        loop {
            if let Some(end) = self.buf.find("\n\n") {
                let block: String = self.buf.drain(..end + 2).collect();
                let mut e = Sse::default();
                let mut data = Vec::new();
                for line in block.lines() {
                    if line.starts_with(':') {
                        e.comments += 1;
                    } else if let Some((k, v)) = line.split_once(':') {
                        let v = v.strip_prefix(' ').unwrap_or(v);
                        match k {
                            "id" => e.id = Some(v.to_owned()),
                            "event" => e.event = Some(v.to_owned()),
                            "data" => data.push(v.to_owned()),
                            _ => {}
                        }
                    }
                }
                e.data = data.join("\n");
                return Some(e);
            }
            let chunk = tokio::time::timeout(Duration::from_secs(60), self.body.next())
                .await
                .expect("an event in time")?
                .unwrap();
            self.buf.push_str(std::str::from_utf8(&chunk).unwrap());
        }
    }

    /// The next event that is not a keep-alive comment.
    pub async fn next_event(&mut self) -> Option<Sse> {
        loop {
            let e = self.next().await?;
            if e.event.is_some() || !e.data.is_empty() {
                return Some(e);
            }
        }
    }
}
