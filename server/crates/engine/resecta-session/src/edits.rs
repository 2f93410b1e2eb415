//! Plan edits: one change (an event, an initial resection, undo, redo) or a whole imported
//! plan against a plan version, computed off the runtime, shown to watchers at once and
//! acknowledged once its log record is durable (rolled back when it cannot be stored).

use std::sync::Arc;

use resecta_geom::{Plane, Vec3};
use resecta_plan::{Change, Plan, PlanEvent, Planner};

use crate::api::{EditOp, EditOutcome, ResectionStatus};
use crate::budget::{
    Charge, Use, added_resection_bytes, plan_bytes, plan_change_bytes, sample_bytes,
};
use crate::error::{Result, SessionError};
use crate::log;
use crate::pools::{self, Priority};
use crate::service::Service;
use crate::state::{self, loaded_mut, no_label_map};
use crate::support::{InFlight, blocking, internal};

/// Edits of surfaces of at most this many samples run on one thread (`pools`: no fork-join).
const QUICK_SAMPLES: usize = 10_000;

impl Service {
    /// Applies one plan change made against `base_version` (0: unchecked). Conflicting edits
    /// (an older base) are rejected with [`SessionError::StaleVersion`], never rebased. An edit
    /// once started completes even if the caller goes away (the planner is never left taken).
    pub async fn edit(
        self: &Arc<Self>,
        id: &str,
        base_version: u64,
        op: EditOp,
    ) -> Result<EditOutcome> {
        let service = Arc::clone(self);
        let id = id.to_owned();
        tokio::spawn(async move { service.edit_to_end(&id, base_version, op).await })
            .await
            .map_err(internal)?
    }

    async fn edit_to_end(
        self: &Arc<Self>,
        id: &str,
        base_version: u64,
        op: EditOp,
    ) -> Result<EditOutcome> {
        let started = std::time::Instant::now();
        let _queued = InFlight::new("resecta_edits_in_flight");
        let (s, mut st) = self.open(id).await?;
        if let Err(e) = check_base(base_version, st.version) {
            metrics::counter!("resecta_edits_rejected_total", "reason" => "stale_version")
                .increment(1);
            return Err(e);
        }
        let version = st.version;
        let loaded = st.loaded.as_mut().ok_or_else(no_label_map)?;
        // The memory a change that reshapes the plan needs is reserved before it is computed.
        let reserved = match memory_need(loaded.ready().await?, &op)? {
            Some(need) => {
                Some(
                    self.budget
                        .reserve_replacing(Use::Plan, need, &s.id, Charge::Plan)?,
                )
            }
            None => None,
        };
        let mut planner = loaded.take_planner().await?;
        // Compute on a quick pool (a drag) or rayon's pool and show the result to watchers right
        // there; store on the blocking pool (a worker never waits for the disk while other sessions' edits queue
        // for it). Only the acknowledgement waits for the record to be durable: a record that
        // cannot be stored rolls the edit back and watchers get a snapshot of the plan as it was.
        let hub = Arc::clone(&s.hub);
        let id = s.id.clone();
        let priority = if is_quick(&planner, &op) {
            Priority::Quick
        } else {
            Priority::Interactive
        };
        let (mut planner, result) = pools::run(priority, move || {
            let fallbacks = planner.device_fallbacks();
            let r = apply_edit(&mut planner, op);
            state::log_device_fallback(&planner, fallbacks);
            let r = r.and_then(|(change, record)| {
                match hub.publish_edit(version + 1, planner.plan(), planner.states(), &change) {
                    Ok(()) => Ok((change, record)),
                    Err(e) => {
                        log::roll_back(&mut planner, &id);
                        Err(e)
                    }
                }
            });
            (planner, r)
        })
        .await?;
        let (change, record) = match result {
            Ok(r) => r,
            Err(e) => {
                loaded.planner = Some(planner);
                return Err(e);
            }
        };
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        let stored = blocking(move || Ok(store.append(&key, version, &[record])?)).await;
        let new_version = match stored {
            Ok(v) => v,
            Err(e) => {
                let id = s.id.clone();
                planner = pools::run(Priority::Interactive, move || {
                    log::roll_back(&mut planner, &id);
                    planner
                })
                .await?;
                let shown = s.hub.reset(version, planner.plan(), planner.states());
                loaded.planner = Some(planner);
                shown?;
                return Err(self.store_failed(&s.id, e).await);
            }
        };
        debug_assert_eq!(new_version, version + 1, "one record appended");
        if let Some(reserved) = reserved {
            reserved.settle(
                &s.id,
                Charge::Plan,
                plan_bytes(planner.plan(), per_sample(&planner)),
            )?;
        }
        let outcome = outcome(&planner, new_version, change);
        loaded.planner = Some(planner);
        st.version = new_version;
        drop(st);
        self.schedule_volumes(&s);
        metrics::histogram!("resecta_edit_seconds").record(started.elapsed().as_secs_f64());
        Ok(outcome)
    }

    /// Replaces the plan by a `resecta-plan/1` document (its roles must be the label map's).
    pub async fn import_plan(&self, id: &str, json: &str, base_version: u64) -> Result<u64> {
        let plan = Plan::from_json(json)?;
        let (s, mut st) = self.open(id).await?;
        check_base(base_version, st.version)?;
        let version = st.version;
        let loaded = loaded_mut(&mut st)?;
        if plan.roles != loaded.summary.roles {
            return Err(SessionError::Invalid(
                "the plan's role map differs from the loaded label map's".into(),
            ));
        }
        let (anatomy, engine) = {
            let planner = loaded.ready().await?;
            (planner.anatomy_shared(), planner.compute_engine().clone())
        };
        // Refused before any surface is computed when the memory budget has no room for the
        // new surfaces, which are computed beside the present ones. (The store takes the record
        // of any plan the plan limits allow: `log` tests the largest.)
        let record = log::reset_record(&plan)?;
        let after = plan_bytes(&plan, sample_bytes(&engine));
        let reserved = self.budget.reserve(Use::Plan, after)?;
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        let stored = blocking(move || {
            let planner = Planner::with_engine(anatomy, plan, engine)?;
            let v = store.append(&key, version, &[record])?;
            Ok((planner, v))
        })
        .await;
        let (planner, new_version) = match stored {
            Ok(r) => r,
            Err(e) => return Err(self.store_failed(&s.id, e).await),
        };
        reserved.settle(&s.id, Charge::Plan, after)?;
        s.hub.reset(new_version, planner.plan(), planner.states())?;
        loaded.planner = Some(planner);
        st.version = new_version;
        Ok(new_version)
    }
}

/// Refuses a change made against plan version `base` (0: unchecked) when the plan is at
/// `current`: conflicting edits are never rebased.
fn check_base(base: u64, current: u64) -> Result<()> {
    if base != 0 && base != current {
        return Err(SessionError::StaleVersion { base, current });
    }
    Ok(())
}

/// What the caller learns of `change`, acknowledged as `plan_version`: the resections it added
/// or changed, each with its verdict, and those it removed.
fn outcome(planner: &Planner, plan_version: u64, change: Change) -> EditOutcome {
    let resections = change
        .changed
        .iter()
        .filter_map(|name| {
            let resection = planner.plan().resection(name).ok()?.clone();
            let verdict = planner.state(name).ok().map(|s| s.verdict.clone());
            Some(ResectionStatus { resection, verdict })
        })
        .collect();
    EditOutcome {
        plan_version,
        resections,
        removed: change.removed,
    }
}

/// Bytes per surface sample of `planner`'s states.
fn per_sample(planner: &Planner) -> u64 {
    sample_bytes(planner.compute_engine())
}

/// The memory a change that reshapes the plan (adds, removes or resamples surfaces) needs
/// while computed: the plan's surfaces after it, with the changed ones twice; it replaces the
/// plan's charge. `None` for a change of existing surfaces, whose recomputation the plan's
/// charge leaves room for.
fn memory_need(planner: &Planner, op: &EditOp) -> Result<Option<u64>> {
    let history = planner.history();
    let staged = match op {
        EditOp::Event { event } if !reshapes(event) => return Ok(None),
        EditOp::Event { event } => history.stage_edit(event.clone())?,
        EditOp::Undo => history.stage_undo()?,
        EditOp::Redo => history.stage_redo()?,
        EditOp::InitFromEndPoint { .. } | EditOp::InitFromPlane { .. } => {
            let per_sample = per_sample(planner);
            let added =
                added_resection_bytes(resecta_plan::resection::DEFAULT_RESOLUTION, per_sample);
            return Ok(Some(plan_bytes(planner.plan(), per_sample) + added));
        }
    };
    Ok(Some(plan_change_bytes(
        staged.plan(),
        staged.changed(),
        per_sample(planner),
    )))
}

/// Whether `event` adds, removes or resamples a surface.
fn reshapes(event: &PlanEvent) -> bool {
    matches!(
        event,
        PlanEvent::AddResection { .. }
            | PlanEvent::DeleteResection { .. }
            | PlanEvent::SetResolution { .. }
            | PlanEvent::SetTarget { .. }
    )
}

/// Whether `op` is a small edit for a quick pool: a change to existing resections (no new
/// resection, resolution or target) while every surface has at most [`QUICK_SAMPLES`] samples.
fn is_quick(planner: &Planner, op: &EditOp) -> bool {
    let EditOp::Event { event } = op else {
        return false;
    };
    !reshapes(event)
        && planner
            .plan()
            .resections
            .iter()
            .all(|r| r.resolution[0] * r.resolution[1] <= QUICK_SAMPLES)
}

/// Applies `op` (its event once). Returns what changed and the log record to store.
fn apply_edit(planner: &mut Planner, op: EditOp) -> Result<(Change, String)> {
    let change = match op {
        EditOp::Event { event } => planner.edit(event)?,
        EditOp::InitFromEndPoint {
            name,
            target,
            end_point,
            grid,
        } => {
            let (r, _) = planner.initial_resection(&name, &target, Vec3::from(end_point), grid)?;
            planner.edit(PlanEvent::AddResection { resection: r })?
        }
        EditOp::InitFromPlane {
            name,
            target,
            point,
            normal,
            grid,
        } => {
            let plane = Plane::new(Vec3::from(point), Vec3::from(normal))
                .map_err(|e| SessionError::Invalid(format!("plane: {e}")))?;
            let (r, _) = planner.initial_on_plane(&name, &target, &plane, grid)?;
            planner.edit(PlanEvent::AddResection { resection: r })?
        }
        EditOp::Undo => planner.undo()?,
        EditOp::Redo => planner.redo()?,
    };
    let record = log::entry_record(&change.entry)?;
    Ok((change, record))
}

#[cfg(test)]
mod tests {
    use resecta_geom::RoleMap;
    use resecta_phantom::{PhantomSpec, generate};
    use resecta_plan::Anatomy;

    use super::*;

    fn planner() -> Planner {
        let labels = generate(&PhantomSpec::small()).unwrap().labels;
        let roles = RoleMap::default();
        let anatomy = Arc::new(Anatomy::new(&labels, &roles).unwrap());
        Planner::new(anatomy, Plan::new(roles)).unwrap()
    }

    fn init(name: &str) -> EditOp {
        EditOp::InitFromEndPoint {
            name: name.into(),
            target: Default::default(),
            end_point: [-30.0, 0.0, 0.0],
            grid: [4, 4],
        }
    }

    fn event(event: PlanEvent) -> EditOp {
        EditOp::Event { event }
    }

    #[test]
    fn only_the_current_version_or_none_is_a_valid_base() {
        assert!(check_base(0, 7).is_ok());
        assert!(check_base(7, 7).is_ok());
        for base in [6, 8] {
            assert!(matches!(
                check_base(base, 7),
                Err(SessionError::StaleVersion { base: b, current: 7 }) if b == base
            ));
        }
    }

    #[test]
    fn outcomes_name_what_the_change_added_changed_and_removed() {
        let mut planner = planner();
        let (change, record) = apply_edit(&mut planner, init("r1")).unwrap();
        assert!(!record.is_empty());
        let added = outcome(&planner, 1, change);
        assert_eq!(added.plan_version, 1);
        assert_eq!(added.resections.len(), 1);
        assert_eq!(added.resections[0].resection.name, "r1");
        assert!(added.resections[0].verdict.is_some());
        assert!(added.removed.is_empty());

        let delete = event(PlanEvent::DeleteResection { name: "r1".into() });
        let (change, _) = apply_edit(&mut planner, delete).unwrap();
        let removed = outcome(&planner, 2, change);
        assert!(removed.resections.is_empty());
        assert_eq!(removed.removed, ["r1"]);

        let (change, _) = apply_edit(&mut planner, EditOp::Undo).unwrap();
        assert_eq!(outcome(&planner, 3, change).resections.len(), 1);
    }

    #[test]
    fn small_reshaping_free_edits_are_quick() {
        let mut planner = planner();
        assert!(!is_quick(&planner, &init("r1")));
        apply_edit(&mut planner, init("r1")).unwrap();
        let translate = event(PlanEvent::Translate {
            name: "r1".into(),
            delta: [1.0, 0.0, 0.0],
        });
        let resolution = |resolution| {
            event(PlanEvent::SetResolution {
                name: "r1".into(),
                resolution,
            })
        };
        assert!(!is_quick(&planner, &resolution([50, 50])));
        assert!(!is_quick(&planner, &EditOp::Undo));
        apply_edit(&mut planner, resolution([100, 100])).unwrap();
        assert!(is_quick(&planner, &translate), "10 000 samples");
        apply_edit(&mut planner, resolution([101, 100])).unwrap();
        assert!(!is_quick(&planner, &translate), "10 100 samples");
    }
}
