//! Where the operation layer's CPU work runs. Small edits (a drag of a surface of at most
//! `QUICK_SAMPLES` (module `service`) samples) run on single-thread "quick" pools, their parallel
//! loops inline: under load, a fork-join edit waits for the half another worker stole, and that
//! worker may just have been preempted, which puts scheduler time slices into the edit's latency
//! tail; one thread per edit also never wakes a sleeping sibling. Other edits run on rayon's
//! global pool, so their parallel loops fork inside a worker instead of queueing behind other
//! callers. A planner set-up (after an upload or a restore: a client is about to wait for it)
//! runs on a pool of its own at normal priority. Other heavy work —
//! reconstruction, volumes recomputed between edits — runs on a background pool
//! whose threads are in the idle scheduling class (Linux `SCHED_IDLE`; elsewhere the lowest
//! priority), so the edits of a drag preempt it and a long job never holds the workers an edit
//! needs.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::error::{Result, SessionError};

/// Which pool runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Priority {
    /// Latency matters: a client waits (edits, explicit requests).
    Interactive,
    /// Latency matters and the job is small: one thread, no fork-join.
    Quick,
    /// Throughput matters; yields the cores to interactive work.
    Background,
    /// A planner set-up (after an upload, or a restore): heavy, but a client is about to wait
    /// for it; its own pool at normal priority, so it neither queues behind edits' fork-joins
    /// nor starves behind every other thread of the machine.
    SetUp,
}

fn background() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .thread_name(|k| format!("resecta-background-{k}"))
            .start_handler(|_| {
                if let Err(e) = lower_priority() {
                    tracing::warn!(error = ?e, "could not lower a background thread's priority");
                }
            })
            .build()
            .map_err(|e| tracing::error!(error = %e, "background pool; using the global pool"))
            .ok()
    })
    .as_ref()
}

/// Threads of the set-up pool.
#[cfg(test)]
pub(crate) fn set_up_threads() -> usize {
    set_up().map_or_else(
        rayon::current_num_threads,
        rayon::ThreadPool::current_num_threads,
    )
}

fn set_up() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .thread_name(|k| format!("resecta-setup-{k}"))
            .build()
            .map_err(|e| tracing::error!(error = %e, "set-up pool; using the global pool"))
            .ok()
    })
    .as_ref()
}

/// A single-thread pool and the number of its jobs queued or running.
type QuickPool = (rayon::ThreadPool, AtomicUsize);

/// One single-thread pool per core (a job goes to the one with the fewest queued); empty if
/// none could be built. Half the cores gave a worse concurrent tail on two cores (one compute
/// thread saturated first: `docs/benchmarks.md`).
fn quick() -> &'static [QuickPool] {
    static POOLS: OnceLock<Vec<QuickPool>> = OnceLock::new();
    POOLS.get_or_init(|| {
        let n = std::thread::available_parallelism().map_or(1, |n| n.get());
        (0..n)
            .map_while(|k| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .thread_name(move |_| format!("resecta-quick-{k}"))
                    .build()
                    .map_err(|e| tracing::error!(error = %e, "quick pool; using the global pool"))
                    .ok()
                    .map(|p| (p, AtomicUsize::new(0)))
            })
            .collect()
    })
}

/// Lowers the calling thread to the idle scheduling class where there is one (Linux
/// `SCHED_IDLE`: any other runnable thread preempts it), else to the lowest priority.
fn lower_priority() -> Result<(), thread_priority::Error> {
    use thread_priority::{ThreadPriority, set_current_thread_priority};
    #[cfg(target_os = "linux")]
    {
        use thread_priority::{
            NormalThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy,
            thread_native_id,
        };
        let idle = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Idle);
        if set_thread_priority_and_policy(thread_native_id(), ThreadPriority::Min, idle).is_ok() {
            return Ok(());
        }
    }
    set_current_thread_priority(ThreadPriority::Min)
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
    match priority {
        Priority::Background => match background() {
            Some(pool) => pool.spawn(job),
            None => rayon::spawn(job),
        },
        Priority::Quick => match quick()
            .iter()
            .min_by_key(|(_, q)| q.load(Ordering::Relaxed))
        {
            Some((pool, queued)) => {
                queued.fetch_add(1, Ordering::Relaxed);
                pool.spawn(move || {
                    job();
                    queued.fetch_sub(1, Ordering::Relaxed);
                });
            }
            None => rayon::spawn(job),
        },
        Priority::SetUp => match set_up() {
            Some(pool) => pool.spawn(job),
            None => rayon::spawn(job),
        },
        Priority::Interactive => rayon::spawn(job),
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

    /// The calling thread's (nice value, scheduling policy), from /proc.
    fn priority() -> Option<(i32, u32)> {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
        let fields: Vec<&str> = stat.rsplit(')').next()?.split_whitespace().collect();
        Some((fields.get(16)?.parse().ok()?, fields.get(38)?.parse().ok()?))
    }

    #[tokio::test]
    async fn background_jobs_run_in_the_idle_class_and_interactive_at_normal() {
        let bg = run(Priority::Background, priority).await.unwrap();
        let fg = run(Priority::Interactive, priority).await.unwrap();
        if cfg!(target_os = "linux") {
            const SCHED_IDLE: u32 = 5;
            let (nice, policy) = bg.unwrap();
            assert!(policy == SCHED_IDLE || nice == 19, "{bg:?}");
            assert_eq!(
                fg,
                priority(),
                "interactive jobs keep the process' priority"
            );
        }
        let name = run(Priority::Background, || {
            std::thread::current().name().map(str::to_owned)
        })
        .await
        .unwrap();
        assert!(name.unwrap().starts_with("resecta-background-"));
    }

    #[tokio::test]
    async fn quick_jobs_run_their_parallel_loops_inline_on_one_thread() {
        use rayon::prelude::*;
        let (name, threads, inline) = run(Priority::Quick, || {
            let me = std::thread::current().id();
            let inline = (0..10_000)
                .into_par_iter()
                .all(|_| std::thread::current().id() == me);
            let name = std::thread::current().name().map(str::to_owned);
            (name, rayon::current_num_threads(), inline)
        })
        .await
        .unwrap();
        assert!(name.unwrap().starts_with("resecta-quick-"));
        assert_eq!(threads, 1);
        assert!(inline);
        // Many at once all complete.
        let jobs: Vec<_> = (0..32u64)
            .map(|k| tokio::spawn(run(Priority::Quick, move || k * 2)))
            .collect();
        for (k, j) in jobs.into_iter().enumerate() {
            assert_eq!(j.await.unwrap().unwrap(), k as u64 * 2);
        }
    }

    #[tokio::test]
    async fn a_panicking_job_is_an_internal_error() {
        #[allow(clippy::panic)]
        let r = run(Priority::Interactive, || -> u8 { panic!("boom") }).await;
        assert!(matches!(r, Err(SessionError::Internal(_))), "{r:?}");
    }
}
