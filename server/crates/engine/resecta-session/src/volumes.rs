//! Volumetry: the current plan's volumes, on request or recomputed once a burst of edits
//! pauses (mid-drag at a bounded rate over all sessions), computed without holding the session.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use resecta_plan::VolumeReport;

use crate::api::Versioned;
use crate::config::ServiceConfig;
use crate::error::Result;
use crate::pools::{self, Priority};
use crate::service::Service;
use crate::state::{Session, no_label_map};
use crate::support::InFlight;

/// When the volumes of a burst of edits are recomputed: once the edits pause for `delay`, at
/// the latest `max_interval` after the burst's first edit, and mid-drag at most
/// `during_drags_per_s` times a second over all the sessions dragging.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct VolumeTiming {
    pub(crate) delay: Duration,
    pub(crate) max_interval: Duration,
    pub(crate) during_drags_per_s: f64,
}

impl VolumeTiming {
    pub(crate) fn new(config: &ServiceConfig) -> Self {
        Self {
            delay: config.volumes_delay,
            max_interval: config.volumes_max_interval,
            during_drags_per_s: config.volumes_during_drags_per_s,
        }
    }

    /// The longest a burst waits while `dragging` sessions share the mid-drag rate.
    fn interval(&self, dragging: usize) -> Duration {
        let share = dragging as f64 / self.during_drags_per_s.max(1e-3);
        self.max_interval
            .max(Duration::try_from_secs_f64(share).unwrap_or(Duration::MAX))
    }

    /// When the recomputation of a burst that began at `first` (with `dragging` sessions
    /// scheduled, this one included) is due, its last edit so far made at `last`.
    pub(crate) fn due(&self, first: Instant, last: Instant, dragging: usize) -> Instant {
        let deadline = first
            .checked_add(self.interval(dragging))
            .unwrap_or(first + Duration::from_secs(3600));
        (last + self.delay).min(deadline.max(first + self.delay))
    }
}

impl Service {
    /// Recomputes the volumes once the edits pause for `volumes_delay` (at the latest
    /// `volumes_max_interval` into a continuous burst) and publishes them. Volumetry holds the
    /// session, so it must not run between every two edits of a drag.
    pub(crate) fn schedule_volumes(self: &Arc<Self>, s: &Arc<Session>) {
        let first = Instant::now();
        if let Ok(mut last) = s.last_edit.lock() {
            *last = first;
        }
        if s.volumes_scheduled.swap(true, Ordering::AcqRel) {
            return;
        }
        let dragging = self.volumes_scheduled.fetch_add(1, Ordering::AcqRel) + 1;
        let service = Arc::clone(self);
        let s = Arc::clone(s);
        tokio::spawn(async move {
            let timing = VolumeTiming::new(&service.config);
            loop {
                let last = s.last_edit.lock().map_or(first, |t| *t);
                let due = timing.due(first, last, dragging);
                if Instant::now() >= due {
                    break;
                }
                tokio::time::sleep_until(due.into()).await;
            }
            s.volumes_scheduled.store(false, Ordering::Release);
            service.volumes_scheduled.fetch_sub(1, Ordering::AcqRel);
            let started = std::time::Instant::now();
            let _running = InFlight::new("resecta_volumes_in_flight");
            match service.volumes_detached(&s, Priority::Background).await {
                Ok(Some((version, v))) => {
                    let _ = s.hub.publish_volumes(version, v);
                }
                Ok(None) => {}
                Err(e) => tracing::warn!(session = %s.id, error = %e, "volumes failed"),
            }
            metrics::histogram!("resecta_volumes_seconds").record(started.elapsed().as_secs_f64());
        });
    }

    /// Volumes of the current plan version computed without holding the session: the session
    /// is locked only to take the plan's cut inputs and the volumetry engine, and again to give
    /// the engine back, so edits go on meanwhile. `None` without a label map.
    async fn volumes_detached(
        &self,
        s: &Session,
        priority: Priority,
    ) -> Result<Option<(u64, VolumeReport)>> {
        let (job, version, generation) = {
            let mut st = Arc::clone(&s.state).lock_owned().await;
            let version = st.version;
            let Some(loaded) = st.loaded.as_mut() else {
                return Ok(None);
            };
            let job = loaded.ready().await?.volume_job()?;
            (job, version, loaded.generation)
        };
        let (engine, report) = pools::run(priority, move || job.run()).await?;
        let mut st = Arc::clone(&s.state).lock_owned().await;
        if let Some(loaded) = st.loaded.as_mut()
            && loaded.generation == generation
            && let Some(planner) = loaded.planner.as_mut()
        {
            planner.restore_volumetry(engine);
        }
        Ok(Some((version, report?)))
    }

    /// The current plan's volumes with the plan version they belong to.
    pub async fn volumes(&self, id: &str) -> Result<Versioned<VolumeReport>> {
        let (s, st) = self.open(id).await?;
        drop(st);
        let (plan_version, value) = self
            .volumes_detached(&s, Priority::Interactive)
            .await?
            .ok_or_else(no_label_map)?;
        Ok(Versioned {
            plan_version,
            value,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn timing() -> VolumeTiming {
        VolumeTiming {
            delay: 150 * MS,
            max_interval: 1000 * MS,
            during_drags_per_s: 4.0,
        }
    }

    #[test]
    fn the_defaults_are_the_configured_timing() {
        let c = ServiceConfig::default();
        let t = VolumeTiming::new(&c);
        assert_eq!(
            (t.delay, t.max_interval, t.during_drags_per_s),
            (
                c.volumes_delay,
                c.volumes_max_interval,
                c.volumes_during_drags_per_s
            )
        );
    }

    #[test]
    fn a_pause_is_due_its_delay_after_the_last_edit() {
        let t0 = Instant::now();
        assert_eq!(timing().due(t0, t0, 1), t0 + 150 * MS);
        assert_eq!(timing().due(t0, t0 + 300 * MS, 1), t0 + 450 * MS);
    }

    #[test]
    fn a_drag_is_due_at_most_the_max_interval_after_its_first_edit() {
        let t0 = Instant::now();
        assert_eq!(timing().due(t0, t0 + 900 * MS, 1), t0 + 1000 * MS);
        assert_eq!(timing().due(t0, t0 + 5000 * MS, 1), t0 + 1000 * MS);
    }

    #[test]
    fn many_drags_share_the_mid_drag_rate() {
        let t0 = Instant::now();
        let last = t0 + 10_000 * MS;
        // Four per second over all sessions: up to four dragging keep the max interval ...
        assert_eq!(timing().due(t0, last, 4), t0 + 1000 * MS);
        // ... eight wait two seconds each.
        assert_eq!(timing().due(t0, last, 8), t0 + 2000 * MS);
        // A pause is never held back by the others.
        assert_eq!(timing().due(t0, t0 + 100 * MS, 8), t0 + 250 * MS);
    }

    #[test]
    fn a_delay_longer_than_the_interval_waits_the_delay_once() {
        let t = VolumeTiming {
            delay: 2000 * MS,
            ..timing()
        };
        let t0 = Instant::now();
        assert_eq!(t.due(t0, t0 + 500 * MS, 1), t0 + 2000 * MS);
    }

    #[test]
    fn degenerate_rates_and_intervals_wait_for_a_pause_or_an_hour() {
        let t0 = Instant::now();
        for t in [
            VolumeTiming {
                during_drags_per_s: 0.0,
                ..timing()
            },
            VolumeTiming {
                during_drags_per_s: f64::NAN,
                ..timing()
            },
            VolumeTiming {
                max_interval: Duration::MAX,
                ..timing()
            },
        ] {
            assert_eq!(t.due(t0, t0 + 100 * MS, 1), t0 + 250 * MS, "{t:?}");
            let dragged = t.due(t0, t0 + 10_000_000 * MS, 1);
            assert!(dragged <= t0 + Duration::from_secs(3600), "{t:?}");
            assert!(dragged >= t0 + 1000 * MS, "{t:?}");
        }
    }
}
