//! Keeps `proto/resecta/v1` lint-clean: the buf STANDARD style rules and comments on every
//! element (buf's COMMENTS category), checked on the compiled descriptor set so CI needs no buf.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

use std::collections::{BTreeMap, BTreeSet};

use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, EnumDescriptorProto, FileDescriptorProto, FileDescriptorSet,
    ServiceDescriptorProto,
};

const PACKAGE: &str = "resecta.v1";

// Field numbers of the descriptor messages, for source-code-info paths.
const FILE_MESSAGE: i32 = 4;
const FILE_ENUM: i32 = 5;
const FILE_SERVICE: i32 = 6;
const MESSAGE_FIELD: i32 = 2;
const MESSAGE_NESTED: i32 = 3;
const MESSAGE_ENUM: i32 = 4;
const MESSAGE_ONEOF: i32 = 8;
const ENUM_VALUE: i32 = 2;
const SERVICE_METHOD: i32 = 2;

fn descriptor_set() -> FileDescriptorSet {
    FileDescriptorSet::decode(resecta_api::FILE_DESCRIPTOR_SET).unwrap()
}

fn api_files(set: &FileDescriptorSet) -> Vec<&FileDescriptorProto> {
    set.file.iter().filter(|f| f.package() == PACKAGE).collect()
}

fn is_pascal(s: &str) -> bool {
    s.starts_with(|c: char| c.is_ascii_uppercase()) && s.chars().all(|c| c.is_ascii_alphanumeric())
}

/// lower_snake_case whose words each start with a letter (`song_name1`, not `song_name_1`).
fn is_lower_snake(s: &str) -> bool {
    !s.is_empty()
        && s.split('_').all(|w| {
            w.starts_with(|c: char| c.is_ascii_lowercase())
                && w.chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit())
        })
}

fn is_upper_snake(s: &str) -> bool {
    !s.is_empty()
        && s.split('_').all(|w| {
            w.starts_with(|c: char| c.is_ascii_uppercase())
                && w.chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit())
        })
}

/// `LabelMapFormat` → `LABEL_MAP_FORMAT`.
fn upper_snake_of(pascal: &str) -> String {
    let mut out = String::new();
    for (i, c) in pascal.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

/// Every style violation of `files`, one line each.
fn lint(files: &[&FileDescriptorProto]) -> Vec<String> {
    let mut v = Vec::new();
    for f in files {
        lint_file(f, &mut v);
    }
    lint_rpc_uniqueness(files, &mut v);
    v
}

fn lint_file(f: &FileDescriptorProto, v: &mut Vec<String>) {
    let name = f.name();
    let stem = name
        .strip_prefix("resecta/v1/")
        .and_then(|s| s.strip_suffix(".proto"));
    if !stem.is_some_and(is_lower_snake) {
        v.push(format!(
            "{name}: file must be resecta/v1/<lower_snake_case>.proto"
        ));
    }
    if f.package() != PACKAGE {
        v.push(format!(
            "{name}: package {:?}, expected {PACKAGE}",
            f.package()
        ));
    }
    if f.syntax() != "proto3" {
        v.push(format!("{name}: syntax {:?}, expected proto3", f.syntax()));
    }
    if !f.public_dependency.is_empty() || !f.weak_dependency.is_empty() {
        v.push(format!("{name}: public or weak imports"));
    }
    let comments = leading_comments(f);
    let documented = |path: &[i32], what: &str, v: &mut Vec<String>| {
        if !comments.contains_key(path) {
            v.push(format!("{name}: {what} has no leading comment"));
        }
    };
    for (i, m) in f.message_type.iter().enumerate() {
        lint_message(m, &[FILE_MESSAGE, i as i32], m.name(), &documented, v);
    }
    for (i, e) in f.enum_type.iter().enumerate() {
        lint_enum(e, &[FILE_ENUM, i as i32], e.name(), &documented, v);
    }
    for (i, s) in f.service.iter().enumerate() {
        lint_service(s, &[FILE_SERVICE, i as i32], &documented, v);
    }
    lint_imports(f, v);
}

type Documented<'a> = dyn Fn(&[i32], &str, &mut Vec<String>) + 'a;

fn lint_message(
    m: &DescriptorProto,
    path: &[i32],
    full: &str,
    documented: &Documented,
    v: &mut Vec<String>,
) {
    if !is_pascal(m.name()) {
        v.push(format!("message {full}: name must be PascalCase"));
    }
    documented(path, &format!("message {full}"), v);
    for (i, fd) in m.field.iter().enumerate() {
        if !is_lower_snake(fd.name()) {
            v.push(format!(
                "field {full}.{}: name must be lower_snake_case",
                fd.name()
            ));
        }
        if fd.label() == Label::Required {
            v.push(format!("field {full}.{}: required fields", fd.name()));
        }
        documented(
            &[path, &[MESSAGE_FIELD, i as i32]].concat(),
            &format!("field {full}.{}", fd.name()),
            v,
        );
    }
    for (i, o) in m.oneof_decl.iter().enumerate() {
        // proto3 `optional` fields live in synthetic oneofs named `_<field>`.
        let synthetic = m
            .field
            .iter()
            .any(|fd| fd.proto3_optional() && fd.oneof_index == Some(i as i32));
        if synthetic {
            continue;
        }
        if !is_lower_snake(o.name()) {
            v.push(format!(
                "oneof {full}.{}: name must be lower_snake_case",
                o.name()
            ));
        }
        documented(
            &[path, &[MESSAGE_ONEOF, i as i32]].concat(),
            &format!("oneof {full}.{}", o.name()),
            v,
        );
    }
    for (i, n) in m.nested_type.iter().enumerate() {
        if n.options.as_ref().is_some_and(|o| o.map_entry()) {
            continue;
        }
        let p = [path, &[MESSAGE_NESTED, i as i32]].concat();
        lint_message(n, &p, &format!("{full}.{}", n.name()), documented, v);
    }
    for (i, e) in m.enum_type.iter().enumerate() {
        let p = [path, &[MESSAGE_ENUM, i as i32]].concat();
        lint_enum(e, &p, &format!("{full}.{}", e.name()), documented, v);
    }
}

fn lint_enum(
    e: &EnumDescriptorProto,
    path: &[i32],
    full: &str,
    documented: &Documented,
    v: &mut Vec<String>,
) {
    if !is_pascal(e.name()) {
        v.push(format!("enum {full}: name must be PascalCase"));
    }
    if e.options.as_ref().is_some_and(|o| o.allow_alias()) {
        v.push(format!("enum {full}: allow_alias"));
    }
    documented(path, &format!("enum {full}"), v);
    let prefix = format!("{}_", upper_snake_of(e.name()));
    match e.value.first() {
        Some(z) if z.number() == 0 && z.name() == format!("{prefix}UNSPECIFIED") => {}
        _ => v.push(format!(
            "enum {full}: first value must be {prefix}UNSPECIFIED = 0"
        )),
    }
    for (i, val) in e.value.iter().enumerate() {
        if !is_upper_snake(val.name()) || !val.name().starts_with(&prefix) {
            v.push(format!(
                "enum value {full}.{}: must be UPPER_SNAKE_CASE prefixed {prefix}",
                val.name()
            ));
        }
        documented(
            &[path, &[ENUM_VALUE, i as i32]].concat(),
            &format!("enum value {full}.{}", val.name()),
            v,
        );
    }
}

fn lint_service(
    s: &ServiceDescriptorProto,
    path: &[i32],
    documented: &Documented,
    v: &mut Vec<String>,
) {
    let name = s.name();
    if !is_pascal(name) || !name.ends_with("Service") {
        v.push(format!(
            "service {name}: name must be PascalCase ending in Service"
        ));
    }
    documented(path, &format!("service {name}"), v);
    for (i, m) in s.method.iter().enumerate() {
        let rpc = m.name();
        if !is_pascal(rpc) {
            v.push(format!("rpc {name}.{rpc}: name must be PascalCase"));
        }
        let (req, resp) = (
            format!(".{PACKAGE}.{rpc}Request"),
            format!(".{PACKAGE}.{rpc}Response"),
        );
        if m.input_type() != req {
            v.push(format!(
                "rpc {name}.{rpc}: request {} must be {req}",
                m.input_type()
            ));
        }
        if m.output_type() != resp {
            v.push(format!(
                "rpc {name}.{rpc}: response {} must be {resp}",
                m.output_type()
            ));
        }
        documented(
            &[path, &[SERVICE_METHOD, i as i32]].concat(),
            &format!("rpc {name}.{rpc}"),
            v,
        );
    }
}

/// buf's RPC_REQUEST_RESPONSE_UNIQUE: no message is the request or response of two RPCs.
fn lint_rpc_uniqueness(files: &[&FileDescriptorProto], v: &mut Vec<String>) {
    let mut uses: BTreeMap<&str, usize> = BTreeMap::new();
    for m in files
        .iter()
        .flat_map(|f| &f.service)
        .flat_map(|s| &s.method)
    {
        *uses.entry(m.input_type()).or_default() += 1;
        *uses.entry(m.output_type()).or_default() += 1;
    }
    for (ty, n) in uses {
        if n > 1 {
            v.push(format!("{ty} is used by {n} RPCs"));
        }
    }
}

/// buf's IMPORT_USED: every import defines a type this file refers to.
fn lint_imports(f: &FileDescriptorProto, v: &mut Vec<String>) {
    let mut referenced = BTreeSet::new();
    fn collect(m: &DescriptorProto, out: &mut BTreeSet<String>) {
        out.extend(
            m.field
                .iter()
                .filter(|fd| fd.type_name.is_some())
                .map(|fd| fd.type_name().to_owned()),
        );
        for n in &m.nested_type {
            collect(n, out);
        }
    }
    for m in &f.message_type {
        collect(m, &mut referenced);
    }
    for m in f.service.iter().flat_map(|s| &s.method) {
        referenced.insert(m.input_type().to_owned());
        referenced.insert(m.output_type().to_owned());
    }
    let set = descriptor_set();
    for dep in &f.dependency {
        let Some(d) = set.file.iter().find(|x| x.name() == dep) else {
            v.push(format!("{}: import {dep} is not in the set", f.name()));
            continue;
        };
        let defined: BTreeSet<String> = top_level_types(d);
        if referenced.is_disjoint(&defined) {
            v.push(format!("{}: import {dep} is unused", f.name()));
        }
    }
}

fn top_level_types(f: &FileDescriptorProto) -> BTreeSet<String> {
    let pkg = f.package();
    let mut out = BTreeSet::new();
    fn walk(prefix: &str, m: &DescriptorProto, out: &mut BTreeSet<String>) {
        let full = format!("{prefix}.{}", m.name());
        for e in &m.enum_type {
            out.insert(format!("{full}.{}", e.name()));
        }
        for n in &m.nested_type {
            walk(&full, n, out);
        }
        out.insert(full);
    }
    for m in &f.message_type {
        walk(&format!(".{pkg}"), m, &mut out);
    }
    for e in &f.enum_type {
        out.insert(format!(".{pkg}.{}", e.name()));
    }
    out
}

/// Source paths that carry a non-empty leading comment.
fn leading_comments(f: &FileDescriptorProto) -> BTreeMap<Vec<i32>, String> {
    f.source_code_info
        .iter()
        .flat_map(|s| &s.location)
        .filter(|l| l.leading_comments().trim().len() > 1)
        .map(|l| (l.path.clone(), l.leading_comments().to_owned()))
        .collect()
}

fn message<'a>(set: &'a FileDescriptorSet, full: &str) -> &'a DescriptorProto {
    let (pkg, name) = full.trim_start_matches('.').rsplit_once('.').unwrap();
    set.file
        .iter()
        .filter(|f| f.package() == pkg)
        .flat_map(|f| &f.message_type)
        .find(|m| m.name() == name)
        .unwrap_or_else(|| panic!("message {full} not found"))
}

#[test]
fn api_is_lint_clean() {
    let set = descriptor_set();
    let files = api_files(&set);
    assert!(files.len() >= 9, "only {} resecta.v1 files", files.len());
    let violations = lint(&files);
    assert!(
        violations.is_empty(),
        "{} lint violations:\n{}",
        violations.len(),
        violations.join("\n")
    );
}

#[test]
fn api_imports_nothing_outside_proto_dir() {
    let set = descriptor_set();
    for f in &set.file {
        assert!(
            f.name().starts_with("resecta/v1/"),
            "{} is outside proto/resecta/v1 (imports must stay inside proto/)",
            f.name()
        );
    }
}

#[test]
fn service_has_the_operations_with_their_stream_kinds() {
    let set = descriptor_set();
    let services: Vec<&ServiceDescriptorProto> =
        api_files(&set).iter().flat_map(|f| &f.service).collect();
    assert_eq!(services.len(), 1, "one PlanningService");
    let s = services[0];
    assert_eq!(s.name(), "PlanningService");
    let kinds: BTreeMap<&str, (bool, bool)> = s
        .method
        .iter()
        .map(|m| (m.name(), (m.client_streaming(), m.server_streaming())))
        .collect();
    let expected = [
        ("GetServerInfo", (false, false)),
        ("CreateSession", (false, false)),
        ("ListSessions", (false, false)),
        ("GetSession", (false, false)),
        ("DeleteSession", (false, false)),
        ("UploadLabelMap", (true, false)),
        ("Reconstruct", (false, true)),
        ("Edit", (false, false)),
        ("GetVolumes", (false, false)),
        ("ExportPlan", (false, false)),
        ("ImportPlan", (false, false)),
        ("ExportModel", (false, true)),
        ("GetSlices", (false, false)),
        ("GetLabelSlice", (false, false)),
        ("GetResectogram", (false, false)),
        ("GetRiskMap", (false, false)),
        ("ReconstructPoints", (false, false)),
        ("Watch", (false, true)),
    ];
    assert_eq!(kinds, expected.into_iter().collect());
}

/// No vertex data as repeated floats on the Watch and slice paths: every message reachable from
/// their responses carries meshes and polylines as bytes. Only a voxel grid's fixed-size geometry
/// (3 or 9 values) is a repeated double.
#[test]
fn streamed_geometry_is_packed_bytes() {
    const FIXED_SIZE: [&str; 3] = [
        ".resecta.v1.LabelMapSummary.spacing",
        ".resecta.v1.LabelMapSummary.origin",
        ".resecta.v1.LabelMapSummary.direction",
    ];
    let set = descriptor_set();
    let mut seen = BTreeSet::new();
    let mut stack = vec![
        ".resecta.v1.WatchResponse".to_owned(),
        ".resecta.v1.GetSlicesResponse".to_owned(),
    ];
    while let Some(ty) = stack.pop() {
        if !seen.insert(ty.clone()) {
            continue;
        }
        let m = message(&set, &ty);
        for fd in &m.field {
            let floats = matches!(fd.r#type(), Type::Float | Type::Double);
            let fixed = FIXED_SIZE.contains(&format!("{ty}.{}", fd.name()).as_str());
            assert!(
                fixed || !(floats && fd.label() == Label::Repeated),
                "{ty}.{} is a repeated float on a streamed geometry path",
                fd.name()
            );
            if fd.r#type() == Type::Message {
                stack.push(fd.type_name().to_owned());
            }
        }
    }
    for ty in [
        ".resecta.v1.Surface",
        ".resecta.v1.ResectionSurface",
        ".resecta.v1.Polyline",
    ] {
        assert!(seen.contains(ty), "{ty} not reached");
    }
}

/// The checker finds each kind of violation in a deliberately bad file (so a clean result means
/// something).
#[test]
fn lint_catches_violations() {
    use prost_types::{
        EnumValueDescriptorProto, FieldDescriptorProto, MethodDescriptorProto, OneofDescriptorProto,
    };
    let field = |name: &str, n: i32| FieldDescriptorProto {
        name: Some(name.into()),
        number: Some(n),
        label: Some(Label::Optional as i32),
        r#type: Some(Type::Uint32 as i32),
        ..Default::default()
    };
    let bad = FileDescriptorProto {
        name: Some("resecta/v1/Bad-File.proto".into()),
        package: Some("resecta.v1".into()),
        syntax: Some("proto3".into()),
        message_type: vec![DescriptorProto {
            name: Some("bad_message".into()),
            field: vec![field("camelCase", 1), field("grid_1", 2)],
            oneof_decl: vec![OneofDescriptorProto {
                name: Some("Choice".into()),
                ..Default::default()
            }],
            ..Default::default()
        }],
        enum_type: vec![EnumDescriptorProto {
            name: Some("Colour".into()),
            value: vec![
                EnumValueDescriptorProto {
                    name: Some("RED".into()),
                    number: Some(0),
                    ..Default::default()
                },
                EnumValueDescriptorProto {
                    name: Some("COLOUR_blue".into()),
                    number: Some(1),
                    ..Default::default()
                },
            ],
            ..Default::default()
        }],
        service: vec![ServiceDescriptorProto {
            name: Some("Planner".into()),
            method: ["Get", "Put"]
                .map(|n| MethodDescriptorProto {
                    name: Some(n.into()),
                    input_type: Some(".resecta.v1.Thing".into()),
                    output_type: Some(".resecta.v1.GetResponse".into()),
                    ..Default::default()
                })
                .to_vec(),
            ..Default::default()
        }],
        ..Default::default()
    };
    let found = lint(&[&bad]).join("\n");
    for expected in [
        "file must be resecta/v1/<lower_snake_case>.proto",
        "message bad_message: name must be PascalCase",
        "message bad_message has no leading comment",
        "field bad_message.camelCase: name must be lower_snake_case",
        "field bad_message.grid_1: name must be lower_snake_case",
        "oneof bad_message.Choice: name must be lower_snake_case",
        "enum Colour: first value must be COLOUR_UNSPECIFIED = 0",
        "enum value Colour.RED: must be UPPER_SNAKE_CASE prefixed COLOUR_",
        "enum value Colour.COLOUR_blue: must be UPPER_SNAKE_CASE prefixed COLOUR_",
        "service Planner: name must be PascalCase ending in Service",
        "rpc Planner.Get: request .resecta.v1.Thing must be .resecta.v1.GetRequest",
        "rpc Planner.Put: response .resecta.v1.GetResponse must be .resecta.v1.PutResponse",
        "rpc Planner.Put has no leading comment",
        ".resecta.v1.Thing is used by 2 RPCs",
    ] {
        assert!(
            found.contains(expected),
            "missing {expected:?} in:\n{found}"
        );
    }
}

#[test]
fn name_rules() {
    assert!(is_lower_snake("violating_area_mm2"));
    assert!(!is_lower_snake("area_2d"));
    assert!(!is_lower_snake("_x"));
    assert!(is_upper_snake("DATA_TYPE_UINT8"));
    assert!(!is_upper_snake("DATA__TYPE"));
    assert_eq!(upper_snake_of("LabelMapFormat"), "LABEL_MAP_FORMAT");
}
