//! The server's identity and limits as both faces report them (`GetServerInfo`, `GET /v1/info`).

use resecta_api::MAX_CHUNK_BYTES;
use resecta_api::v1 as pb;
use resecta_session::Service;

use crate::MAX_MESSAGE_BYTES;

fn saturating_u32(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// The one `GetServerInfoResponse` of `service`: version, capabilities and every limit.
pub fn server_info(service: &Service) -> pb::GetServerInfoResponse {
    let info = service.info();
    pb::GetServerInfoResponse {
        server_version: info.version.to_owned(),
        api_version: info.api_version.to_owned(),
        capabilities: info.capabilities,
        limits: Some(pb::ServerLimits {
            max_voxels: info.limits.max_voxels,
            max_sessions: saturating_u32(info.limits.max_sessions),
            max_upload_bytes: info.limits.max_upload_bytes,
            max_chunk_bytes: saturating_u32(MAX_CHUNK_BYTES),
            max_message_bytes: saturating_u32(MAX_MESSAGE_BYTES),
            max_resections: saturating_u32(resecta_plan::MAX_RESECTIONS),
            max_control_points: saturating_u32(resecta_bezier::MAX_CONTROL_POINTS),
            max_resolution: saturating_u32(resecta_plan::resection::MAX_RESOLUTION),
            max_memory_bytes: info.limits.max_memory_bytes,
            session_idle_timeout_s: service.config().idle_expiry.map_or(0, |d| d.as_secs()),
        }),
    }
}
