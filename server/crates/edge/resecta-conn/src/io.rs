//! The stream wrapper: records activity on its connection and fails once the registry closed
//! the connection, so that the HTTP stack drops it (and the socket with it).

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use crate::admission::Conn;

pin_project_lite::pin_project! {
    /// An accepted stream (TCP, below TLS when there is TLS) of an admitted connection. Every
    /// byte read or written counts as activity; once the connection is closed (timeout or
    /// eviction) reads and writes fail. Dropping it takes the connection out of the registry.
    #[derive(Debug)]
    pub struct ConnIo<S> {
        #[pin]
        inner: S,
        conn: Conn,
    }

    impl<S> PinnedDrop for ConnIo<S> {
        fn drop(this: Pin<&mut Self>) {
            this.conn.release();
        }
    }
}

impl<S> ConnIo<S> {
    pub fn new(inner: S, conn: Conn) -> Self {
        Self { inner, conn }
    }

    /// The connection's handle.
    pub fn conn(&self) -> &Conn {
        &self.conn
    }

    pub fn get_ref(&self) -> &S {
        &self.inner
    }
}

impl<S: AsyncRead> AsyncRead for ConnIo<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.project();
        this.conn.register_read(cx.waker());
        if let Some(reason) = this.conn.close_reason() {
            return Poll::Ready(Err(reason.io_error()));
        }
        let before = buf.filled().len();
        let polled = this.inner.poll_read(cx, buf);
        if matches!(polled, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.conn.touch();
        }
        polled
    }
}

impl<S: AsyncWrite> AsyncWrite for ConnIo<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.project();
        this.conn.register_write(cx.waker());
        if let Some(reason) = this.conn.close_reason() {
            return Poll::Ready(Err(reason.io_error()));
        }
        let polled = this.inner.poll_write(cx, buf);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            this.conn.touch();
        }
        polled
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.project();
        this.conn.register_write(cx.waker());
        if let Some(reason) = this.conn.close_reason() {
            return Poll::Ready(Err(reason.io_error()));
        }
        let polled = this.inner.poll_write_vectored(cx, bufs);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            this.conn.touch();
        }
        polled
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.project();
        this.conn.register_write(cx.waker());
        if let Some(reason) = this.conn.close_reason() {
            return Poll::Ready(Err(reason.io_error()));
        }
        this.inner.poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.project();
        if this.conn.close_reason().is_some() {
            // Closed already: nothing more to send; the socket closes when this drops.
            return Poll::Ready(Ok(()));
        }
        this.inner.poll_shutdown(cx)
    }
}
