//! Extractors whose rejections are problems: bounded body reading, JSON bodies, path and query.

use axum::body::{Body, Bytes};
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::request::Parts;
use axum::http::{HeaderMap, header};
use futures_util::StreamExt;
use serde::de::DeserializeOwned;

use crate::App;
use crate::problem::Problem;
use resecta_session::UploadMemory;

/// Bytes reserved up front for a body, at most (the rest grows as it arrives).
const MAX_PREALLOC: u64 = 8 << 20;

/// Reads a body of at most `limit` bytes: refuses a larger `Content-Length` before reading
/// anything, and a longer (e.g. chunked) body as soon as it passes the limit.
pub async fn read_body(
    headers: &HeaderMap,
    body: Body,
    limit: u64,
    mut memory: Option<&mut UploadMemory>,
) -> Result<Bytes, Problem> {
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit) {
        return Err(Problem::too_large(limit));
    }
    let reserve = declared.unwrap_or(0).min(limit).min(MAX_PREALLOC);
    let mut out = Vec::with_capacity(usize::try_from(reserve).unwrap_or(0));
    let mut chunks = body.into_data_stream();
    while let Some(chunk) = chunks.next().await {
        let chunk = chunk.map_err(|e| Problem::invalid(format!("request body: {e}")))?;
        if (out.len() + chunk.len()) as u64 > limit {
            return Err(Problem::too_large(limit));
        }
        // An upload holds the memory budget as its bytes arrive.
        if let Some(memory) = memory.as_deref_mut() {
            memory.grow(chunk.len() as u64)?;
        }
        out.extend_from_slice(&chunk);
    }
    Ok(out.into())
}

/// A request message as its proto JSON body, of at most [`crate::HttpOptions::max_json_bytes`];
/// an empty body (or only whitespace) is the message with every field at its default.
#[derive(Debug)]
pub struct ProtoJson<T>(pub T);

impl<T: DeserializeOwned + Default + prost::Name> FromRequest<App> for ProtoJson<T> {
    type Rejection = Problem;

    async fn from_request(req: Request, app: &App) -> Result<Self, Problem> {
        let (parts, body) = req.into_parts();
        let bytes = read_body(&parts.headers, body, app.max_json_bytes, None).await?;
        if bytes.iter().all(u8::is_ascii_whitespace) {
            return Ok(Self(T::default()));
        }
        proto_json::<T>(&bytes)
            .map(ProtoJson)
            .map_err(|e| Problem::invalid(format!("request body: {e}")))
    }
}

/// Message `T` from its proto JSON text; integer fields may be written `5.0` too (JSON does not
/// tell the two apart: see [`crate::proto::integral_numbers`]).
pub fn proto_json<T: DeserializeOwned + prost::Name>(text: &[u8]) -> serde_json::Result<T> {
    let mut value: serde_json::Value = serde_json::from_slice(text)?;
    crate::proto::integral_numbers(&T::full_name(), &mut value);
    serde_json::from_value(value)
}

/// A request message whose fields are the query parameters (by their proto or JSON names; the
/// scalar fields of a GET route's request message, as gRPC transcoding has them).
#[derive(Debug)]
pub struct ProtoQuery<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned + prost::Name> FromRequestParts<S> for ProtoQuery<T> {
    type Rejection = Problem;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Problem> {
        let pairs: Vec<(String, String)> = axum::extract::Query::try_from_uri(&parts.uri)
            .map(|q: axum::extract::Query<Vec<(String, String)>>| q.0)
            .map_err(|e| Problem::invalid(e.body_text()))?;
        let json = crate::proto::query_json(&T::full_name(), pairs)
            .map_err(|e| Problem::invalid(format!("query: {e}")))?;
        serde_json::from_value(json)
            .map(ProtoQuery)
            .map_err(|e| Problem::invalid(format!("query: {e}")))
    }
}

/// Path parameters.
#[derive(Debug)]
pub struct Path<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned + Send> FromRequestParts<S> for Path<T> {
    type Rejection = Problem;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Problem> {
        axum::extract::Path::<T>::from_request_parts(parts, state)
            .await
            .map(|p| Self(p.0))
            .map_err(|e| Problem::invalid(e.body_text()))
    }
}

/// Query parameters.
#[derive(Debug)]
pub struct Query<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned> FromRequestParts<S> for Query<T> {
    type Rejection = Problem;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Problem> {
        axum::extract::Query::<T>::try_from_uri(&parts.uri)
            .map(|q| Self(q.0))
            .map_err(|e| Problem::invalid(e.body_text()))
    }
}
