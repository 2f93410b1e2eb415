//! Graceful shutdown of long-lived streams: tonic's graceful shutdown waits for every open call,
//! so a `Watch` (which never ends by itself) or a long `Reconstruct` would hold the process up
//! for ever. Each such stream is wrapped in [`until_shutdown`], which ends it with `UNAVAILABLE`
//! once the server's shutdown signal fires.

use std::pin::Pin;

use futures_util::future::{self, Either};
use futures_util::{Stream, StreamExt};
use tokio::sync::watch;
use tonic::Status;

/// The server's shutdown signal: `true` once it is shutting down. A dropped sender counts as
/// shutting down.
pub type ShutdownSignal = watch::Receiver<bool>;

/// The message of the status that ends a stream on shutdown.
pub const SHUTTING_DOWN: &str = "the server is shutting down; reconnect later";

/// Completes once `signal` says the server is shutting down (never without a signal).
pub async fn shutting_down(signal: Option<ShutdownSignal>) {
    match signal {
        Some(mut rx) => {
            // Err: the sender is gone, which also means the server is going away.
            let _ = rx.wait_for(|stopping| *stopping).await;
        }
        None => future::pending::<()>().await,
    }
}

type Boxed<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;
type Stop = Pin<Box<dyn Future<Output = ()> + Send>>;

/// `inner`, ended with `UNAVAILABLE` as soon as the server shuts down (dropping `inner`, which
/// cancels whatever feeds it).
pub fn until_shutdown<T: Send + 'static>(
    inner: impl Stream<Item = Result<T, Status>> + Send + 'static,
    signal: Option<ShutdownSignal>,
) -> impl Stream<Item = Result<T, Status>> + Send + 'static {
    let inner: Boxed<T> = Box::pin(inner);
    let stop: Stop = Box::pin(shutting_down(signal));
    futures_util::stream::unfold(Some((inner, stop)), |state| async move {
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
                Some((Err(Status::unavailable(SHUTTING_DOWN)), None))
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_pending_stream_ends_with_unavailable_on_shutdown() {
        let (tx, rx) = watch::channel(false);
        let inner = futures_util::stream::iter([Ok::<u32, Status>(1)])
            .chain(futures_util::stream::pending());
        let mut s = Box::pin(until_shutdown(inner, Some(rx)));
        assert_eq!(s.next().await.unwrap().unwrap(), 1);
        tx.send(true).unwrap();
        let e = s.next().await.unwrap().unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unavailable);
        assert!(s.next().await.is_none());
    }

    #[tokio::test]
    async fn a_finite_stream_ends_as_it_would() {
        let inner = futures_util::stream::iter([Ok::<u32, Status>(1), Ok(2)]);
        let s = until_shutdown(inner, None);
        let got: Vec<u32> = s.map(Result::unwrap).collect().await;
        assert_eq!(got, [1, 2]);
    }
}
