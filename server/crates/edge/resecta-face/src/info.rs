//! The server's identity and limits as both faces report them (`GetServerInfo`, `GET /v1/info`).

use resecta_api::v1 as pb;
use resecta_session::Service;

/// Every fixed limit of a request, re-exported from the constant that enforces it (the wire
/// validation of [`crate::convert`], the operation layer, the plan): `GetServerInfo` reports
/// them, and the HTTP face's OpenAPI document states them, so neither repeats a number.
pub mod limits {
    pub use resecta_api::MAX_CHUNK_BYTES;
    pub use resecta_bezier::MAX_CONTROL_POINTS;
    pub use resecta_plan::FORMAT as PLAN_FORMAT;
    pub use resecta_plan::MAX_RESECTIONS;
    pub use resecta_plan::anatomy::TARGET_POINT_SNAP_MM;
    pub use resecta_plan::init::MIN_END_DISTANCE_MM;
    pub use resecta_plan::label_slice::{MAX_LABEL_SLICE_PIXEL_MM, MAX_LABEL_SLICE_SIDE};
    pub use resecta_plan::plan::MAX_PLAN_BYTES;
    pub use resecta_plan::resection::{
        MAX_ANGLE_DEG, MAX_COORDINATE_MM, MAX_MARGIN_MM, MAX_NAME_LEN, MAX_RESOLUTION,
        MAX_TARGET_LABELS, MAX_TARGET_POINTS, MIN_CONTROL_POINTS, MIN_RESOLUTION,
    };
    pub use resecta_plan::resectogram::MAX_SIDE as MAX_RESECTOGRAM_SIDE;
    pub use resecta_plan::traces::cp::{MAX_OFFSET_MM, MAX_RADIUS_MM};
    pub use resecta_plan::traces::{
        MAX_DEFORMATIONS, MAX_TRACE_POINTS, MAX_TRACES, MIN_TRACE_POINTS, MIN_TRACES,
        SLICE_TOLERANCE_MM,
    };
    pub use resecta_session::api::{
        DEFAULT_CLOUD_DEPTH, DEFAULT_CLOUD_NEIGHBOURS, DEFAULT_GRID, MAX_CLOUD_NEIGHBOURS,
        MAX_DISPLAY_NAME, MAX_EXTENT_MM, MAX_ORIGIN_MM, MIN_CLOUD_NEIGHBOURS, MIN_CLOUD_POINTS,
        SPACING_MM,
    };

    pub use crate::MAX_MESSAGE_BYTES;
    pub use crate::convert::{DECIMATION, DEFAULT_RESECTOGRAM_SIDE, PSR_DEPTHS, SMOOTHING};

    /// Largest label value (labels are `1..=MAX_LABEL`; 0 is the background).
    pub const MAX_LABEL: u16 = u16::MAX;
}

pub(crate) fn saturating_u32(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// The one `GetServerInfoResponse` of `service`: version, capabilities, every limit and the
/// compute backend.
pub fn server_info(service: &Service) -> pb::GetServerInfoResponse {
    use limits::*;
    let info = service.info();
    pb::GetServerInfoResponse {
        server_version: info.version.to_owned(),
        api_version: info.api_version.to_owned(),
        capabilities: info.capabilities,
        compute: Some(pb::ComputeInfo {
            backend: info.compute.backend,
            adapter: info.compute.adapter,
            f64: info.compute.f64,
        }),
        limits: Some(pb::ServerLimits {
            max_voxels: info.limits.max_voxels,
            max_sessions: saturating_u32(info.limits.max_sessions),
            max_upload_bytes: info.limits.max_upload_bytes,
            max_chunk_bytes: saturating_u32(MAX_CHUNK_BYTES),
            max_message_bytes: saturating_u32(MAX_MESSAGE_BYTES),
            max_resections: saturating_u32(MAX_RESECTIONS),
            max_control_points: saturating_u32(MAX_CONTROL_POINTS),
            max_resolution: saturating_u32(MAX_RESOLUTION),
            max_memory_bytes: info.limits.max_memory_bytes,
            session_idle_timeout_s: service.config().idle_expiry.map_or(0, |d| d.as_secs()),
            min_control_points: saturating_u32(MIN_CONTROL_POINTS),
            min_resolution: saturating_u32(MIN_RESOLUTION),
            max_margin_mm: MAX_MARGIN_MM,
            max_band_mm: MAX_MARGIN_MM,
            max_name_bytes: saturating_u32(MAX_NAME_LEN),
            max_coordinate_mm: MAX_COORDINATE_MM,
            max_rotation_deg: MAX_ANGLE_DEG,
            max_display_name_chars: saturating_u32(MAX_DISPLAY_NAME),
            max_plan_bytes: saturating_u32(MAX_PLAN_BYTES),
            min_psr_depth: *PSR_DEPTHS.start(),
            max_psr_depth: *PSR_DEPTHS.end(),
            min_spacing_mm: *SPACING_MM.start(),
            max_spacing_mm: *SPACING_MM.end(),
            max_extent_mm: MAX_EXTENT_MM,
            max_origin_mm: MAX_ORIGIN_MM,
            max_label_slice_side: saturating_u32(MAX_LABEL_SLICE_SIDE),
            max_label_slice_pixel_mm: MAX_LABEL_SLICE_PIXEL_MM,
            max_traces: saturating_u32(MAX_TRACES),
            min_trace_points: saturating_u32(MIN_TRACE_POINTS),
            max_trace_points: saturating_u32(MAX_TRACE_POINTS),
            min_ds_traces: saturating_u32(MIN_TRACES),
            slice_tolerance_mm: SLICE_TOLERANCE_MM,
            max_deformations: saturating_u32(MAX_DEFORMATIONS),
            max_deformation_radius_mm: MAX_RADIUS_MM,
            max_deformation_offset_mm: MAX_OFFSET_MM,
            max_resectogram_side: saturating_u32(MAX_RESECTOGRAM_SIDE),
            max_cloud_points: saturating_u32(info.limits.max_cloud_points),
            max_cloud_depth: info.limits.max_cloud_depth,
        }),
    }
}
