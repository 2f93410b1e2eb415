//! Wire (`resecta.v1` prost messages) ⇄ operation layer (`resecta_session::api`) translation, in
//! one place for both faces. Inbound conversions validate what the wire type cannot express (required fields,
//! finite numbers, array lengths, UNSPECIFIED enums, label ranges) and name the offending field;
//! the operation layer checks the rest (ranges of plan parameters, geometry, quotas).

use std::collections::BTreeMap;

use resecta_api::v1 as pb;
use resecta_geom::{Mat3, Real, Role, RoleMap};
use resecta_io::mesh::MeshFormat;
use resecta_plan::resection::ResectionKind;

use crate::info::saturating_u32;
use resecta_plan::resection::MAX_COORDINATE_MM;
use resecta_plan::{
    CutVessel, Deformation, Group, IncompleteCut, LabelSlice, PlanEvent, Resection, Resectogram,
    RiskMap, RiskReport, SliceAxis, SlicePositions, SliceProjections, Target, Verdict,
    VolumeReport,
};
use resecta_session::api::{
    CloudSurface, DEFAULT_GRID, DataType, EditOp, EditOutcome, FileFormat, LabelMapSummary,
    ModelInfo, NormalSource, PointCloud, ReconMethod, ReconOptions, ReconstructEvent, SessionInfo,
    SessionState, Surface, SurfaceKind,
};

use crate::error::WireError;
use resecta_session::SessionError;

type Wire<T> = Result<T, WireError>;

pub use resecta_session::api::{DECIMATION, PSR_DEPTHS, SMOOTHING};

// ---- inbound ---------------------------------------------------------------------------------

fn finite(field: &str, v: f64) -> Wire<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(WireError::invalid(
            field,
            format!("must be finite, got {v}"),
        ))
    }
}

fn point(field: &str, v: &pb::Vec3) -> Wire<[Real; 3]> {
    Ok([
        finite(&format!("{field}.x"), v.x)?,
        finite(&format!("{field}.y"), v.y)?,
        finite(&format!("{field}.z"), v.z)?,
    ])
}

/// A repeated `Vec3` field, every coordinate finite.
fn points(field: &str, values: &[pb::Vec3]) -> Wire<Vec<[Real; 3]>> {
    values
        .iter()
        .enumerate()
        .map(|(k, p)| point(&format!("{field}[{k}]"), p))
        .collect()
}

/// A required `Vec3` field.
fn required(field: &str, v: Option<&pb::Vec3>) -> Wire<[Real; 3]> {
    point(
        field,
        v.ok_or_else(|| WireError::invalid(field, "is required"))?,
    )
}

/// Exactly `N` finite values.
fn array<const N: usize>(field: &str, values: &[f64]) -> Wire<[Real; N]> {
    let a: [f64; N] = values.try_into().map_err(|_| {
        WireError::invalid(
            field,
            format!("needs exactly {N} values, got {}", values.len()),
        )
    })?;
    for (k, &v) in a.iter().enumerate() {
        finite(&format!("{field}[{k}]"), v)?;
    }
    Ok(a)
}

fn label(field: &str, v: u32) -> Wire<u16> {
    u16::try_from(v)
        .ok()
        .filter(|&l| l != 0)
        .ok_or_else(|| WireError::invalid(field, format!("label {v} is outside 1..=65535")))
}

fn labels(field: &str, values: &[u32]) -> Wire<Vec<u16>> {
    values
        .iter()
        .enumerate()
        .map(|(k, &v)| label(&format!("{field}[{k}]"), v))
        .collect()
}

/// A non-UNSPECIFIED value of a proto enum.
fn known<E: TryFrom<i32>>(field: &str, v: i32) -> Wire<E> {
    if v == 0 {
        return Err(WireError::invalid(field, "must not be UNSPECIFIED"));
    }
    E::try_from(v).map_err(|_| WireError::invalid(field, format!("unknown value {v}")))
}

/// The role map of an upload; absent: the default `{parenchyma:[1], tumor:[2], portal:[3],
/// hepatic:[4]}`.
pub fn role_map(field: &str, roles: Option<&pb::RoleMap>) -> Wire<RoleMap> {
    let Some(r) = roles else {
        return Ok(RoleMap::default());
    };
    let mut map = BTreeMap::new();
    for (role, values) in [
        (Role::Parenchyma, &r.parenchyma),
        (Role::Tumor, &r.tumor),
        (Role::Portal, &r.portal),
        (Role::Hepatic, &r.hepatic),
        (Role::Vessel, &r.vessel),
    ] {
        if !values.is_empty() {
            map.insert(role, labels(&format!("{field}.{}", role.name()), values)?);
        }
    }
    RoleMap::try_from(map).map_err(|e| WireError::invalid(field, e.to_string()))
}

fn target(field: &str, t: Option<&pb::Target>) -> Wire<Target> {
    let Some(t) = t else {
        return Ok(Target::default());
    };
    Ok(Target {
        labels: labels(&format!("{field}.labels"), &t.labels)?,
        points: points(&format!("{field}.points"), &t.points)?,
    })
}

/// Grid size of an init: 0 means the default ([`DEFAULT_GRID`]).
fn grid(m: u32, n: u32) -> [usize; 2] {
    let side = |v: u32, default: usize| if v == 0 { default } else { v as usize };
    [side(m, DEFAULT_GRID[0]), side(n, DEFAULT_GRID[1])]
}

/// A resection as given on the wire (`AddResection`); the plan checks the ranges.
fn resection_in(field: &str, r: Option<&pb::Resection>) -> Wire<Resection> {
    let r = r.ok_or_else(|| WireError::invalid(field, "is required"))?;
    Ok(Resection {
        name: r.name.clone(),
        // UNSPECIFIED is BEZIER: resections of clients that predate the kinds.
        kind: match pb::ResectionKind::try_from(r.kind).map_err(|_| {
            WireError::invalid(format!("{field}.kind"), format!("unknown value {}", r.kind))
        })? {
            pb::ResectionKind::Unspecified | pb::ResectionKind::Bezier => ResectionKind::Bezier,
            pb::ResectionKind::Ds => ResectionKind::Ds,
            pb::ResectionKind::Cp => ResectionKind::Cp,
        },
        grid: [r.grid_m as usize, r.grid_n as usize],
        control_points: points(&format!("{field}.control_points"), &r.control_points)?,
        traces: r
            .traces
            .iter()
            .enumerate()
            .map(|(k, t)| trace(&format!("{field}.traces[{k}]"), Some(t)))
            .collect::<Wire<_>>()?,
        deformations: r
            .deformations
            .iter()
            .enumerate()
            .map(|(k, d)| deformation(&format!("{field}.deformations[{k}]"), Some(d)))
            .collect::<Wire<_>>()?,
        margin_mm: finite(&format!("{field}.margin_mm"), r.margin_mm)?,
        band_mm: finite(&format!("{field}.band_mm"), r.band_mm)?,
        target: target(&format!("{field}.target"), r.target.as_ref())?,
        resolution: [r.ru as usize, r.rv as usize],
    })
}

fn trace(field: &str, t: Option<&pb::Trace>) -> Wire<Vec<[Real; 3]>> {
    let t = t.ok_or_else(|| WireError::invalid(field, "is required"))?;
    points(&format!("{field}.points"), &t.points)
}

fn deformation(field: &str, d: Option<&pb::Deformation>) -> Wire<Deformation> {
    let d = d.ok_or_else(|| WireError::invalid(field, "is required"))?;
    Ok(Deformation {
        point: required(&format!("{field}.point"), d.point.as_ref())?,
        offset_mm: finite(&format!("{field}.offset_mm"), d.offset_mm)?,
        radius_mm: finite(&format!("{field}.radius_mm"), d.radius_mm)?,
    })
}

/// The operation of an `EditRequest`.
pub fn edit(edit: Option<&pb::edit_request::Edit>) -> Wire<EditOp> {
    use pb::edit_request::Edit as E;
    let event = |event| Ok(EditOp::Event { event });
    match edit.ok_or_else(|| WireError::invalid("edit", "is required"))? {
        E::InitFromEndPoint(e) => Ok(EditOp::InitFromEndPoint {
            name: e.name.clone(),
            target: target("init_from_end_point.target", e.target.as_ref())?,
            end_point: required("init_from_end_point.end_point", e.end_point.as_ref())?,
            grid: grid(e.grid_m, e.grid_n),
        }),
        E::InitFromPlane(e) => Ok(EditOp::InitFromPlane {
            name: e.name.clone(),
            target: target("init_from_plane.target", e.target.as_ref())?,
            point: required("init_from_plane.plane_point", e.plane_point.as_ref())?,
            normal: required("init_from_plane.plane_normal", e.plane_normal.as_ref())?,
            grid: grid(e.grid_m, e.grid_n),
        }),
        E::SetControlPoint(e) => event(PlanEvent::SetControlPoint {
            name: e.name.clone(),
            i: e.i as usize,
            j: e.j as usize,
            point: required("set_control_point.point", e.point.as_ref())?,
        }),
        E::SetControlPoints(e) => event(PlanEvent::SetControlPoints {
            name: e.name.clone(),
            points: points("set_control_points.points", &e.points)?,
        }),
        E::MoveGroup(e) => {
            use pb::move_group::Selection;
            let group = match e.selection {
                None => return Err(WireError::invalid("move_group.selection", "is required")),
                Some(Selection::Ring(k)) => Group::Ring(k as usize),
                Some(Selection::Group(g)) => match known("move_group.group", g)? {
                    pb::ControlGroup::Inner => Group::Inner,
                    pb::ControlGroup::Outer => Group::Outer,
                    pb::ControlGroup::All => Group::All,
                    pb::ControlGroup::Unspecified => {
                        return Err(WireError::invalid(
                            "move_group.group",
                            "must not be UNSPECIFIED",
                        ));
                    }
                },
            };
            event(PlanEvent::MoveGroup {
                name: e.name.clone(),
                group,
                delta: required("move_group.delta", e.delta.as_ref())?,
            })
        }
        E::Translate(e) => event(PlanEvent::Translate {
            name: e.name.clone(),
            delta: required("translate.delta", e.delta.as_ref())?,
        }),
        E::Rotate(e) => event(PlanEvent::Rotate {
            name: e.name.clone(),
            axis: required("rotate.axis", e.axis.as_ref())?,
            angle_deg: finite("rotate.angle_deg", e.angle_deg)?,
            centre: e
                .centre
                .as_ref()
                .map(|c| point("rotate.centre", c))
                .transpose()?,
        }),
        E::SetMargin(e) => event(PlanEvent::SetMargin {
            name: e.name.clone(),
            margin_mm: finite("set_margin.margin_mm", e.margin_mm)?,
        }),
        E::SetBand(e) => event(PlanEvent::SetBand {
            name: e.name.clone(),
            band_mm: finite("set_band.band_mm", e.band_mm)?,
        }),
        E::SetResolution(e) => event(PlanEvent::SetResolution {
            name: e.name.clone(),
            resolution: [e.ru as usize, e.rv as usize],
        }),
        E::SetTarget(e) => event(PlanEvent::SetTarget {
            name: e.name.clone(),
            target: target("set_target.target", e.target.as_ref())?,
        }),
        E::DeleteResection(e) => event(PlanEvent::DeleteResection {
            name: e.name.clone(),
        }),
        E::AddResection(e) => event(PlanEvent::AddResection {
            resection: resection_in("add_resection.resection", e.resection.as_ref())?,
        }),
        E::AddTrace(e) => event(PlanEvent::AddTrace {
            name: e.name.clone(),
            trace: trace("add_trace.trace", e.trace.as_ref())?,
        }),
        E::SetTrace(e) => event(PlanEvent::SetTrace {
            name: e.name.clone(),
            index: e.index as usize,
            trace: trace("set_trace.trace", e.trace.as_ref())?,
        }),
        E::RemoveTrace(e) => event(PlanEvent::RemoveTrace {
            name: e.name.clone(),
            index: e.index as usize,
        }),
        E::AddDeformation(e) => event(PlanEvent::AddDeformation {
            name: e.name.clone(),
            deformation: deformation("add_deformation.deformation", e.deformation.as_ref())?,
        }),
        E::UndoDeformation(e) => event(PlanEvent::UndoDeformation {
            name: e.name.clone(),
        }),
        E::Undo(_) => Ok(EditOp::Undo),
        E::Redo(_) => Ok(EditOp::Redo),
    }
}

/// Geometry and voxel type of a raw upload, checked against its `total_bytes`.
#[derive(Debug, Clone)]
pub struct RawGeometry {
    pub dims: [usize; 3],
    pub spacing: [Real; 3],
    pub origin: [Real; 3],
    pub direction: [Real; 9],
    pub data_type: DataType,
    /// The wire type was INT8: bytes ≥ 0x80 are negative labels and refused; the rest are the
    /// same bytes as UINT8.
    pub signed_bytes: bool,
}

/// The geometry of a raw upload header.
pub fn raw_geometry(h: &pb::RawLabelMapHeader) -> Wire<RawGeometry> {
    let dims: [u32; 3] = h.dims.as_slice().try_into().map_err(|_| {
        WireError::invalid(
            "raw.dims",
            format!("needs exactly 3 values, got {}", h.dims.len()),
        )
    })?;
    if let Some(k) = dims.iter().position(|&d| d == 0) {
        return Err(WireError::invalid(
            format!("raw.dims[{k}]"),
            "must be at least 1",
        ));
    }
    let spacing = array::<3>("raw.spacing", &h.spacing)?;
    if let Some(k) = spacing.iter().position(|&s| s <= 0.0) {
        return Err(WireError::invalid(
            format!("raw.spacing[{k}]"),
            "must be > 0",
        ));
    }
    let (data_type, signed_bytes) = match known("raw.data_type", h.data_type)? {
        pb::DataType::Uint8 => (DataType::U8, false),
        pb::DataType::Int8 => (DataType::U8, true),
        pb::DataType::Uint16 => (DataType::U16, false),
        pb::DataType::Int16 => (DataType::I16, false),
        pb::DataType::Uint32 => (DataType::U32, false),
        pb::DataType::Int32 => (DataType::I32, false),
        pb::DataType::Unspecified => {
            return Err(WireError::invalid(
                "raw.data_type",
                "must not be UNSPECIFIED",
            ));
        }
    };
    let g = RawGeometry {
        dims: dims.map(|d| d as usize),
        spacing,
        origin: array("raw.origin", &h.origin)?,
        direction: array("raw.direction", &h.direction)?,
        data_type,
        signed_bytes,
    };
    let need = g
        .dims
        .iter()
        .try_fold(data_type.size() as u64, |n, &d| n.checked_mul(d as u64));
    if need != Some(h.total_bytes) {
        return Err(WireError::invalid(
            "raw.total_bytes",
            format!(
                "{}×{}×{} voxels of {} bytes need {} bytes, but total_bytes is {}",
                g.dims[0],
                g.dims[1],
                g.dims[2],
                data_type.size(),
                need.map_or_else(|| "more than 2^64".to_owned(), |n| n.to_string()),
                h.total_bytes
            ),
        ));
    }
    Ok(g)
}

pub fn file_format(v: i32) -> Wire<FileFormat> {
    Ok(match known("file.format", v)? {
        pb::LabelMapFormat::Auto => FileFormat::Auto,
        pb::LabelMapFormat::Nifti => FileFormat::Nifti,
        pb::LabelMapFormat::Nrrd => FileFormat::Nrrd,
        pb::LabelMapFormat::SegNrrd => FileFormat::SegNrrd,
        pb::LabelMapFormat::Metaimage => FileFormat::MetaImage,
        pb::LabelMapFormat::Unspecified => {
            return Err(WireError::invalid("file.format", "must not be UNSPECIFIED"));
        }
    })
}

pub fn mesh_format(v: i32) -> Wire<MeshFormat> {
    Ok(match known("format", v)? {
        pb::ModelFormat::Vtp => MeshFormat::Vtp,
        pb::ModelFormat::Vtk => MeshFormat::Vtk,
        pb::ModelFormat::Stl => MeshFormat::Stl,
        pb::ModelFormat::Ply => MeshFormat::Ply,
        pb::ModelFormat::Obj => MeshFormat::Obj,
        pb::ModelFormat::Unspecified => {
            return Err(WireError::invalid("format", "must not be UNSPECIFIED"));
        }
    })
}

/// The options of a reconstruction request: UNSPECIFIED method is PSR (the default), absent
/// options the server's defaults; values out of range are INVALID_ARGUMENT naming the field.
pub fn reconstruct_options(r: &pb::ReconstructRequest) -> Wire<ReconOptions> {
    let method = match r.method {
        0 => ReconMethod::Psr,
        v => match pb::ReconstructionMethod::try_from(v)
            .map_err(|_| WireError::invalid("method", format!("unknown value {v}")))?
        {
            pb::ReconstructionMethod::Mcsd => ReconMethod::Mcsd,
            pb::ReconstructionMethod::Psr | pb::ReconstructionMethod::Unspecified => {
                ReconMethod::Psr
            }
        },
    };
    let mut options = ReconOptions {
        method,
        ..ReconOptions::default()
    };
    let Some(o) = &r.options else {
        return Ok(options);
    };
    if let Some(d) = o.psr_depth {
        if !PSR_DEPTHS.contains(&d) {
            return Err(WireError::invalid(
                "options.psr_depth",
                format!(
                    "{d} is outside {}..={}",
                    PSR_DEPTHS.start(),
                    PSR_DEPTHS.end()
                ),
            ));
        }
        options.psr_depth = Some(d);
    }
    if let Some(v) = o.smoothing {
        if !SMOOTHING.contains(&finite("options.smoothing", v)?) {
            return Err(WireError::invalid(
                "options.smoothing",
                format!(
                    "{v} is outside [{}, {}]",
                    SMOOTHING.start(),
                    SMOOTHING.end()
                ),
            ));
        }
        options.smoothing = Some(v);
    }
    if let Some(v) = o.decimation {
        if !DECIMATION.contains(&finite("options.decimation", v)?) {
            return Err(WireError::invalid(
                "options.decimation",
                format!("{v} is outside [{}, {})", DECIMATION.start, DECIMATION.end),
            ));
        }
        options.decimation = Some(v);
    }
    if let Some(v) = o.min_component_mm3 {
        if finite("options.min_component_mm3", v)? < 0.0 {
            return Err(WireError::invalid(
                "options.min_component_mm3",
                format!("{v} is negative"),
            ));
        }
        options.min_component_mm3 = Some(v);
    }
    options.split_components = o.split_components.unwrap_or(false);
    Ok(options)
}

/// `values` as x, y, z triples: a multiple of 3 values, each finite and, when `bound` is
/// given, within ±`bound`.
fn triples(field: &str, values: &[f64], bound: Option<Real>) -> Wire<Vec<[Real; 3]>> {
    if !values.len().is_multiple_of(3) {
        return Err(WireError::invalid(
            field,
            format!(
                "needs x, y, z per point: {} values is not a multiple of 3",
                values.len()
            ),
        ));
    }
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(WireError::invalid(
            format!("{field}[{k}]"),
            "must be finite",
        ));
    }
    if let Some(b) = bound
        && let Some(k) = values.iter().position(|v| v.abs() > b)
    {
        return Err(WireError::invalid(
            format!("{field}[{k}]"),
            format!("must be within ±{b} mm (max_coordinate_mm)"),
        ));
    }
    Ok(values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// The point cloud of a `ReconstructPointsRequest`: positions as x, y, z triples, finite and
/// within the coordinate range; normals empty (estimated) or one finite triple per point;
/// depth and neighbours 0 for the defaults. Their ranges and the server's limits are the
/// operation's to check.
pub fn point_cloud(r: pb::ReconstructPointsRequest) -> Wire<PointCloud> {
    let positions = triples("positions", &r.positions, Some(MAX_COORDINATE_MM))?;
    let normals = if r.normals.is_empty() {
        None
    } else {
        if r.normals.len() != r.positions.len() {
            return Err(WireError::invalid(
                "normals",
                format!(
                    "must be empty or hold as many values as positions: {} values for {}",
                    r.normals.len(),
                    r.positions.len()
                ),
            ));
        }
        Some(triples("normals", &r.normals, None)?)
    };
    let given = |v: u32| (v != 0).then_some(v);
    Ok(PointCloud {
        positions,
        normals,
        depth: given(r.depth),
        neighbours: given(r.neighbours).map(|k| k as usize),
        allow_zstd: r.allow_zstd,
        allow_quantized: r.allow_quantized,
    })
}

/// The answer of `ReconstructPoints`, or [`WireError::MessageTooLarge`] when its mesh does not
/// fit the largest message.
pub fn point_cloud_surface(s: CloudSurface) -> Wire<pb::ReconstructPointsResponse> {
    use prost::Message;
    let r = &s.report;
    let count = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
    let report = pb::PointCloudReport {
        points: count(r.points),
        distinct: count(r.distinct),
        normals: match r.normals {
            NormalSource::Given => pb::NormalSource::Given,
            NormalSource::Estimated => pb::NormalSource::Estimated,
        } as i32,
        components: r.components.map(count),
        degenerate: r.degenerate.map(count),
        spacing_mm: r.spacing_mm,
        sampled_area_mm2: r.sampled_area_mm2,
        depth: r.depth,
        neighbours: count(s.neighbours),
        cell_mm: r.cell_mm,
        normals_s: r.normals_s,
        solve_s: r.solve_s,
        surface_s: r.surface_s,
    };
    let answer = pb::ReconstructPointsResponse {
        mesh: s.mesh,
        vertex_count: s.vertices as u64,
        triangle_count: s.triangles as u64,
        volume_ml: s.volume_ml,
        report: Some(report),
    };
    let len = answer.encoded_len();
    if len > crate::MAX_MESSAGE_BYTES {
        return Err(WireError::MessageTooLarge(format!(
            "the surface needs {len} bytes, more than the largest message ({} bytes); ask for \
             a smaller depth",
            crate::MAX_MESSAGE_BYTES
        )));
    }
    Ok(answer)
}

/// The refusal of slices of a model (only resections are sliced so far).
pub fn model_slices() -> WireError {
    WireError::Unsupported {
        field: "model".into(),
        message: "slices of models are not supported yet; ask for a resection".into(),
    }
}

pub fn slice_positions(r: &pb::GetSlicesRequest) -> Wire<SlicePositions> {
    let at = |field: &str, v: Option<f64>| v.map(|v| finite(field, v)).transpose();
    Ok(SlicePositions {
        axial: at("axial", r.axial)?,
        coronal: at("coronal", r.coronal)?,
        sagittal: at("sagittal", r.sagittal)?,
    })
}

/// A label slice's plane and pixel size: the axis known, the numbers finite (their ranges
/// depend on the label map and are the operation's to check).
pub fn label_slice_request(r: &pb::GetLabelSliceRequest) -> Wire<(SliceAxis, Real, Option<Real>)> {
    let axis = match known("axis", r.axis)? {
        pb::SliceAxis::Axial => SliceAxis::Axial,
        pb::SliceAxis::Coronal => SliceAxis::Coronal,
        pb::SliceAxis::Sagittal => SliceAxis::Sagittal,
        pb::SliceAxis::Unspecified => {
            return Err(WireError::invalid("axis", "must not be UNSPECIFIED"));
        }
    };
    let pixel = r.pixel_mm.map(|v| finite("pixel_mm", v)).transpose()?;
    Ok((axis, finite("position_mm", r.position_mm)?, pixel))
}

// ---- outbound --------------------------------------------------------------------------------

fn vec3(p: [Real; 3]) -> pb::Vec3 {
    pb::Vec3 {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

pub fn role_map_pb(roles: &RoleMap) -> pb::RoleMap {
    let get = |role| roles.labels(role).iter().map(|&l| u32::from(l)).collect();
    pb::RoleMap {
        parenchyma: get(Role::Parenchyma),
        tumor: get(Role::Tumor),
        portal: get(Role::Portal),
        hepatic: get(Role::Hepatic),
        vessel: get(Role::Vessel),
    }
}

pub fn label_map(s: &LabelMapSummary) -> pb::LabelMapSummary {
    // Voxel volume: |det(direction · diag(spacing))|, in ml.
    let voxel_ml = Mat3::from_row_slice(&s.direction).determinant().abs()
        * s.spacing.iter().product::<Real>()
        / 1000.0;
    pb::LabelMapSummary {
        dims: s.dims.iter().map(|&d| d as u32).collect(),
        spacing: s.spacing.to_vec(),
        origin: s.origin.to_vec(),
        direction: s.direction.to_vec(),
        roles: Some(role_map_pb(&s.roles)),
        labels: s
            .labels
            .iter()
            .map(|(&label, &voxels)| pb::LabelCount {
                label: label.into(),
                voxels,
                volume_ml: voxels as f64 * voxel_ml,
            })
            .collect(),
        liver_volume_ml: s.liver_ml,
    }
}

pub fn session(s: &SessionInfo) -> pb::Session {
    pb::Session {
        id: s.id.clone(),
        display_name: s.display_name.clone(),
        created_ms: s.created_ms,
        last_access_ms: s.last_access_ms,
        state: match s.state {
            SessionState::Empty => pb::SessionState::Empty,
            SessionState::LabelMap => pb::SessionState::LabelMap,
            SessionState::Ready => pb::SessionState::Ready,
            SessionState::Damaged => pb::SessionState::Damaged,
        } as i32,
        plan_version: s.plan_version,
        label_map: s.label_map.as_ref().map(label_map),
    }
}

fn target_pb(t: &Target) -> pb::Target {
    pb::Target {
        labels: t.labels.iter().map(|&l| u32::from(l)).collect(),
        points: t.points.iter().copied().map(vec3).collect(),
    }
}

pub fn resection(r: &Resection) -> pb::Resection {
    pb::Resection {
        name: r.name.clone(),
        grid_m: r.grid[0] as u32,
        grid_n: r.grid[1] as u32,
        control_points: r.control_points.iter().copied().map(vec3).collect(),
        margin_mm: r.margin_mm,
        band_mm: r.band_mm,
        target: Some(target_pb(&r.target)),
        ru: r.resolution[0] as u32,
        rv: r.resolution[1] as u32,
        kind: match r.kind {
            ResectionKind::Bezier => pb::ResectionKind::Bezier,
            ResectionKind::Ds => pb::ResectionKind::Ds,
            ResectionKind::Cp => pb::ResectionKind::Cp,
        } as i32,
        traces: r
            .traces
            .iter()
            .map(|t| pb::Trace {
                points: t.iter().copied().map(vec3).collect(),
            })
            .collect(),
        deformations: r
            .deformations
            .iter()
            .map(|d| pb::Deformation {
                point: Some(vec3(d.point)),
                offset_mm: d.offset_mm,
                radius_mm: d.radius_mm,
            })
            .collect(),
    }
}

/// The answer of an edit.
pub fn edit_response(out: EditOutcome) -> pb::EditResponse {
    pb::EditResponse {
        plan_version: out.plan_version,
        resections: out
            .resections
            .iter()
            .map(|r| pb::ResectionStatus {
                resection: Some(resection(&r.resection)),
                verdict: r.verdict.as_ref().map(verdict),
            })
            .collect(),
        removed: out.removed,
    }
}

pub fn verdict(v: &Verdict) -> pb::Verdict {
    pb::Verdict {
        min_margin_mm: v.min_margin_mm,
        point: v.point.map(|p| vec3([p.x, p.y, p.z])),
        u: v.uv.map(|uv| uv[0]),
        v: v.uv.map(|uv| uv[1]),
        violation: v.violation,
        violating_area_mm2: v.violating_area_mm2,
        warning_area_mm2: v.warning_area_mm2,
        inside_area_mm2: v.inside_area_mm2,
        margin_uncertainty_mm: v.margin_uncertainty_mm,
    }
}

pub fn volumes(v: &VolumeReport) -> pb::VolumeReport {
    pb::VolumeReport {
        total_ml: v.total_ml,
        remnant_ml: v.remnant_ml,
        remnant_pct: v.remnant_pct,
        resected_ml: v.resected_ml,
        flr_threshold_pct: v.flr_threshold_pct,
        flr_warning: v.flr_warning,
        complete: v.complete,
        resections: v
            .resections
            .iter()
            .map(|r| pb::ResectionVolume {
                name: r.name.clone(),
                resected_ml: r.resected_ml,
                resected_pct: r.resected_pct,
                complete_cut: r.complete_cut,
                incomplete_reason: r
                    .incomplete
                    .as_ref()
                    .map(ToString::to_string)
                    .unwrap_or_default(),
                incomplete_point: match r.incomplete {
                    Some(IncompleteCut::EdgeInsideLiver { point }) => Some(vec3(point)),
                    _ => None,
                },
                metrics: Some(pb::ResectionMetrics {
                    margin_deviation_mm: r.metrics.margin_deviation_mm,
                    volume_deviation_pct: r.metrics.volume_deviation_pct,
                    median_abs_mean_curvature_per_mm: r.metrics.median_abs_mean_curvature_per_mm,
                }),
            })
            .collect(),
        risk: v.risk.as_ref().map(risk),
        risk_unavailable: v.risk_unavailable.clone().unwrap_or_default(),
    }
}

fn cut_vessel(c: &CutVessel) -> pb::CutVessel {
    pb::CutVessel {
        system: (if c.system == "hepatic" {
            pb::VesselSystem::Hepatic
        } else {
            pb::VesselSystem::Portal
        }) as i32,
        resection: c.resection.clone(),
        branch: saturating_u32(c.branch),
        generation: c.generation,
        radius_mm: c.radius_mm,
        point: Some(vec3(c.point)),
        u: c.uv[0],
        v: c.uv[1],
        downstream_of_another_cut: c.downstream_of_another_cut,
    }
}

pub fn risk(r: &RiskReport) -> pb::RiskReport {
    pb::RiskReport {
        devascularised_ml: r.devascularised_ml,
        congested_ml: r.congested_ml,
        at_risk_ml: r.at_risk_ml,
        functional_remnant_ml: r.functional_remnant_ml,
        functional_remnant_pct: r.functional_remnant_pct,
        has_portal: r.has_portal,
        has_hepatic: r.has_hepatic,
        cut_vessels: r.cut_vessels.iter().map(cut_vessel).collect(),
    }
}

/// A resectogram request's resection and size (0 → [`DEFAULT_RESECTOGRAM_SIDE`]; the upper
/// limit is the operation's to check, and an unknown name, the empty one too, is NOT_FOUND
/// there, as for slices).
pub fn resectogram_request(r: &pb::GetResectogramRequest) -> Wire<(String, usize, usize)> {
    let side = |v: u32| match v {
        0 => DEFAULT_RESECTOGRAM_SIDE,
        v => v as usize,
    };
    Ok((r.resection.clone(), side(r.width), side(r.height)))
}

/// The risk map with its classes and territories as zstd frames.
pub fn risk_map(plan_version: u64, m: &RiskMap) -> Result<pb::GetRiskMapResponse, SessionError> {
    let pack = |bytes: &[u8]| {
        zstd::bulk::compress(bytes, 3).map_err(|e| SessionError::Internal(format!("zstd: {e}")))
    };
    let territories: Vec<u8> = m
        .territories
        .iter()
        .flat_map(|&t| u16::try_from(t).unwrap_or(u16::MAX).to_le_bytes())
        .collect();
    let d = m.grid.direction();
    let o = m.grid.origin();
    Ok(pb::GetRiskMapResponse {
        plan_version,
        dims: m.grid.dims().map(saturating_u32).to_vec(),
        spacing: m.grid.spacing().to_vec(),
        origin: vec![o.x, o.y, o.z],
        direction: (0..9).map(|k| d[(k / 3, k % 3)]).collect(),
        classes_zstd: pack(&m.classes)?,
        territories_zstd: pack(&territories)?,
        risk: Some(risk(&m.report)),
    })
}

/// Resectogram side when a request leaves it 0.
pub const DEFAULT_RESECTOGRAM_SIDE: usize = 200;

pub fn resectogram(plan_version: u64, g: &Resectogram) -> pb::GetResectogramResponse {
    pb::GetResectogramResponse {
        plan_version,
        resection: g.resection.clone(),
        width: saturating_u32(g.width),
        height: saturating_u32(g.height),
        classes: g.classes.clone(),
        territories: g.territories.clone(),
        cut_vessels: g.cut_vessels.iter().map(cut_vessel).collect(),
        worst_u: g.worst_uv.map(|uv| uv[0]),
        worst_v: g.worst_uv.map(|uv| uv[1]),
        min_margin_mm: g.min_margin_mm,
        margin_mm: g.margin_mm,
        band_mm: g.band_mm,
    }
}

pub fn surface_kind(k: SurfaceKind) -> i32 {
    (match k {
        SurfaceKind::Parenchyma => pb::SurfaceKind::Parenchyma,
        SurfaceKind::Tumor => pb::SurfaceKind::Tumor,
        SurfaceKind::Portal => pb::SurfaceKind::Portal,
        SurfaceKind::Hepatic => pb::SurfaceKind::Hepatic,
        SurfaceKind::Vessel => pb::SurfaceKind::Vessel,
        SurfaceKind::Resection => pb::SurfaceKind::Resection,
    }) as i32
}

pub fn surface(s: &Surface) -> pb::Surface {
    pb::Surface {
        name: s.name.clone(),
        kind: surface_kind(s.kind),
        label: u32::from(s.label),
        color: s.color.map(|[r, g, b, a]| pb::Rgba { r, g, b, a }),
        mesh: s.mesh.clone(),
    }
}

pub fn model_info(m: &ModelInfo) -> pb::ModelInfo {
    pb::ModelInfo {
        name: m.name.clone(),
        kind: surface_kind(m.kind),
        label: u32::from(m.label),
        triangle_count: m.triangles as u64,
        vertex_count: m.vertices as u64,
        volume_ml: m.volume_ml,
        method: (match m.method.as_str() {
            "psr" => pb::ReconstructionMethod::Psr,
            "mcsd" => pb::ReconstructionMethod::Mcsd,
            _ => pb::ReconstructionMethod::Unspecified,
        }) as i32,
    }
}

pub fn reconstruct_event(e: ReconstructEvent) -> pb::ReconstructResponse {
    use pb::reconstruct_response::Event;
    let event = match e {
        ReconstructEvent::Progress { stage, fraction } => {
            Event::Progress(pb::ReconstructProgress { stage, fraction })
        }
        ReconstructEvent::Model { model } => Event::Model(model_info(&model)),
        ReconstructEvent::Done {
            models,
            time_ms,
            dropped,
            min_component_mm3,
        } => Event::Done(pb::ReconstructDone {
            model_count: u32::try_from(models).unwrap_or(u32::MAX),
            elapsed_s: time_ms / 1000.0,
            dropped: dropped
                .into_iter()
                .map(|d| pb::DroppedComponents {
                    kind: surface_kind(d.kind),
                    count: u32::try_from(d.count).unwrap_or(u32::MAX),
                    volume_ml: d.volume_ml,
                })
                .collect(),
            min_component_mm3,
        }),
    };
    pb::ReconstructResponse { event: Some(event) }
}

pub fn slices(s: &SliceProjections) -> pb::GetSlicesResponse {
    let lines = |ls: &[resecta_geom::Polyline]| {
        ls.iter()
            .map(|l| pb::Polyline {
                points: l
                    .points
                    .iter()
                    .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
                    .flat_map(f32::to_le_bytes)
                    .collect(),
                closed: l.is_closed,
            })
            .collect()
    };
    pb::GetSlicesResponse {
        axial: lines(&s.axial),
        coronal: lines(&s.coronal),
        sagittal: lines(&s.sagittal),
    }
}

pub fn label_slice(s: &LabelSlice) -> pb::GetLabelSliceResponse {
    pb::GetLabelSliceResponse {
        width: u32::try_from(s.width).unwrap_or(u32::MAX),
        height: u32::try_from(s.height).unwrap_or(u32::MAX),
        pixel_mm: s.pixel_mm,
        origin: Some(vec3(s.origin.into())),
        column_axis: Some(vec3(s.column_axis.into())),
        row_axis: Some(vec3(s.row_axis.into())),
        labels: s.labels.iter().flat_map(|l| l.to_le_bytes()).collect(),
        min_position_mm: s.extent[0],
        max_position_mm: s.extent[1],
    }
}
