//! Small helpers shared by the parts of the operation layer: the clock, error mapping, the
//! blocking pool for store I/O and gauges of operations in flight.

use std::time::{SystemTime, UNIX_EPOCH};

use crate::error::{Result, SessionError};

pub(crate) fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// A gauge of operations in progress (queued for their session or running): +1 now, −1 on drop.
pub(crate) struct InFlight(&'static str);

impl InFlight {
    pub(crate) fn new(name: &'static str) -> Self {
        metrics::gauge!(name).increment(1.0);
        Self(name)
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        metrics::gauge!(self.0).decrement(1.0);
    }
}

pub(crate) fn internal(e: impl std::fmt::Display) -> SessionError {
    SessionError::Internal(e.to_string())
}

/// Runs `f` on the blocking pool.
pub(crate) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T> + Send + 'static,
) -> Result<T> {
    tokio::task::spawn_blocking(f).await.map_err(internal)?
}
