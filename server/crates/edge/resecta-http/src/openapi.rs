//! The OpenAPI 3.1 document of the face, generated from the route table and the `resecta.v1`
//! descriptors so that it cannot drift from either: every message and enum is a schema of its
//! proto JSON (lowerCamelCase names, enums by name, 64-bit integers as strings, bytes as
//! base64), every RPC route an operation named after its RPC whose body, query, answer or event
//! stream are that RPC's messages; the exceptions (upload body, model file) are stated there.

use std::sync::LazyLock;

use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{FieldDescriptorProto, MethodDescriptorProto};
use serde_json::{Map, Value, json};

use crate::proto::{self, Api, is_scalar, json_name};
use crate::{Verb, table};

const REF: &str = "#/components/schemas/";

fn reference(type_name: &str) -> Value {
    json!({"$ref": format!("{REF}{}", type_name.trim_start_matches('.'))})
}

fn scalar(f: &FieldDescriptorProto) -> Value {
    let int64 = |format: &str| {
        json!({"type": ["string", "integer"], "format": format,
               "description": "64-bit integer: a decimal string in answers; requests may send a number"})
    };
    match f.r#type() {
        Type::Double | Type::Float => json!({"type": "number"}),
        Type::Int32 | Type::Sint32 | Type::Sfixed32 => {
            json!({"type": "integer", "format": "int32"})
        }
        Type::Uint32 | Type::Fixed32 => {
            json!({"type": "integer", "format": "uint32", "minimum": 0})
        }
        Type::Int64 | Type::Sint64 | Type::Sfixed64 => int64("int64"),
        Type::Uint64 | Type::Fixed64 => int64("uint64"),
        Type::Bool => json!({"type": "boolean"}),
        Type::String => json!({"type": "string"}),
        Type::Bytes => json!({"type": "string", "contentEncoding": "base64"}),
        Type::Enum | Type::Message | Type::Group => reference(f.type_name()),
    }
}

fn field_schema(f: &FieldDescriptorProto, comment: &str, oneof: Option<&str>) -> Value {
    let mut s = scalar(f);
    if f.label() == Label::Repeated {
        s = json!({"type": "array", "items": s});
    }
    let mut text = comment.to_owned();
    if let Some(o) = oneof {
        text = format!("{text} (one of `{o}`: at most one of its fields is set)");
    }
    if !text.is_empty() {
        // A `$ref` with siblings is allowed in 3.1; the description goes beside it.
        if let Some(obj) = s.as_object_mut() {
            obj.insert("description".into(), Value::String(text.trim().to_owned()));
        }
    }
    s
}

fn schemas(api: &Api) -> Map<String, Value> {
    let mut out = Map::new();
    for (name, m, comments) in &api.messages {
        let mut properties = Map::new();
        for (f, comment) in m.item.field.iter().zip(comments) {
            // proto3 `optional` fields are synthetic oneofs, not choices.
            let oneof = f
                .oneof_index
                .filter(|_| !f.proto3_optional())
                .and_then(|k| m.item.oneof_decl.get(k as usize))
                .map(|o| o.name());
            properties.insert(json_name(f), field_schema(f, comment, oneof));
        }
        out.insert(
            name.clone(),
            json!({"type": "object", "description": m.comment, "properties": properties,
                   "additionalProperties": false}),
        );
    }
    for (name, e) in &api.enums {
        let values: Vec<&str> = e.item.value.iter().map(|v| v.name()).collect();
        out.insert(
            name.clone(),
            json!({"type": "string", "enum": values, "description": e.comment}),
        );
    }
    out.insert("Problem".into(), problem_schema());
    out
}

fn problem_schema() -> Value {
    json!({
        "type": "object",
        "description": "RFC 9457 problem document (`application/problem+json`).",
        "required": ["type", "title", "status", "detail", "code"],
        "properties": {
            "type": {"type": "string", "example": "urn:resecta:problem:STALE_VERSION"},
            "title": {"type": "string"},
            "status": {"type": "integer"},
            "detail": {"type": "string", "description": "What is wrong, naming the offending quantity (never patient data)."},
            "code": {"type": "string", "description": "Stable code, the same as the gRPC face's `ErrorInfo.code` (proto/README.md); HTTP only: PAYLOAD_TOO_LARGE, NO_ROUTE, METHOD_NOT_ALLOWED."},
            "current_version": {"type": "integer", "description": "The current plan version (`STALE_VERSION` only)."}
        }
    })
}

fn problem_response() -> Value {
    json!({"description": "A problem document.",
           "content": {"application/problem+json": {"schema": {"$ref": format!("{REF}Problem")}}}})
}

fn parameter(name: &str, place: &str, schema: Value, description: &str) -> Value {
    json!({"name": name, "in": place, "required": place == "path", "schema": schema,
           "description": description})
}

/// The path parameters a route's path holds, and the request fields they fill.
fn path_parameters(path: &str) -> (Vec<Value>, Vec<&'static str>) {
    let mut params = Vec::new();
    let mut filled = Vec::new();
    if path.contains("{id}") {
        params.push(parameter(
            "id",
            "path",
            json!({"type": "string"}),
            "The session's id (the request's `sessionId`).",
        ));
        filled.push("session_id");
    }
    if path.contains("{name}") {
        params.push(parameter(
            "name",
            "path",
            json!({"type": "string"}),
            "A model's or a resection's name (the request's `model` or `resection`).",
        ));
        filled.extend(["model", "resection"]);
    }
    (params, filled)
}

fn rpc_operation(api: &Api, verb: Verb, path: &str, m: &MethodDescriptorProto) -> Value {
    let input = m.input_type().trim_start_matches('.');
    let output = m.output_type().trim_start_matches('.');
    let comment = api
        .methods
        .iter()
        .find(|d| d.item.name() == m.name())
        .map_or("", |d| d.comment.as_str());
    let (mut params, filled) = path_parameters(path);
    let mut op = Map::new();
    op.insert("operationId".into(), json!(m.name()));
    let mut description = comment.to_owned();
    if m.client_streaming() {
        // The upload: header in the query, data as the body.
        for (name, message) in [("raw", "RawLabelMapHeader"), ("file", "FileLabelMapHeader")] {
            params.push(parameter(
                name,
                "query",
                json!({"type": "string", "contentMediaType": "application/json",
                       "contentSchema": reference(&format!("resecta.v1.{message}"))}),
                &format!("The proto JSON of a `{message}` (`sessionId` from the path; `totalBytes` may be left out: the body's length). Neither `raw` nor `file`: a file whose format is told from its bytes."),
            ));
        }
        op.insert(
            "requestBody".into(),
            json!({"required": true, "description": "The data of the whole upload (the `data` of every `UploadLabelMapRequest` chunk, in one body): raw little-endian voxels, i fastest, or the image file.",
                   "content": {"application/octet-stream": {"schema": {"type": "string", "contentEncoding": "binary"}}}}),
        );
        description.push_str(
            " HTTP: one request instead of a stream of chunks; the header is a query parameter.",
        );
    } else if matches!(verb, Verb::Get | Verb::Delete) {
        if let Some(msg) = api.message(input) {
            for f in msg.field.iter().filter(|f| is_scalar(f)) {
                if filled.contains(&f.name()) {
                    continue;
                }
                params.push(parameter(
                    &json_name(f),
                    "query",
                    scalar(f),
                    &format!("The request's `{}`.", json_name(f)),
                ));
            }
        }
    } else {
        op.insert(
            "requestBody".into(),
            json!({"required": false,
                   "description": format!("The proto JSON of `{input}` (`sessionId` comes from the path; an empty body is the message with every field at its default)."),
                   "content": {"application/json": {"schema": reference(input)}}}),
        );
    }
    let ok = if m.server_streaming() && m.name() == "ExportModel" {
        description.push_str(" HTTP: the whole file as the body, not chunks.");
        json!({"description": "The mesh file.",
               "content": {"application/octet-stream": {"schema": {"type": "string", "contentEncoding": "binary"}}}})
    } else if m.server_streaming() {
        json!({"description": format!("Server-sent events: each event's data is the proto JSON of one `{output}` (the event's name is its `event` case; `id` is its `seq` where it has one); an `error` event carries a problem document and ends the stream."),
               "content": {"text/event-stream": {"schema": {"type": "string"},
                                                  "itemSchema": reference(output)}}})
    } else {
        json!({"description": format!("The proto JSON of `{output}`."),
               "content": {"application/json": {"schema": reference(output)}}})
    };
    let status = if m.name() == "CreateSession" {
        "201"
    } else {
        "200"
    };
    op.insert("summary".into(), json!(format!("{} (gRPC)", m.name())));
    op.insert("description".into(), json!(description.trim()));
    op.insert("parameters".into(), Value::Array(params));
    op.insert(
        "responses".into(),
        json!({status: ok, "default": problem_response()}),
    );
    Value::Object(op)
}

fn plain_operation(path: &str) -> Value {
    let (summary, media) = match path {
        "/healthz" => ("Liveness (no token).", "text/plain"),
        "/metrics" => ("Prometheus metrics (no token).", "text/plain"),
        _ => ("This document (no token).", "application/json"),
    };
    json!({"summary": summary, "security": [{}],
           "responses": {"200": {"description": summary, "content": {media: {"schema": {"type": "string"}}}}}})
}

fn document() -> Value {
    let api = proto::api();
    let mut paths = Map::new();
    for r in table() {
        let op = match r.rpc.and_then(|name| api.method(name)) {
            Some(m) => {
                let mut op = rpc_operation(api, r.verb, r.path, m);
                if !r.guarded
                    && let Some(o) = op.as_object_mut()
                {
                    o.insert("security".into(), json!([{}]));
                }
                op
            }
            None => plain_operation(r.path),
        };
        let entry = paths
            .entry(r.path.to_owned())
            .or_insert_with(|| Value::Object(Map::new()));
        if let Some(e) = entry.as_object_mut() {
            e.insert(r.verb.method().as_str().to_lowercase(), op);
        }
    }
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "resecta planning server, HTTP/JSON face",
            "version": "1.0.0",
            "description": "The resecta.v1 API (proto/resecta/v1) as JSON over HTTP: every route is one RPC of `resecta.v1.PlanningService` (its `operationId`), its bodies that RPC's messages in the canonical protobuf JSON mapping, with the same semantics and error codes as the gRPC face. Send `authorization: Bearer <token>` when the server has a token and `resecta-api-version: v1`. Every response carries `x-request-id` (the client's, up to 64 printable ASCII characters, or a fresh UUID). Errors are `application/problem+json`; a cancelled operation answers 499."
        },
        "security": [{"bearer": []}, {}],
        "paths": paths,
        "components": {
            "schemas": schemas(api),
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}}
        }
    })
}

static TEXT: LazyLock<String> = LazyLock::new(|| document().to_string());

/// The OpenAPI document as JSON text (generated once).
pub fn document_text() -> &'static str {
    &TEXT
}
