//! The gRPC face's side (tonic): an incoming-connection stream for
//! `Server::serve_with_incoming_shutdown` that admits each accepted TCP stream and wraps it, and
//! the [`Connected`] impl that puts the connection's [`Conn`] into every request's extensions
//! (tonic does that with the connect info, under TLS too).

use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::net::TcpStream;
use tokio_stream::Stream;
use tonic::transport::server::Connected;

use crate::admission::{Admission, Conn};
use crate::io::ConnIo;

/// Refused connections handled in one poll before yielding to the runtime.
const REFUSALS_PER_POLL: usize = 64;

/// Pause after an accept error that is not about one connection (e.g. out of file
/// descriptors), so that the accept loop does not spin.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(50);

/// Accepted TCP streams (from tonic's `TcpIncoming`, which sets `TCP_NODELAY`) that passed
/// [`Admission::admit`], wrapped in [`ConnIo`]; refused ones are closed at once.
#[derive(Debug)]
pub struct ConnIncoming<I> {
    inner: I,
    admission: Arc<Admission>,
    face: &'static str,
    pause: Option<Pin<Box<tokio::time::Sleep>>>,
}

impl<I> ConnIncoming<I> {
    /// `face` labels the connections in metrics and logs.
    pub fn new(inner: I, admission: Arc<Admission>, face: &'static str) -> Self {
        Self {
            inner,
            admission,
            face,
            pause: None,
        }
    }
}

/// Accept errors about one connection only (the listener is fine).
fn transient(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionAborted
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::BrokenPipe
            | io::ErrorKind::Interrupted
            | io::ErrorKind::WouldBlock
            | io::ErrorKind::TimedOut
    )
}

impl<I> Stream for ConnIncoming<I>
where
    I: Stream<Item = io::Result<TcpStream>> + Unpin,
{
    type Item = io::Result<ConnIo<TcpStream>>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        if let Some(pause) = self.pause.as_mut() {
            if pause.as_mut().poll(cx).is_pending() {
                return Poll::Pending;
            }
            self.pause = None;
        }
        for _ in 0..REFUSALS_PER_POLL {
            let stream = match Pin::new(&mut self.inner).poll_next(cx) {
                Poll::Pending => return Poll::Pending,
                Poll::Ready(None) => return Poll::Ready(None),
                Poll::Ready(Some(Ok(stream))) => stream,
                Poll::Ready(Some(Err(e))) => {
                    if !transient(&e) {
                        tracing::debug!(face = self.face, error = %e, "accept failed; pausing");
                        self.pause = Some(Box::pin(tokio::time::sleep(ACCEPT_ERROR_PAUSE)));
                    }
                    return Poll::Ready(Some(Err(e)));
                }
            };
            // A peer already gone has nothing to serve.
            let Ok(peer) = stream.peer_addr() else {
                continue;
            };
            if let Ok(conn) = self.admission.admit(self.face, peer) {
                return Poll::Ready(Some(Ok(ConnIo::new(stream, conn))));
            }
        }
        cx.waker().wake_by_ref();
        Poll::Pending
    }
}

impl<S> Connected for ConnIo<S> {
    type ConnectInfo = Conn;

    fn connect_info(&self) -> Conn {
        self.conn().clone()
    }
}
