//! Graceful shutdown of long-lived streams: a graceful shutdown waits for every open call, so a
//! watch (which never ends by itself) or a long reconstruction would hold the process up for
//! ever. Each face wraps such a stream in [`until_shutdown`], which ends it with the face's own
//! last item (gRPC: `UNAVAILABLE`; HTTP: an `error` event with a 503 problem) once the server's
//! shutdown signal fires.

use std::pin::Pin;

use futures_util::future::{self, Either};
use futures_util::{Stream, StreamExt};
use tokio::sync::watch;

/// The server's shutdown signal: `true` once it is shutting down. A dropped sender counts as
/// shutting down.
pub type ShutdownSignal = watch::Receiver<bool>;

/// The message with which a stream ends on shutdown.
pub const SHUTTING_DOWN: &str = "the server is shutting down; reconnect later";

/// Completes once `signal` says the server is shutting down (never without a signal).
pub async fn shutting_down(signal: Option<ShutdownSignal>) {
    match signal {
        // Err: the sender is gone, which also means the server is going away.
        Some(mut rx) => drop(rx.wait_for(|stopping| *stopping).await),
        None => future::pending::<()>().await,
    }
}

type Boxed<T> = Pin<Box<dyn Stream<Item = T> + Send>>;
type Stop = Pin<Box<dyn Future<Output = ()> + Send>>;

/// `inner`, ended by `last()` as soon as the server shuts down (dropping `inner`, which cancels
/// whatever feeds it). Without a signal, `inner` as it is.
pub fn until_shutdown<T: Send + 'static>(
    inner: impl Stream<Item = T> + Send + 'static,
    signal: Option<ShutdownSignal>,
    last: fn() -> T,
) -> impl Stream<Item = T> + Send + 'static {
    let inner: Boxed<T> = Box::pin(inner);
    let stop: Stop = Box::pin(shutting_down(signal));
    futures_util::stream::unfold(Some((inner, stop)), move |state| async move {
        let (mut inner, mut stop) = state?;
        let next = match future::select(inner.next(), stop.as_mut()).await {
            Either::Left((item, _)) => Some(item),
            Either::Right(((), _)) => None,
        };
        match next {
            Some(Some(item)) => Some((item, Some((inner, stop)))),
            Some(None) => None,
            None => {
                drop(inner);
                Some((last(), None))
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_pending_stream_ends_with_the_last_item_on_shutdown() {
        let (tx, rx) = watch::channel(false);
        let inner = futures_util::stream::iter([1]).chain(futures_util::stream::pending());
        let mut s = Box::pin(until_shutdown(inner, Some(rx), || 0));
        assert_eq!(s.next().await, Some(1));
        tx.send(true).unwrap();
        assert_eq!(s.next().await, Some(0));
        assert!(s.next().await.is_none());
    }

    #[tokio::test]
    async fn a_finite_stream_ends_as_it_would() {
        let s = until_shutdown(futures_util::stream::iter([1, 2]), None, || 0);
        let got: Vec<u32> = s.collect().await;
        assert_eq!(got, [1, 2]);
    }
}
