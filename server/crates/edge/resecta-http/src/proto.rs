//! The `resecta.v1` descriptors (`resecta_api::FILE_DESCRIPTOR_SET`), decoded once: messages by
//! name, their fields with JSON names and comments, the service's methods. The OpenAPI document
//! is generated from them, and query parameters are read as request fields through them.

use std::sync::LazyLock;

use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, EnumDescriptorProto, FieldDescriptorProto, FileDescriptorSet,
    MethodDescriptorProto, SourceCodeInfo,
};
use serde_json::{Map, Value};

/// The package every message of the API is in.
pub const PACKAGE: &str = "resecta.v1";

/// A message, an enum or a method with its leading comment.
#[derive(Debug)]
pub struct Documented<T> {
    pub item: T,
    pub comment: String,
}

/// What the descriptor set holds of `resecta.v1`, with comments.
#[derive(Debug, Default)]
pub struct Api {
    /// Every message by full name (`resecta.v1.EditRequest`), nested ones included, each field's
    /// comment beside it.
    pub messages: Vec<(String, Documented<DescriptorProto>, Vec<String>)>,
    pub enums: Vec<(String, Documented<EnumDescriptorProto>)>,
    /// `PlanningService`'s methods in declaration order.
    pub methods: Vec<Documented<MethodDescriptorProto>>,
}

fn comment(info: Option<&SourceCodeInfo>, path: &[i32]) -> String {
    info.and_then(|i| i.location.iter().find(|l| l.path == path))
        .and_then(|l| l.leading_comments.as_deref())
        .map(|c| {
            c.trim()
                .lines()
                .map(str::trim)
                .collect::<Vec<_>>()
                .join(" ")
        })
        .unwrap_or_default()
}

fn add_message(
    api: &mut Api,
    info: Option<&SourceCodeInfo>,
    scope: &str,
    path: Vec<i32>,
    m: &DescriptorProto,
) {
    let name = format!("{scope}.{}", m.name());
    let fields = (0..m.field.len())
        .map(|k| comment(info, &[path.as_slice(), &[2, k as i32]].concat()))
        .collect();
    for (k, nested) in m.nested_type.iter().enumerate() {
        add_message(
            api,
            info,
            &name,
            [path.as_slice(), &[3, k as i32]].concat(),
            nested,
        );
    }
    for (k, e) in m.enum_type.iter().enumerate() {
        let item = Documented {
            item: e.clone(),
            comment: comment(info, &[path.as_slice(), &[4, k as i32]].concat()),
        };
        api.enums.push((format!("{name}.{}", e.name()), item));
    }
    let item = Documented {
        item: m.clone(),
        comment: comment(info, &path),
    };
    api.messages.push((name, item, fields));
}

fn decode() -> Api {
    let mut api = Api::default();
    let Ok(set) = FileDescriptorSet::decode(resecta_api::FILE_DESCRIPTOR_SET) else {
        return api;
    };
    for file in set.file.iter().filter(|f| f.package() == PACKAGE) {
        let info = file.source_code_info.as_ref();
        for (k, m) in file.message_type.iter().enumerate() {
            add_message(&mut api, info, PACKAGE, vec![4, k as i32], m);
        }
        for (k, e) in file.enum_type.iter().enumerate() {
            let item = Documented {
                item: e.clone(),
                comment: comment(info, &[5, k as i32]),
            };
            api.enums.push((format!("{PACKAGE}.{}", e.name()), item));
        }
        for (s, service) in file.service.iter().enumerate() {
            for (k, m) in service.method.iter().enumerate() {
                api.methods.push(Documented {
                    item: m.clone(),
                    comment: comment(info, &[6, s as i32, 2, k as i32]),
                });
            }
        }
    }
    api
}

static API: LazyLock<Api> = LazyLock::new(decode);

/// The API's descriptors.
pub fn api() -> &'static Api {
    &API
}

impl Api {
    /// The message `full_name` (`resecta.v1.X`, without a leading dot).
    pub fn message(&self, full_name: &str) -> Option<&DescriptorProto> {
        self.messages
            .iter()
            .find(|(n, ..)| n == full_name)
            .map(|(_, m, _)| &m.item)
    }

    /// The method `name` of `PlanningService`.
    pub fn method(&self, name: &str) -> Option<&MethodDescriptorProto> {
        self.methods
            .iter()
            .map(|m| &m.item)
            .find(|m| m.name() == name)
    }
}

/// A field's name in proto JSON: its `json_name`, else lowerCamelCase of its name.
pub fn json_name(f: &FieldDescriptorProto) -> String {
    if let Some(j) = &f.json_name {
        return j.clone();
    }
    let mut out = String::new();
    let mut upper = false;
    for c in f.name().chars() {
        if c == '_' {
            upper = true;
        } else if upper {
            out.extend(c.to_uppercase());
            upper = false;
        } else {
            out.push(c);
        }
    }
    out
}

/// Whether `f` can be a query parameter: a single scalar, string or enum.
pub fn is_scalar(f: &FieldDescriptorProto) -> bool {
    f.label() != Label::Repeated && !matches!(f.r#type(), Type::Message | Type::Group)
}

/// The query parameters `pairs` as the proto JSON object of message `full_name`: each key is a
/// field's proto or JSON name; booleans become JSON booleans, every other value stays a string
/// (the mapping accepts numbers and enum names as strings).
pub fn query_json(full_name: &str, pairs: Vec<(String, String)>) -> Result<Value, String> {
    let message = api()
        .message(full_name)
        .ok_or_else(|| format!("no message {full_name}"))?;
    let mut out = Map::new();
    for (key, value) in pairs {
        let field = message
            .field
            .iter()
            .find(|f| f.name() == key || json_name(f) == key)
            .filter(|f| is_scalar(f))
            .ok_or_else(|| format!("unknown parameter {key:?}"))?;
        let value = if field.r#type() == Type::Bool {
            match value.as_str() {
                "true" => Value::Bool(true),
                "false" => Value::Bool(false),
                _ => return Err(format!("{key} must be true or false")),
            }
        } else {
            Value::String(value)
        };
        if out.insert(json_name(field), value).is_some() {
            return Err(format!("{key} is given twice"));
        }
    }
    Ok(Value::Object(out))
}

/// Whether `f` holds an integer (32- or 64-bit, signed or not).
fn is_integer(f: &FieldDescriptorProto) -> bool {
    matches!(
        f.r#type(),
        Type::Int32
            | Type::Sint32
            | Type::Sfixed32
            | Type::Uint32
            | Type::Fixed32
            | Type::Int64
            | Type::Sint64
            | Type::Sfixed64
            | Type::Uint64
            | Type::Fixed64
    )
}

/// `v` as an integer JSON number when it is a number with an integral value in range (`5.0`,
/// `5e0`): JSON (and JSON Schema's `integer`) does not tell `5.0` from `5`, and protobuf's
/// JSON parsers take both; pbjson takes only the first form.
fn integral(v: &mut Value) {
    let Some(x) = v.as_f64().filter(|_| !v.is_i64() && !v.is_u64()) else {
        return;
    };
    // 2^63 and 2^64 are exact in f64; the casts are exact below them.
    if x.fract() == 0.0 && (-9_223_372_036_854_775_808.0..9_223_372_036_854_775_808.0).contains(&x)
    {
        *v = Value::from(x as i64);
    } else if x.fract() == 0.0 && (0.0..18_446_744_073_709_551_616.0).contains(&x) {
        *v = Value::from(x as u64);
    }
}

/// Rewrites the integral numbers of integer fields in `value`, the proto JSON of message
/// `full_name` (nested messages too), as integers (see [`integral`]). Anything else is left for
/// the message's deserializer to judge.
pub fn integral_numbers(full_name: &str, value: &mut Value) {
    let (Some(message), Some(object)) = (api().message(full_name), value.as_object_mut()) else {
        return;
    };
    for (key, v) in object.iter_mut() {
        let Some(field) = message
            .field
            .iter()
            .find(|f| f.name() == key || json_name(f) == *key)
        else {
            continue;
        };
        let values: Vec<&mut Value> = if field.label() == Label::Repeated
            && let Value::Array(items) = v
        {
            items.iter_mut().collect()
        } else {
            vec![v]
        };
        for item in values {
            if is_integer(field) {
                integral(item);
            } else if field.r#type() == Type::Message {
                integral_numbers(field.type_name().trim_start_matches('.'), item);
            }
        }
    }
}
