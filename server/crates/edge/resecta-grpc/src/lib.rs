//! The gRPC face of the planning server: `resecta.v1.PlanningService` (proto/resecta/v1) over the
//! [`resecta_session::Service`] operation layer, behind the [`resecta_auth::AccessPolicy`], with
//! the standard health and reflection services beside it.
//!
//! [`grpc_routes`] is all the server process needs: it adds the routes to its tonic server,
//! binds, and adds TLS. Every RPC is an adaptation: wire validation and translation in
//! `resecta-face` (shared with the HTTP face), errors mapped to statuses once in [`error`], no
//! planning logic.

mod access;
pub mod error;
mod service;

use std::sync::Arc;

use futures_util::FutureExt;
use resecta_api::v1::planning_service_server::PlanningServiceServer;
use resecta_api::{FILE_DESCRIPTOR_SET, MAX_CHUNK_BYTES};
use resecta_auth::AccessPolicy;
use resecta_session::Service;
use tonic::service::Routes;

pub use error::{RpcStatus, access_status, error_info, session_status};
pub use resecta_face::{MAX_MESSAGE_BYTES, ShutdownSignal, WireError};
pub use service::Planning;

/// Largest request message the server accepts: one 4 MiB chunk plus room for its header.
pub const MAX_REQUEST_BYTES: usize = MAX_CHUNK_BYTES + (64 << 10);

/// The gRPC services of the planning server: `resecta.v1.PlanningService` behind `policy`
/// (token on every call, API version on every call but `GetServerInfo`) with the message size
/// limits set, `grpc.health.v1.Health` (SERVING for the planning service; no token) and
/// reflection v1 and v1alpha from the API's descriptor set (no token). Its streams end only
/// by themselves: a server that shuts down gracefully uses [`grpc_routes_until`].
pub fn grpc_routes(service: Arc<Service>, policy: AccessPolicy) -> Routes {
    routes(Planning::new(service), policy)
}

/// [`grpc_routes`] whose `Watch` and `Reconstruct` streams end with `UNAVAILABLE` once
/// `shutdown` turns `true`: tonic's graceful shutdown waits for every open call, and a watch
/// never ends by itself.
pub fn grpc_routes_until(
    service: Arc<Service>,
    policy: AccessPolicy,
    shutdown: ShutdownSignal,
) -> Routes {
    let planning = Planning::new(service).with_shutdown(shutdown);
    routes(planning, policy)
}

fn routes(planning: Planning, policy: AccessPolicy) -> Routes {
    let planning = PlanningServiceServer::new(planning)
        .max_decoding_message_size(MAX_REQUEST_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);

    let (reporter, health) = tonic_health::server::health_reporter();
    // A fresh reporter's lock is free, so this completes on its first poll.
    if reporter
        .set_serving::<PlanningServiceServer<Planning>>()
        .now_or_never()
        .is_none()
    {
        tracing::warn!("health status of the planning service not set");
    }

    let mut routes = Routes::new(access::Access::new(planning, policy)).add_service(health);
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(FILE_DESCRIPTOR_SET)
    };
    match (reflection().build_v1(), reflection().build_v1alpha()) {
        (Ok(v1), Ok(v1alpha)) => routes = routes.add_service(v1).add_service(v1alpha),
        (Err(e), _) | (_, Err(e)) => tracing::error!(error = %e, "reflection unavailable"),
    }
    routes
}
