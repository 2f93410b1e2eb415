//! What the operation layer holds per session in memory: the session handle with its watch hub,
//! and behind its async mutex the label map, the planner (or its pending set-up) and the models.

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::{Arc, Mutex};

use resecta_geom::{LabelMap, RoleMap, TriMesh};
use resecta_plan::{Anatomy, ComputeEngine, History, Plan, PlanError, Planner};
use resecta_recon::ReconError;
use tokio::sync::Mutex as AsyncMutex;

use crate::api::{LabelMapSummary, ModelInfo, Surface};
use crate::error::{Missing, Result, SessionError};
use crate::pools::{self, Priority};
use crate::support::internal;
use crate::watch::Hub;

/// The error of every operation on a session that cannot be restored.
pub(crate) fn damaged() -> SessionError {
    SessionError::Precondition(
        Missing::Other,
        "the stored session is damaged and cannot be restored; only deleting it works".into(),
    )
}

pub(crate) fn no_label_map() -> SessionError {
    SessionError::Precondition(Missing::LabelMap, "the session has no label map".into())
}

#[derive(Debug)]
pub(crate) struct Model {
    pub(crate) info: ModelInfo,
    pub(crate) mesh: TriMesh,
    pub(crate) surface: Surface,
}

/// What reconstructed models hold: their meshes and encoded surfaces.
pub(crate) fn models_bytes(models: &[Model]) -> u64 {
    models
        .iter()
        .map(|m| {
            (m.mesh.vertices().len() * 48 + m.mesh.triangles().len() * 12 + m.surface.mesh.len())
                as u64
        })
        .sum()
}

/// What a planner set-up builds on: the label map, its roles, the plan history to resume
/// (`None`: an empty plan on the roles) and the flag set when its session is deleted.
#[derive(Debug, Clone)]
pub(crate) struct SetUp {
    pub(crate) labels: Arc<LabelMap>,
    pub(crate) roles: RoleMap,
    pub(crate) history: Option<History>,
    pub(crate) deleted: Arc<AtomicBool>,
    /// Makes the planner's surface evaluators.
    pub(crate) engine: ComputeEngine,
}

/// Sets its flag when dropped: a set-up nobody waits for any more stops at its next check.
#[derive(Debug)]
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
    }
}

/// A planner set-up running on a worker pool.
#[derive(Debug)]
pub(crate) struct Pending {
    handle: tokio::task::JoinHandle<Result<Result<Planner>>>,
    /// Stops the set-up when this is dropped (a new label map, the session gone).
    _cancel: CancelOnDrop,
    /// To retry after an error.
    setup: SetUp,
    /// Shows the plan's resection states to watchers at this plan version once built (a
    /// restored session's).
    publish: Option<(Arc<Hub>, u64)>,
}

#[derive(Debug)]
pub(crate) struct Loaded {
    pub(crate) labels: Arc<LabelMap>,
    pub(crate) summary: LabelMapSummary,
    /// `None` only while a blocking task holds it, or while `pending` builds it.
    pub(crate) planner: Option<Planner>,
    /// The planner's set-up (anatomy: liver envelope, tumour models, margin structures) after
    /// an upload or a restore, running on a worker pool; the upload is acknowledged without
    /// waiting.
    pub(crate) pending: Option<Pending>,
    /// Changes with every label-map load (reconstructions of an older one are dropped).
    pub(crate) generation: u64,
}

#[derive(Debug)]
pub(crate) struct State {
    pub(crate) display_name: String,
    pub(crate) created_ms: i64,
    /// Restored from the store (at start-up in the background, or on first use).
    pub(crate) restored: bool,
    pub(crate) loaded: Option<Loaded>,
    pub(crate) models: Option<Arc<Vec<Model>>>,
    /// Acknowledged log records.
    pub(crate) version: u64,
    pub(crate) generation: u64,
}

#[derive(Debug)]
pub(crate) struct Session {
    pub(crate) id: String,
    pub(crate) state: Arc<AsyncMutex<State>>,
    pub(crate) hub: Arc<Hub>,
    pub(crate) last_touch_ms: AtomicI64,
    pub(crate) volumes_scheduled: AtomicBool,
    /// When the last edit was acknowledged (volume recomputation waits for a pause).
    pub(crate) last_edit: Mutex<std::time::Instant>,
    /// Set when the session is deleted: its planner set-up stops.
    pub(crate) deleted: Arc<AtomicBool>,
    /// Set when the stored session cannot be restored.
    pub(crate) damaged: AtomicBool,
    /// Set when this replica's lease on the session has ended (replicated servers): the next
    /// call drops it and claims the lease anew.
    pub(crate) lost: AtomicBool,
}

impl Loaded {
    /// Whether watchers wait for the set-up: a restored session's resections reach its hub
    /// once its planner is built.
    pub(crate) fn unpublished(&self) -> bool {
        self.pending.as_ref().is_some_and(|p| p.publish.is_some())
    }

    /// Waits for a pending planner set-up (an error there is the operation's error, and comes
    /// again on the next try: the set-up is retried; a cancelled one is not).
    pub(crate) async fn ready(&mut self) -> Result<&mut Planner> {
        // Awaited in place: a caller that goes away leaves the set-up for the next one.
        if let Some(pending) = self.pending.as_mut() {
            let outcome = (&mut pending.handle).await;
            let Some(Pending { setup, publish, .. }) = self.pending.take() else {
                return Err(internal("a pending set-up vanished"));
            };
            match outcome.map_err(internal)?? {
                Ok(p) => {
                    let planner = self.planner.insert(p);
                    if let Some((hub, version)) = publish {
                        hub.reset(version, planner.plan(), planner.states())?;
                    }
                }
                Err(SessionError::Cancelled) => return Err(SessionError::Cancelled),
                Err(e) => {
                    self.pending = Some(spawn_planner(setup, Priority::SetUp, publish));
                    return Err(e);
                }
            }
        }
        self.planner
            .as_mut()
            .ok_or_else(|| internal("session planner is busy or was lost"))
    }

    pub(crate) async fn take_planner(&mut self) -> Result<Planner> {
        self.ready().await?;
        self.planner
            .take()
            .ok_or_else(|| internal("session planner is busy or was lost"))
    }
}

/// Builds the anatomy and the planner of `setup` on the pool for `priority`. The set-up stops
/// with [`SessionError::Cancelled`] once the returned [`Pending`] is dropped or the session is
/// deleted; `publish` shows the planner's states to watchers once it is taken.
pub(crate) fn spawn_planner(
    setup: SetUp,
    priority: Priority,
    publish: Option<(Arc<Hub>, u64)>,
) -> Pending {
    let cancel = Arc::new(AtomicBool::new(false));
    let job = setup.clone();
    let flag = Arc::clone(&cancel);
    let handle = tokio::spawn(pools::run(priority, move || {
        let SetUp {
            labels,
            roles,
            history,
            deleted,
            engine,
        } = job;
        let cancelled = || flag.load(Ordering::Acquire) || deleted.load(Ordering::Acquire);
        let t = std::time::Instant::now();
        let built = build_planner(&labels, roles, history, engine, &cancelled);
        tracing::debug!(
            ms = t.elapsed().as_secs_f64() * 1e3,
            ok = built.is_ok(),
            "planner set up"
        );
        built
    }));
    Pending {
        handle,
        _cancel: CancelOnDrop(cancel),
        setup,
        publish,
    }
}

fn build_planner(
    labels: &LabelMap,
    roles: RoleMap,
    history: Option<History>,
    engine: ComputeEngine,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<Planner> {
    let stopped = |e: PlanError| {
        if matches!(e, PlanError::Recon(ReconError::Cancelled)) {
            SessionError::Cancelled
        } else {
            SessionError::Plan(e)
        }
    };
    let anatomy = Arc::new(Anatomy::new_cancellable(labels, &roles, cancelled).map_err(stopped)?);
    if cancelled() {
        return Err(SessionError::Cancelled);
    }
    let planner = match history {
        Some(h) => Planner::resume_with_engine(anatomy, h, engine)?,
        None => Planner::with_engine(anatomy, Plan::new(roles), engine)?,
    };
    log_device_fallback(&planner, 0);
    Ok(planner)
}

/// Logs that `planner` moved to the CPU when its device failed since it had `before` failures.
pub(crate) fn log_device_fallback(planner: &Planner, before: u32) {
    if planner.device_fallbacks() > before {
        let error = planner
            .states()
            .values()
            .find_map(|s| s.surface.device_error())
            .map(ToString::to_string)
            .unwrap_or_default();
        tracing::warn!(%error, "surface evaluation device failed; this session plans on the CPU");
    }
}

pub(crate) fn loaded_mut(st: &mut State) -> Result<&mut Loaded> {
    st.loaded.as_mut().ok_or_else(no_label_map)
}

#[cfg(test)]
mod tests {
    use std::sync::{Condvar, Weak};
    use std::time::Duration;

    use resecta_phantom::{PhantomSpec, generate};
    use resecta_store::{MemoryStore, StoreOptions};

    use super::*;
    use crate::ServiceConfig;
    use crate::api::{EditOp, LabelMapSource, RawLabelMap};
    use crate::service::Service;

    fn small() -> LabelMapSource {
        let labels = generate(&PhantomSpec::small()).unwrap().labels;
        LabelMapSource::Raw(RawLabelMap::of(&labels))
    }

    /// Occupies every set-up worker until the returned gate opens.
    fn hold_background() -> Arc<(Mutex<bool>, Condvar)> {
        let gate = Arc::new((Mutex::new(false), Condvar::new()));
        for _ in 0..pools::set_up_threads() {
            let gate = Arc::clone(&gate);
            tokio::spawn(pools::run(Priority::SetUp, move || {
                let (open, cv) = &*gate;
                let mut g = open.lock().unwrap();
                while !*g {
                    g = cv.wait(g).unwrap();
                }
            }));
        }
        gate
    }

    fn open(gate: &(Mutex<bool>, Condvar)) {
        *gate.0.lock().unwrap() = true;
        gate.1.notify_all();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn deleting_a_session_stops_its_set_up_and_frees_it() {
        let store = Arc::new(MemoryStore::new(StoreOptions::default()));
        let service = Arc::new(Service::new(store, ServiceConfig::default()));
        let gone = service.create_session("deleted").await.unwrap().id;
        let kept = service.create_session("kept").await.unwrap().id;
        // Neither set-up can start before the delete.
        let gate = hold_background();
        for id in [&gone, &kept] {
            service
                .upload_label_map(id, small(), RoleMap::default())
                .await
                .unwrap();
        }
        let session = service.session(&gone).await.unwrap();
        let labels: Weak<LabelMap> = {
            let st = session.state.lock().await;
            let loaded = st.loaded.as_ref().unwrap();
            assert!(loaded.pending.is_some(), "the set-up is pending");
            Arc::downgrade(&loaded.labels)
        };
        let both = service.memory_in_use().unwrap();
        service.delete_session(&gone).await.unwrap();
        assert!(service.memory_in_use().unwrap() < both);
        open(&gate);
        // The other session plans as usual.
        assert_eq!(first_resection(&service, &kept).await, 1);
        // The deleted one's set-up stopped instead of finishing.
        let stopped = {
            let mut st = session.state.lock().await;
            let loaded = st.loaded.as_mut().unwrap();
            loaded.ready().await.map(|_| ())
        };
        assert!(
            matches!(stopped, Err(SessionError::Cancelled)),
            "{stopped:?}"
        );
        drop(session);
        // Its label map is freed once nothing holds the session (a bound, not a timing).
        for _ in 0..3000 {
            if labels.upgrade().is_none() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert!(
            labels.upgrade().is_none(),
            "the deleted session's label map is still held"
        );
        assert!(service.get_session(&gone).await.is_err());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_new_label_map_cancels_the_set_up_of_the_one_it_replaces() {
        let store = Arc::new(MemoryStore::new(StoreOptions::default()));
        let service = Arc::new(Service::new(store, ServiceConfig::default()));
        let id = service.create_session("twice").await.unwrap().id;
        let gate = hold_background();
        service
            .upload_label_map(&id, small(), RoleMap::default())
            .await
            .unwrap();
        let session = service.session(&id).await.unwrap();
        let first = {
            let st = session.state.lock().await;
            let pending = st.loaded.as_ref().unwrap().pending.as_ref().unwrap();
            Arc::clone(&pending._cancel.0)
        };
        assert!(!first.load(Ordering::Acquire));
        service
            .upload_label_map(&id, small(), RoleMap::default())
            .await
            .unwrap();
        assert!(
            first.load(Ordering::Acquire),
            "the first set-up is cancelled"
        );
        open(&gate);
        assert_eq!(first_resection(&service, &id).await, 1);
    }

    /// Plans a first resection on the session `id`; the resections the edit answers.
    async fn first_resection(service: &Arc<Service>, id: &str) -> usize {
        let op = EditOp::InitFromEndPoint {
            name: "r1".into(),
            target: Default::default(),
            end_point: [-30.0, 0.0, 0.0],
            grid: [4, 4],
        };
        service.edit(id, 0, op).await.unwrap().resections.len()
    }
}
