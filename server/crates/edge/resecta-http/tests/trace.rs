//! Request logs: one span per request with method, matched route, status, latency and request
//! id; never bodies or display names. (Its own test binary: it installs the global subscriber.)
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::Write;
use std::sync::{Arc, Mutex};

use axum::body::Body;
use common::*;
use serde_json::json;

#[derive(Clone, Default)]
struct Logs(Arc<Mutex<Vec<u8>>>);

impl Write for Logs {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Logs {
    /// The text logged once `done` holds of it (or after 10 s, for the assertions to say why).
    async fn until(&self, done: impl Fn(&str) -> bool) -> String {
        let text = || String::from_utf8(self.0.lock().unwrap().clone()).unwrap();
        for _ in 0..1000 {
            if done(&text()) {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
        }
        text()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_are_logged_without_patient_data() {
    let logs = Logs::default();
    let sink = logs.clone();
    tracing_subscriber::fmt()
        .with_max_level(tracing::Level::INFO)
        .with_ansi(false)
        .with_writer(move || sink.clone())
        .init();
    let s = open_server().await;
    let mut req = json_request(
        "POST",
        "/v1/sessions",
        &json!({"displayName": "Jane Roe 1970-01-01"}),
    );
    req.headers_mut()
        .insert("x-request-id", "trace-me-7".parse().unwrap());
    let id = send(s.addr, req).await.json()["session"]["id"]
        .as_str()
        .unwrap()
        .to_owned();
    send(
        s.addr,
        request("GET", &format!("/v1/sessions/{id}"), Body::empty()),
    )
    .await;
    // A request's line may be written just after its client has the answer: wait for both.
    let text = logs
        .until(|t| {
            t.contains("route=\"/v1/sessions/{id}\"")
                && t.lines()
                    .any(|l| l.contains("trace-me-7") && l.contains("response"))
        })
        .await;
    let created = text
        .lines()
        .find(|l| l.contains("request_id=\"trace-me-7\"") && l.contains("response"))
        .unwrap_or_else(|| panic!("no response line in\n{text}"));
    for field in [
        "method=POST",
        "route=\"/v1/sessions\"",
        "status=201",
        "latency_ms=",
    ] {
        assert!(created.contains(field), "{field} missing: {created}");
    }
    assert!(text.contains("route=\"/v1/sessions/{id}\""), "{text}");
    // The date in full: "1970" alone may occur in a latency or an id.
    assert!(
        !text.contains("Jane") && !text.contains("1970-01-01"),
        "{text}"
    );
}
