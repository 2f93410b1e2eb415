//! What the server enforces beyond the proto types, as JSON Schema keywords of the document:
//! the ranges, lengths, patterns and required fields of the wire validation
//! (`resecta_face::convert`), the operation layer and the plan, each from the constant that
//! enforces it ([`resecta_face::info::limits`]); and, in words, what a schema cannot say
//! (relations between fields, the session's state).

use resecta_face::info::limits::*;
use serde_json::{Map, Value, json};

/// No control character (Unicode general category Cc), as `char::is_control` refuses.
const NO_CONTROL: &str = r"^[^\u0000-\u001F\u007F-\u009F]*$";

/// At least one character that is not Unicode White_Space (what `str::trim` removes): a name
/// that is not blank.
const NOT_BLANK: &str =
    r"[^\u0009-\u000D\u0020\u0085\u00A0\u1680\u2000-\u200A\u2028\u2029\u202F\u205F\u3000]";

/// The request field the path's `{id}` fills: left out of the request bodies and upload
/// headers (one may still carry it when it equals the path's; another id is refused).
pub const SESSION_FIELD: &str = "sessionId";

/// Enums whose zero value (`*_UNSPECIFIED`) is never valid on the wire: refused in requests
/// (`convert::known`) or never sent. They are offered without it.
pub const NO_ZERO: [&str; 8] = [
    "resecta.v1.DataType",
    "resecta.v1.LabelMapFormat",
    "resecta.v1.ControlGroup",
    "resecta.v1.ModelFormat",
    "resecta.v1.NormalSource",
    "resecta.v1.SessionState",
    "resecta.v1.SliceAxis",
    "resecta.v1.SurfaceKind",
];

fn label() -> Value {
    json!({"type": "integer", "minimum": 1, "maximum": MAX_LABEL})
}

/// A finite double (JSON has no NaN or infinities; these bounds keep out numbers that overflow).
pub fn finite() -> Value {
    json!({"type": "number", "minimum": -f64::MAX, "maximum": f64::MAX})
}

fn coordinate() -> Value {
    json!({"type": "number", "minimum": -MAX_COORDINATE_MM, "maximum": MAX_COORDINATE_MM})
}

/// A resection's name where a new resection is named (init, add).
fn new_name() -> Value {
    json!({"minLength": 1, "maxLength": MAX_NAME_LEN, "pattern": NOT_BLANK,
           "description": format!("1..={MAX_NAME_LEN} bytes of UTF-8 (`maxLength` counts characters: a name of multi-byte characters is refused sooner), not blank; a name in use is refused.")})
}

/// A grid side of an init: 0 (the default, [`DEFAULT_GRID`]) or a side of a resection grid.
fn init_side() -> Value {
    let below: Vec<usize> = (1..MIN_CONTROL_POINTS).collect();
    json!({"maximum": MAX_CONTROL_POINTS, "not": {"enum": below}})
}

fn side() -> Value {
    json!({"minimum": MIN_CONTROL_POINTS, "maximum": MAX_CONTROL_POINTS})
}

fn resolution() -> Value {
    json!({"minimum": MIN_RESOLUTION, "maximum": MAX_RESOLUTION})
}

fn margin() -> Value {
    json!({"exclusiveMinimum": 0, "maximum": MAX_MARGIN_MM})
}

fn band() -> Value {
    json!({"minimum": 0, "maximum": MAX_MARGIN_MM})
}

fn control_points() -> Value {
    json!({"minItems": MIN_CONTROL_POINTS * MIN_CONTROL_POINTS,
           "maxItems": MAX_CONTROL_POINTS * MAX_CONTROL_POINTS})
}

/// Extra keywords of field `field` (JSON name) of message `message` (full name), merged into
/// its schema (`items` into the items' schema).
pub fn field(message: &str, field: &str) -> Option<Value> {
    let short = message.trim_start_matches("resecta.v1.");
    Some(match (short, field) {
        ("CreateSessionRequest", "displayName") => {
            json!({"minLength": 1, "maxLength": MAX_DISPLAY_NAME, "pattern": NO_CONTROL})
        }
        ("Vec3", "x" | "y" | "z") => coordinate(),
        ("RoleMap", "parenchyma" | "tumor") => json!({"minItems": 1, "items": label()}),
        ("RoleMap", _) => json!({"items": label()}),
        ("Target", "labels") => json!({"maxItems": MAX_TARGET_LABELS, "items": label()}),
        ("Target", "points") => json!({"maxItems": MAX_TARGET_POINTS}),
        ("RawLabelMapHeader", "dims") => {
            json!({"minItems": 3, "maxItems": 3, "items": {"minimum": 1}})
        }
        ("RawLabelMapHeader", "spacing") => json!({"minItems": 3, "maxItems": 3,
            "items": {"minimum": SPACING_MM.start(), "maximum": SPACING_MM.end()}}),
        ("RawLabelMapHeader", "origin") => json!({"minItems": 3, "maxItems": 3,
            "items": {"minimum": -MAX_ORIGIN_MM, "maximum": MAX_ORIGIN_MM}}),
        ("RawLabelMapHeader", "direction") => json!({"minItems": 9, "maxItems": 9}),
        ("ReconstructOptions", "psrDepth") => {
            json!({"minimum": PSR_DEPTHS.start(), "maximum": PSR_DEPTHS.end()})
        }
        ("ReconstructOptions", "smoothing") => {
            json!({"minimum": SMOOTHING.start(), "maximum": SMOOTHING.end()})
        }
        ("ReconstructOptions", "decimation") => {
            json!({"minimum": DECIMATION.start, "exclusiveMaximum": DECIMATION.end})
        }
        ("ReconstructOptions", "minComponentMm3") => json!({"minimum": 0}),
        ("InitFromEndPoint" | "InitFromPlane", "name") => new_name(),
        ("InitFromEndPoint" | "InitFromPlane", "gridM" | "gridN") => init_side(),
        ("SetControlPoints", "points") => control_points(),
        ("Rotate", "angleDeg") => json!({"minimum": -MAX_ANGLE_DEG, "maximum": MAX_ANGLE_DEG}),
        ("SetMargin", "marginMm") | ("Resection", "marginMm") => margin(),
        ("SetBand", "bandMm") | ("Resection", "bandMm") => band(),
        ("SetResolution" | "Resection", "ru" | "rv") => resolution(),
        ("Resection", "name") => new_name(),
        ("Resection", "gridM" | "gridN") => side(),
        ("Resection", "controlPoints") => control_points(),
        ("Resection", "traces") => json!({"maxItems": MAX_TRACES}),
        ("Resection", "deformations") => json!({"maxItems": MAX_DEFORMATIONS}),
        ("Trace", "points") => json!({"minItems": MIN_TRACE_POINTS, "maxItems": MAX_TRACE_POINTS}),
        ("Deformation", "offsetMm") => {
            json!({"minimum": -MAX_OFFSET_MM, "maximum": MAX_OFFSET_MM})
        }
        ("Deformation", "radiusMm") => json!({"exclusiveMinimum": 0, "maximum": MAX_RADIUS_MM}),
        ("GetResectogramRequest", "width" | "height") => {
            json!({"minimum": 0, "maximum": MAX_RESECTOGRAM_SIDE})
        }
        ("GetLabelSliceRequest", "positionMm") => finite(),
        ("GetLabelSliceRequest", "pixelMm") => {
            json!({"exclusiveMinimum": 0, "maximum": MAX_LABEL_SLICE_PIXEL_MM})
        }
        ("ReconstructPointsRequest", "positions") => {
            json!({"minItems": 3 * MIN_CLOUD_POINTS, "items": coordinate()})
        }
        ("ReconstructPointsRequest", "depth") => json!({"maximum": PSR_DEPTHS.end()}),
        ("ReconstructPointsRequest", "neighbours") => {
            let below: Vec<usize> = (1..MIN_CLOUD_NEIGHBOURS).collect();
            json!({"maximum": MAX_CLOUD_NEIGHBOURS, "not": {"enum": below}})
        }
        ("ImportPlanRequest", "planJson") => json!({
            "minLength": 1, "contentMediaType": "application/json",
            "contentSchema": {"$ref": "#/components/schemas/PlanDocument"},
            "description": format!("A `resecta-plan/1` JSON document (schema `PlanDocument`), at most {MAX_PLAN_BYTES} bytes; anything else is refused (400 `BAD_PLAN`), and so is a plan whose role map differs from the session's label map's.")}),
        _ => return None,
    })
}

/// Fields (JSON names) a request must carry: absent, they are the proto default, which the
/// server refuses (an empty string, an UNSPECIFIED enum, a missing message, a 0 out of range).
pub fn required(message: &str) -> &'static [&'static str] {
    match message.trim_start_matches("resecta.v1.") {
        "CreateSessionRequest" => &["displayName"],
        "RoleMap" => &["parenchyma", "tumor"],
        "RawLabelMapHeader" => &["dims", "spacing", "origin", "direction", "dataType"],
        "FileLabelMapHeader" => &["format"],
        "InitFromEndPoint" => &["name", "endPoint"],
        "InitFromPlane" => &["name", "planePoint", "planeNormal"],
        "SetControlPoint" => &["point"],
        "SetControlPoints" => &["points"],
        "MoveGroup" | "Translate" => &["delta"],
        "Rotate" => &["axis"],
        "SetMargin" => &["marginMm"],
        "SetResolution" => &["ru", "rv"],
        "AddResection" => &["resection"],
        "Resection" => &["name", "marginMm", "ru", "rv"],
        "AddTrace" | "SetTrace" => &["trace"],
        "Trace" => &["points"],
        "AddDeformation" => &["deformation"],
        "Deformation" => &["point", "radiusMm"],
        "ImportPlanRequest" => &["planJson"],
        "ExportModelRequest" => &["format"],
        "GetSlicesRequest" => &["resection"],
        "GetLabelSliceRequest" => &["axis"],
        "GetResectogramRequest" => &["resection"],
        "ReconstructPointsRequest" => &["positions"],
        _ => &[],
    }
}

/// Query fields of a GET route's request message that the HTTP face refuses, and why.
pub fn refused_query(message: &str, field: &str) -> Option<&'static str> {
    match (message.trim_start_matches("resecta.v1."), field) {
        ("GetSlicesRequest", "model") => {
            Some("`model=` is refused (501 `UNSUPPORTED`): only resections are sliced so far.")
        }
        _ => None,
    }
}

/// The oneof of `message` a request must set (exactly one of its fields).
pub fn required_oneof(message: &str) -> Option<&'static str> {
    match message.trim_start_matches("resecta.v1.") {
        "EditRequest" => Some("edit"),
        "MoveGroup" => Some("selection"),
        _ => None,
    }
}

/// What the server refuses beyond the schema of `message`, in words.
pub fn note(message: &str) -> Option<String> {
    Some(match message.trim_start_matches("resecta.v1.") {
        "RoleMap" => "Each label belongs to at most one role (refused otherwise). In an upload, some parenchyma label and some tumour label must occur in the label map.".to_owned(),
        "RawLabelMapHeader" => format!("Also refused: `totalBytes` (when given) other than dims[0]·dims[1]·dims[2]·size of `dataType`, and a body of another length; a `direction` that is singular or whose columns are not orthogonal; a side (voxels × spacing) longer than {MAX_EXTENT_MM} mm; voxel values outside 0..={MAX_LABEL}; INT8 data holding negative values; more voxels than `ServerLimits.max_voxels` (413)."),
        "FileLabelMapHeader" => "Also refused: `totalBytes` (when given) other than the body's length, a file that is not in `format`, or whose geometry or labels are out of range as for raw uploads.".to_owned(),
        "Target" => format!("`labels` must be tumour labels of the session's role map present in its label map, and a tumour label that does not touch the liver is refused; each point must lie within {TARGET_POINT_SNAP_MM} mm of a tumour component (all refused with 400 otherwise)."),
        "InitFromEndPoint" => format!("The end point must lie at least {MIN_END_DISTANCE_MM} mm from the target's centroid, and the plane it gives must cut the liver (400 otherwise)."),
        "InitFromPlane" => "`planeNormal` must be non-zero, and the plane must cut the liver (400 otherwise).".to_owned(),
        "SetControlPoint" => "`i` and `j` must lie in the resection's grid (400 otherwise); an unknown name is 404.".to_owned(),
        "SetControlPoints" => "As many points as the resection's grid has (gridM·gridN; 400 otherwise).".to_owned(),
        "MoveGroup" => "The group must hold some point of the resection's grid (a ring beyond its middle is refused), and the moved points must stay within the coordinate range.".to_owned(),
        "Translate" => "The moved points must stay within the coordinate range.".to_owned(),
        "Rotate" => "`axis` must be non-zero, and the rotated points must stay within the coordinate range.".to_owned(),
        "Resection" => format!("By `kind`: a Bézier resection (BEZIER, or UNSPECIFIED as older clients send) needs `gridM`, `gridN` and `controlPoints`, and refuses traces and deformations. In a request, `controlPoints` holds exactly gridM·gridN points. DS and CP resections are given by `traces` and refuse a control grid; a DS resection needs {MIN_TRACES} or more traces on axis-aligned slices of one orientation (points within {SLICE_TOLERANCE_MM} mm of their slice), one trace per slice, none crossing itself; a CP resection's traces must span a plane, and only CP resections take `deformations`, each of whose point must project onto the plane (all refused with 400 otherwise)."),
        "Trace" => "A trace with no length (all points equal) is refused.".to_owned(),
        "GetLabelSliceRequest" => format!("`positionMm` must lie within the label map's extent along the axis (the answer's `minPositionMm`..=`maxPositionMm`; 400 otherwise). The pixel size is raised so that neither side of the raster exceeds {MAX_LABEL_SLICE_SIDE} pixels. 409 `NO_LABEL_MAP` before a label map is loaded."),
        "GetResectogramRequest" => format!("`width` and `height` of 0 (or absent) mean {DEFAULT_RESECTOGRAM_SIDE}; at most {MAX_RESECTOGRAM_SIDE} each (400 otherwise). An unknown resection is 404; 409 `NO_LABEL_MAP` before a label map is loaded."),
        "ReconstructPointsRequest" => format!("Also refused (400): `positions` that are not a multiple of 3 values; `normals` neither empty nor as long as `positions`; fewer than {MIN_CLOUD_POINTS} distinct points; `neighbours` not below the number of distinct points; points all on one line (without normals); a zero normal; more points than `ServerLimits.max_cloud_points`; a `depth` above `ServerLimits.max_cloud_depth` (default 8); and a cloud whose surface cannot be built (a degenerate point set). A `depth` of 0 means {DEFAULT_CLOUD_DEPTH}, `neighbours` of 0 mean {DEFAULT_CLOUD_NEIGHBOURS}. The server's memory budget may refuse a deep grid (413 `MEMORY_QUOTA`)."),
        "EditRequest" => "Every edit but init and add names an existing resection (404 otherwise); undo and redo need something to undo or redo (409 otherwise); a non-zero `baseVersion` other than the plan's version is 409 `STALE_VERSION`. Edits apply to kinds: control points and groups to Bézier resections, traces to DS and CP resections, deformations to CP resections, the resolution to Bézier and DS resections (a CP resection is sampled at its grid); translate, rotate, margin, band and target to every kind; another pairing is refused (400). A trace edit must leave a valid surface (as `Resection` says), a trace index must exist, and undoing a deformation needs one (400 otherwise).".to_owned(),
        _ => return None,
    })
}

/// The `resecta-plan/1` document (`ImportPlanRequest.planJson`, `ExportPlanResponse.planJson`),
/// as the plan reads it: unknown fields are refused, and so are missing required ones.
pub fn plan_document() -> Value {
    let labels = json!({"type": "array", "minItems": 1, "items": label()});
    let roles: Map<String, Value> = ["parenchyma", "tumor", "portal", "hepatic", "vessel"]
        .into_iter()
        .map(|r| (r.to_owned(), labels.clone()))
        .collect();
    let point = json!({"type": "array", "minItems": 3, "maxItems": 3, "items": coordinate()});
    let pair = |lo: usize, hi: usize| {
        json!({"type": "array", "minItems": 2, "maxItems": 2,
               "items": {"type": "integer", "minimum": lo, "maximum": hi}})
    };
    let resection = json!({
        "type": "object",
        "additionalProperties": false,
        "required": ["name"],
        "description": "One resection. A Bézier resection (`kind` absent or `bezier`) needs `grid` and `control_points`, and `control_points` holds exactly grid[0]·grid[1] points; a `ds` or `cp` resection is given by `traces` (and a `cp` one by `deformations` too) and refuses a grid, under the rules of the API's `Resection`; names are unique in the plan; target labels are tumour labels of `roles` (all refused otherwise).",
        "properties": {
            "name": {"type": "string", "minLength": 1, "maxLength": MAX_NAME_LEN, "pattern": NOT_BLANK,
                     "description": format!("1..={MAX_NAME_LEN} bytes of UTF-8 (`maxLength` counts characters: a name of multi-byte characters is refused sooner), not blank.")},
            "kind": {"enum": ["bezier", "ds", "cp"]},
            "traces": {"type": "array", "maxItems": MAX_TRACES,
                       "items": {"type": "array", "items": point,
                                 "minItems": MIN_TRACE_POINTS, "maxItems": MAX_TRACE_POINTS}},
            "deformations": {"type": "array", "maxItems": MAX_DEFORMATIONS, "items": {
                "type": "object", "additionalProperties": false,
                "required": ["point", "offset_mm", "radius_mm"],
                "properties": {
                    "point": point,
                    "offset_mm": {"type": "number", "minimum": -MAX_OFFSET_MM, "maximum": MAX_OFFSET_MM},
                    "radius_mm": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_RADIUS_MM}}}},
            "grid": pair(MIN_CONTROL_POINTS, MAX_CONTROL_POINTS),
            "control_points": {"type": "array", "items": point,
                               "minItems": MIN_CONTROL_POINTS * MIN_CONTROL_POINTS,
                               "maxItems": MAX_CONTROL_POINTS * MAX_CONTROL_POINTS},
            "margin_mm": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_MARGIN_MM},
            "band_mm": {"type": "number", "minimum": 0, "maximum": MAX_MARGIN_MM},
            "target": {"type": "object", "additionalProperties": false, "properties": {
                "labels": {"type": "array", "maxItems": MAX_TARGET_LABELS, "items": label()},
                "points": {"type": "array", "maxItems": MAX_TARGET_POINTS, "items": point}}},
            "resolution": pair(MIN_RESOLUTION, MAX_RESOLUTION)
        }
    });
    json!({
        "type": "object",
        "description": "A `resecta-plan/1` plan file (not a protobuf message: snake_case keys). Unknown fields are refused everywhere in it.",
        "additionalProperties": false,
        "required": ["format", "roles"],
        "properties": {
            "format": {"const": PLAN_FORMAT},
            "roles": {"type": "object", "additionalProperties": false, "required": ["tumor"],
                      "properties": roles,
                      "description": "Role → label values; each label in at most one role. `tumor` is required: resections need tumour labels, and ImportPlan takes only the session's label map's role map, which has some."},
            "resections": {"type": "array", "maxItems": MAX_RESECTIONS, "items": resection}
        }
    })
}
