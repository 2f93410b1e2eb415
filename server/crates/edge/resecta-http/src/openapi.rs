//! The OpenAPI 3.1 document of the face, generated from the route table and the `resecta.v1`
//! descriptors so that it cannot drift from either: every message and enum is a schema of its
//! proto JSON (lowerCamelCase names, enums by name, 64-bit integers as strings, bytes as
//! base64), every RPC route an operation named after its RPC whose body, query, answer or event
//! stream are that RPC's messages; the exceptions (upload body, model file) are stated there.
//! What the server enforces beyond the proto types (ranges, lengths, required fields, refused
//! enum values, exactly one edit) is stated as schema keywords from the constants that enforce
//! it ([`rules`]), and what a schema cannot say is stated in words.

mod rules;

use std::sync::LazyLock;

use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{FieldDescriptorProto, MethodDescriptorProto};
use serde_json::{Map, Value, json};

use resecta_auth::{API_VERSION_HEADER, API_VERSION_HEADER_VALUE};

use crate::proto::{self, Api, is_scalar, json_name};
use crate::{Verb, table};

const REF: &str = "#/components/schemas/";

fn reference(type_name: &str) -> Value {
    json!({"$ref": format!("{REF}{}", type_name.trim_start_matches('.'))})
}

fn scalar(f: &FieldDescriptorProto) -> Value {
    let int64 = |format: &str, pattern: &str, min: Value, max: Value| {
        json!({"type": ["string", "integer"], "format": format, "pattern": pattern,
               "minimum": min, "maximum": max,
               "description": "64-bit integer: a decimal string in answers; requests may send a number"})
    };
    match f.r#type() {
        Type::Double | Type::Float => rules::finite(),
        Type::Int32 | Type::Sint32 | Type::Sfixed32 => {
            json!({"type": "integer", "format": "int32", "minimum": i32::MIN, "maximum": i32::MAX})
        }
        Type::Uint32 | Type::Fixed32 => {
            json!({"type": "integer", "format": "uint32", "minimum": 0, "maximum": u32::MAX})
        }
        // The strings are the decimal forms of at most 18 (19) digits: every one a value of
        // the type (longer ones may be too, but not every one).
        Type::Int64 | Type::Sint64 | Type::Sfixed64 => {
            int64("int64", "^-?[0-9]{1,18}$", json!(i64::MIN), json!(i64::MAX))
        }
        Type::Uint64 | Type::Fixed64 => int64("uint64", "^[0-9]{1,19}$", json!(0), json!(u64::MAX)),
        Type::Bool => json!({"type": "boolean"}),
        Type::String => json!({"type": "string"}),
        Type::Bytes => json!({"type": "string", "contentEncoding": "base64"}),
        Type::Enum | Type::Message | Type::Group => reference(f.type_name()),
    }
}

/// Merges `extra` into `schema`: its `items` into the schema's items, its `description` after
/// the schema's, every other keyword over the schema's.
fn merge(schema: &mut Value, extra: Value) {
    let (Some(s), Value::Object(extra)) = (schema.as_object_mut(), extra) else {
        return;
    };
    for (key, value) in extra {
        match (key.as_str(), s.get_mut(&key)) {
            ("items", Some(items)) => merge(items, value),
            ("description", Some(Value::String(old))) => {
                if let Value::String(v) = value {
                    *old = format!("{old} {v}");
                }
            }
            _ => {
                s.insert(key, value);
            }
        }
    }
}

fn field_schema(
    message: &str,
    f: &FieldDescriptorProto,
    comment: &str,
    oneof: Option<&str>,
) -> Value {
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
    if let Some(extra) = rules::field(message, &json_name(f)) {
        merge(&mut s, extra);
    }
    s
}

/// Messages that are request bodies or upload headers, whose `sessionId` the path gives.
fn takes_path_session(name: &str) -> bool {
    name.ends_with("Request") || name.ends_with("LabelMapHeader")
}

fn schemas(api: &Api) -> Map<String, Value> {
    let mut out = Map::new();
    for (name, m, comments) in &api.messages {
        let mut properties = Map::new();
        let mut choices: Vec<String> = Vec::new();
        let must_choose = rules::required_oneof(name);
        for (f, comment) in m.item.field.iter().zip(comments) {
            if takes_path_session(name) && json_name(f) == rules::SESSION_FIELD {
                continue;
            }
            // proto3 `optional` fields are synthetic oneofs, not choices.
            let oneof = f
                .oneof_index
                .filter(|_| !f.proto3_optional())
                .and_then(|k| m.item.oneof_decl.get(k as usize))
                .map(|o| o.name());
            if oneof.is_some() && oneof == must_choose {
                choices.push(json_name(f));
            }
            properties.insert(json_name(f), field_schema(name, f, comment, oneof));
        }
        let mut description = m.comment.clone();
        if takes_path_session(name)
            && m.item
                .field
                .iter()
                .any(|f| json_name(f) == rules::SESSION_FIELD)
        {
            description.push_str(" `sessionId` is the path's `{id}` (a body or header naming another session is refused).");
        }
        if let Some(o) = must_choose {
            description.push_str(&format!(" Exactly one field of `{o}` is set."));
        }
        if let Some(note) = rules::note(name) {
            description.push(' ');
            description.push_str(&note);
        }
        let mut schema = json!({"type": "object", "description": description.trim(),
                                "properties": properties, "additionalProperties": false});
        let required = rules::required(name);
        if !required.is_empty() {
            schema["required"] = json!(required);
        }
        if !choices.is_empty() {
            let one: Vec<Value> = choices.iter().map(|c| json!({"required": [c]})).collect();
            schema["oneOf"] = Value::Array(one);
        }
        out.insert(name.clone(), schema);
    }
    for (name, e) in &api.enums {
        let no_zero = rules::NO_ZERO.contains(&name.as_str());
        let values: Vec<&str> = e
            .item
            .value
            .iter()
            .filter(|v| !(no_zero && v.number() == 0))
            .map(|v| v.name())
            .collect();
        let mut description = e.comment.clone();
        if no_zero {
            description.push_str(
                " The zero value (`*_UNSPECIFIED`) is refused in requests and never sent.",
            );
        }
        out.insert(
            name.clone(),
            json!({"type": "string", "enum": values, "description": description.trim()}),
        );
    }
    out.insert("Problem".into(), problem_schema());
    out.insert("PlanDocument".into(), rules::plan_document());
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
            "current_version": {"type": "integer", "description": "The current plan version (`STALE_VERSION` only)."},
            "replica": {
                "type": "object",
                "description": "The replica that holds the session (`SESSION_ELSEWHERE`, status 421, only): repeat the request at `http_url`.",
                "required": ["id", "grpc_address", "http_url", "lease_remaining_ms"],
                "properties": {
                    "id": {"type": "string"},
                    "grpc_address": {"type": "string"},
                    "http_url": {"type": "string"},
                    "lease_remaining_ms": {"type": "integer"}
                }
            }
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
            json!({"type": "string", "minLength": 1}),
            "The session's id (the request's `sessionId`); an unknown one is 404.",
        ));
        filled.push("session_id");
    }
    if path.contains("{name}") {
        params.push(parameter(
            "name",
            "path",
            json!({"type": "string", "minLength": 1}),
            "A model's or a resection's name (the request's `model` or `resection`); an unknown one is 404.",
        ));
        filled.extend(["model", "resection"]);
    }
    (params, filled)
}

/// The upload's header parameters: the proto JSON of a raw or a file header.
fn upload_parameters() -> Vec<Value> {
    [("raw", "RawLabelMapHeader"), ("file", "FileLabelMapHeader")]
        .into_iter()
        .map(|(name, message)| {
            json!({"name": name, "in": "query", "required": false,
                   "content": {"application/json": {"schema": reference(&format!("resecta.v1.{message}"))}},
                   "description": format!("The proto JSON of a `{message}` (`sessionId` from the path; `totalBytes` may be left out: the body's length). Give `raw` or `file`, not both (refused: a schema cannot say so); neither is a file whose format is told from its bytes.")})
        })
        .collect()
}

/// The query parameters of a GET route: the scalar fields of its request message that the path
/// does not fill and the face takes.
fn query_parameters(
    api: &Api,
    input: &str,
    filled: &[&str],
    params: &mut Vec<Value>,
) -> Vec<String> {
    let mut refused = Vec::new();
    let Some(msg) = api.message(input) else {
        return refused;
    };
    let required = rules::required(input);
    for f in msg.field.iter().filter(|f| is_scalar(f)) {
        let name = json_name(f);
        if filled.contains(&f.name()) {
            continue;
        }
        if let Some(why) = rules::refused_query(input, &name) {
            refused.push(why.to_owned());
            continue;
        }
        let mut schema = scalar(f);
        if let Some(extra) = rules::field(input, &name) {
            merge(&mut schema, extra);
        }
        let mut p = parameter(&name, "query", schema, &format!("The request's `{name}`."));
        p["required"] = json!(required.contains(&name.as_str()));
        params.push(p);
    }
    refused
}

fn rpc_operation(
    api: &Api,
    verb: Verb,
    path: &str,
    m: &MethodDescriptorProto,
    guarded: bool,
) -> Value {
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
        params.extend(upload_parameters());
        op.insert(
            "requestBody".into(),
            json!({"required": true, "description": "The data of the whole upload (the `data` of every `UploadLabelMapRequest` chunk, in one body): raw little-endian voxels, i fastest, or the image file; at most `ServerLimits.max_upload_bytes` (413 beyond).",
                   "content": {"application/octet-stream": {"schema": {"type": "string", "contentEncoding": "binary"}}}}),
        );
        description.push_str(
            " HTTP: one request instead of a stream of chunks; the header is a query parameter.",
        );
    } else if matches!(verb, Verb::Get | Verb::Delete) {
        for why in query_parameters(api, input, &filled, &mut params) {
            description.push(' ');
            description.push_str(&why);
        }
    } else {
        let needed = !rules::required(input).is_empty() || rules::required_oneof(input).is_some();
        let session = api
            .message(input)
            .is_some_and(|m| m.field.iter().any(|f| json_name(f) == rules::SESSION_FIELD));
        let notes: Vec<&str> = [
            (session, "`sessionId` comes from the path"),
            (
                !needed,
                "an empty body is the message with every field at its default",
            ),
        ]
        .into_iter()
        .filter_map(|(on, text)| on.then_some(text))
        .collect();
        let notes = if notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", notes.join("; "))
        };
        op.insert(
            "requestBody".into(),
            json!({"required": needed,
                   "description": format!("The proto JSON of `{input}`{notes}."),
                   "content": {"application/json": {"schema": reference(input)}}}),
        );
    }
    if m.name() == "Watch" {
        params.push(parameter(
            "Last-Event-ID",
            "header",
            json!({"type": "string", "pattern": "^[0-9]{1,19}$"}),
            "The last event id (`seq`) a reconnecting client saw; takes precedence over `sinceSeq`. Anything but a sequence number (a decimal u64) is refused, an empty value too.",
        ));
        description.push_str(" A server that compresses or quantises mesh payloads refuses a watch that does not allow them (409 `FAILED_PRECONDITION`, see `GetServerInfo`'s capabilities).");
    }
    if guarded {
        params.push(parameter(
            API_VERSION_HEADER,
            "header",
            json!({"type": "string", "enum": [API_VERSION_HEADER_VALUE]}),
            "The API version the client speaks; any other value is refused (400 `API_VERSION_MISMATCH`).",
        ));
    }
    let ok = if m.server_streaming() && m.name() == "ExportModel" {
        description.push_str(" HTTP: the whole file as the body, not chunks.");
        let mut content = Map::new();
        // Every format but UNSPECIFIED (0), by number until the enum ends.
        let formats = (1..).map_while(|n| resecta_api::v1::ModelFormat::try_from(n).ok());
        for format in formats {
            content.insert(
                crate::handlers::model_media(format).to_owned(),
                json!({"schema": {"type": "string", "contentEncoding": "binary"}}),
            );
        }
        json!({"description": "The mesh file: VTP as application/xml, STL as model/stl, OBJ as model/obj, VTK and PLY as application/octet-stream.",
               "content": content})
    } else if m.server_streaming() {
        let event = json!({
            "type": "object",
            "required": ["data"],
            "properties": {
                "event": {"type": "string"},
                "id": {"type": "string"},
                "data": {"type": "string", "contentMediaType": "application/json",
                         "contentSchema": {"anyOf": [reference(output), {"$ref": format!("{REF}Problem")}]}}
            }
        });
        json!({"description": format!("Server-sent events: each event's data is the proto JSON of one `{output}` (the event's name is its `event` case; `id` is its `seq` where it has one); an `error` event carries a problem document and ends the stream."),
               "content": {"text/event-stream": {"itemSchema": event}}})
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
        "/readyz" => (
            "Readiness (no token): 503 while the server drains or its store does not answer.",
            "text/plain",
        ),
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
                let mut op = rpc_operation(api, r.verb, r.path, m, r.guarded);
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
            "description": format!("The resecta.v1 API (proto/resecta/v1) as JSON over HTTP: every route is one RPC of `resecta.v1.PlanningService` (its `operationId`), its bodies that RPC's messages in the canonical protobuf JSON mapping, with the same semantics and error codes as the gRPC face. Send `authorization: Bearer <token>` when the server has a token and `resecta-api-version: v1`. Every response carries `x-request-id` (the client's, up to 64 printable ASCII characters, or a fresh UUID). Errors are `application/problem+json`; a cancelled operation answers 499. The schemas state what the server enforces (ranges, lengths, required fields; `GetServerInfo`'s `limits` report the same numbers); what a schema cannot say (relations between fields, the session's state) is said in the descriptions. Requests may also use what the proto JSON mapping allows beyond the schemas: a field's proto name (snake_case) for its JSON name, an enum's number for its name, a 32-bit integer or a double as a string. JSON bodies are at most {max_json} bytes (413 beyond).", max_json = crate::MAX_JSON_BYTES)
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
