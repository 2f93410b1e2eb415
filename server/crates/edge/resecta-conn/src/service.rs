//! The per-request side: every request carries its connection's [`Conn`] in its extensions,
//! admits the connection when any request does ([`crate::AdmitOn::AnyRequest`]), and keeps the
//! connection from looking idle while it is in flight.

use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use crate::admission::{Conn, InFlight};

/// A service whose requests are tracked on their connection. Made by the HTTP acceptor (which
/// knows the connection and puts its [`Conn`] into the extensions) or by [`ConnLayer`] (for a
/// stack that put the [`Conn`] there itself, as tonic does with its connect info).
#[derive(Debug, Clone)]
pub struct ConnService<S> {
    inner: S,
    conn: Option<Conn>,
}

impl<S> ConnService<S> {
    /// `inner`, whose requests all belong to `conn`.
    pub fn for_conn(inner: S, conn: Conn) -> Self {
        Self {
            inner,
            conn: Some(conn),
        }
    }
}

/// Tracks each request on the [`Conn`] found in its extensions (requests without one pass
/// untouched).
#[derive(Debug, Clone, Copy, Default)]
pub struct ConnLayer;

impl<S> tower::Layer<S> for ConnLayer {
    type Service = ConnService<S>;

    fn layer(&self, inner: S) -> Self::Service {
        ConnService { inner, conn: None }
    }
}

impl<S, B> tower::Service<http::Request<B>> for ConnService<S>
where
    S: tower::Service<http::Request<B>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Tracked<S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<B>) -> Self::Future {
        let conn = match &self.conn {
            Some(conn) => {
                req.extensions_mut().insert(conn.clone());
                Some(conn.clone())
            }
            None => req.extensions().get::<Conn>().cloned(),
        };
        let in_flight = conn.map(|c| {
            c.note_request();
            c.start_request()
        });
        Tracked {
            inner: self.inner.call(req),
            in_flight,
        }
    }
}

pin_project_lite::pin_project! {
    /// A request's future, counted in flight on its connection until it completes or is
    /// dropped (the response head is out; a streamed body then moves bytes itself).
    pub struct Tracked<F> {
        #[pin]
        inner: F,
        in_flight: Option<InFlight>,
    }
}

impl<F> std::fmt::Debug for Tracked<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracked")
            .field("tracked", &self.in_flight.is_some())
            .finish_non_exhaustive()
    }
}

impl<F: Future> Future for Tracked<F> {
    type Output = F::Output;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<F::Output> {
        let this = self.project();
        let polled = this.inner.poll(cx);
        if polled.is_ready() {
            this.in_flight.take();
        }
        polled
    }
}
