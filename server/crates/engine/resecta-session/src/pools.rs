//! Where the operation layer's CPU work runs. Edits run on rayon's global pool, so an edit's own
//! parallel loops fork inside a worker instead of queueing behind other callers. Heavy work —
//! reconstruction, planning set-up, volumes recomputed between edits — runs on a background pool
//! whose threads have the lowest scheduling priority (nice 19), so the edits of a drag preempt it
//! and a long job never holds the workers an edit needs.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::OnceLock;

use crate::error::{Result, SessionError};

/// Which pool runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Priority {
    /// Latency matters: a client waits (edits, explicit requests).
    Interactive,
    /// Throughput matters; yields the cores to interactive work.
    Background,
}

fn background() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .thread_name(|k| format!("resecta-background-{k}"))
            .start_handler(|_| {
                if let Err(e) = thread_priority::set_current_thread_priority(
                    thread_priority::ThreadPriority::Min,
                ) {
                    tracing::warn!(error = ?e, "could not lower a background thread's priority");
                }
            })
            .build()
            .map_err(|e| tracing::error!(error = %e, "background pool; using the global pool"))
            .ok()
    })
    .as_ref()
}

/// Runs `f` on the pool for `priority` and waits for it without blocking the async runtime. A
/// panic in `f` becomes an internal error. Dropping the future does not stop `f`.
pub(crate) async fn run<T: Send + 'static>(
    priority: Priority,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    let job = move || {
        let _ = tx.send(catch_unwind(AssertUnwindSafe(f)));
    };
    match (priority, background()) {
        (Priority::Background, Some(pool)) => pool.spawn(job),
        _ => rayon::spawn(job),
    }
    match rx.await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(_)) => Err(SessionError::Internal("a worker job panicked".into())),
        Err(_) => Err(SessionError::Internal("a worker job was dropped".into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The calling thread's nice value, from /proc.
    fn nice() -> Option<i32> {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
        stat.rsplit(')')
            .next()?
            .split_whitespace()
            .nth(16)?
            .parse()
            .ok()
    }

    #[tokio::test]
    async fn background_jobs_run_at_lowest_priority_and_interactive_at_normal() {
        let bg = run(Priority::Background, nice).await.unwrap();
        let fg = run(Priority::Interactive, nice).await.unwrap();
        if cfg!(target_os = "linux") {
            assert_eq!(bg, Some(19));
            assert_eq!(fg, nice(), "interactive jobs keep the process' priority");
        }
        let name = run(Priority::Background, || {
            std::thread::current().name().map(str::to_owned)
        })
        .await
        .unwrap();
        assert!(name.unwrap().starts_with("resecta-background-"));
    }

    #[tokio::test]
    async fn a_panicking_job_is_an_internal_error() {
        #[allow(clippy::panic)]
        let r = run(Priority::Interactive, || -> u8 { panic!("boom") }).await;
        assert!(matches!(r, Err(SessionError::Internal(_))), "{r:?}");
    }
}
