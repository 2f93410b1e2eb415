//! The HTTP face's side (axum-server): an acceptor that admits each accepted TCP stream, sets
//! `TCP_NODELAY`, wraps the stream below the inner acceptor (TLS or none) and the service above
//! it, so that every request carries the connection's [`Conn`].

use std::future::{Ready, ready};
use std::io;
use std::sync::Arc;

use axum_server::accept::Accept;
use futures_util::future::Either;
use tokio::net::TcpStream;

use crate::admission::Admission;
use crate::io::ConnIo;
use crate::service::ConnService;

/// Wraps `inner` (`DefaultAcceptor`, or `RustlsAcceptor` for TLS).
#[derive(Debug, Clone)]
pub struct ConnAcceptor<A> {
    inner: A,
    admission: Arc<Admission>,
    face: &'static str,
}

impl<A> ConnAcceptor<A> {
    /// `face` labels the connections in metrics and logs.
    pub fn new(inner: A, admission: Arc<Admission>, face: &'static str) -> Self {
        Self {
            inner,
            admission,
            face,
        }
    }
}

impl<A, S> Accept<TcpStream, S> for ConnAcceptor<A>
where
    A: Accept<ConnIo<TcpStream>, ConnService<S>>,
{
    type Stream = A::Stream;
    type Service = A::Service;
    type Future = Either<A::Future, Ready<io::Result<(A::Stream, A::Service)>>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        let conn = match stream.peer_addr() {
            Ok(peer) => self
                .admission
                .admit(self.face, peer)
                .map_err(io::Error::other),
            Err(e) => Err(e),
        };
        match conn {
            Ok(conn) => {
                // Small answers (edits) must not wait for Nagle's delayed ACK.
                if let Err(e) = stream.set_nodelay(true) {
                    tracing::debug!(face = self.face, error = %e, "TCP_NODELAY not set");
                }
                let service = ConnService::for_conn(service, conn.clone());
                Either::Left(self.inner.accept(ConnIo::new(stream, conn), service))
            }
            Err(e) => Either::Right(ready(Err(e))),
        }
    }
}
