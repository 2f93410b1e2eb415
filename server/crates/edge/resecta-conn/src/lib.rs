//! Connection hygiene of the server's faces: which accepted connections may stay open, and for
//! how long. Independent of the HTTP stacks but for two small adapters.
//!
//! - [`Admission`] is the registry of open connections against the [`ConnLimits`]: a cap on
//!   all connections, one per client address and one on connections not yet admitted. A
//!   connection is *admitted* by its first authenticated request ([`Conn::mark_authenticated`],
//!   called by the faces' access checks) or, on a server without a token, by its first request
//!   ([`AdmitOn`]). Where a cap is reached the **oldest unadmitted connection is closed** to make
//!   room, so a flood of idle connections cycles through its own slots and never locks real
//!   clients out; a new connection is refused only when the connections filling the cap are all
//!   admitted.
//! - Its sweeper closes a connection not admitted within the handshake timeout, and one with no
//!   request in flight over which no byte moved either way within the idle timeout. Long
//!   requests and progressing uploads are never idle; HTTP/2 pings and server-sent-event
//!   keep-alives are bytes.
//! - [`ConnIo`] wraps the accepted TCP stream (below TLS): it records activity and, once its
//!   connection is closed, fails reads and writes so that the HTTP stack drops the connection.
//! - [`ConnService`] / [`ConnLayer`] put the [`Conn`] into each request's extensions and count
//!   the request in flight.
//! - Adapters: `ConnIncoming` (feature `tonic`) for `serve_with_incoming_shutdown`, whose streams
//!   are tonic `Connected` with the [`Conn`] as connect info; `ConnAcceptor` (feature
//!   `axum-server`) around the HTTP face's acceptor.
//!
//! Closed connections are counted in `resecta_connections_closed_total{face,reason}` (reasons
//! `handshake_timeout`, `idle_timeout`, `evicted`, `refused_max_connections`,
//! `refused_max_per_ip`); `resecta_connections_open{face}` is the gauge of open ones. Logs
//! (debug) name the connection number, face, peer address and reason, never request contents.

mod admission;
#[cfg(feature = "tonic")]
mod grpc;
#[cfg(feature = "axum-server")]
mod http;
mod io;
mod limits;
mod service;

#[cfg(test)]
mod tests;

pub use admission::{Admission, AdmitOn, CloseReason, Conn, Refused};
#[cfg(feature = "tonic")]
pub use grpc::ConnIncoming;
#[cfg(feature = "axum-server")]
pub use http::ConnAcceptor;
pub use io::ConnIo;
pub use limits::{ConnLimits, LimitsError, MAX_TIMEOUT};
pub use service::{ConnLayer, ConnService, Tracked};
