//! Volumetry: the current plan's volumes, on request or recomputed once a burst of edits
//! pauses (mid-drag at a bounded rate over all sessions), computed without holding the session.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use resecta_plan::VolumeReport;

use crate::api::Versioned;
use crate::error::Result;
use crate::pools::{self, Priority};
use crate::service::Service;
use crate::state::{Session, no_label_map};
use crate::support::InFlight;

impl Service {
    /// Recomputes the volumes once the edits pause for `volumes_delay` (at the latest
    /// `volumes_max_interval` into a continuous burst) and publishes them. Volumetry holds the
    /// session, so it must not run between every two edits of a drag.
    pub(crate) fn schedule_volumes(self: &Arc<Self>, s: &Arc<Session>) {
        let now = std::time::Instant::now();
        if let Ok(mut last) = s.last_edit.lock() {
            *last = now;
        }
        if s.volumes_scheduled.swap(true, Ordering::AcqRel) {
            return;
        }
        let dragging = self.volumes_scheduled.fetch_add(1, Ordering::AcqRel) + 1;
        let service = Arc::clone(self);
        let s = Arc::clone(s);
        tokio::spawn(async move {
            let c = &service.config;
            let share = dragging as f64 / c.volumes_during_drags_per_s.max(1e-3);
            let (delay, max) = (
                c.volumes_delay,
                c.volumes_max_interval
                    .max(Duration::try_from_secs_f64(share).unwrap_or(Duration::MAX)),
            );
            let deadline = now
                .checked_add(max)
                .unwrap_or(now + Duration::from_secs(3600));
            loop {
                let last = s.last_edit.lock().map_or(now, |t| *t);
                let due = (last + delay).min(deadline.max(now + delay));
                if std::time::Instant::now() >= due {
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
