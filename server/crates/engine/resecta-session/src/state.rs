//! What the operation layer holds per session in memory: the session handle with its watch hub,
//! and behind its async mutex the label map, the planner (or its pending set-up) and the models.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64};
use std::sync::{Arc, Mutex};

use resecta_geom::{LabelMap, RoleMap, TriMesh};
use resecta_plan::{Anatomy, Plan, Planner};
use tokio::sync::Mutex as AsyncMutex;

use crate::api::{LabelMapSummary, ModelInfo, Surface};
use crate::error::{Missing, Result, SessionError};
use crate::pools::{self, Priority};
use crate::support::internal;
use crate::watch::Hub;

/// Estimated resident bytes per voxel of a loaded session (label map, liver masks, volumetry).
pub(crate) const BYTES_PER_VOXEL: u64 = 8;

pub(crate) fn no_label_map() -> SessionError {
    SessionError::Precondition(Missing::LabelMap, "the session has no label map".into())
}

#[derive(Debug)]
pub(crate) struct Model {
    pub(crate) info: ModelInfo,
    pub(crate) mesh: TriMesh,
    pub(crate) surface: Surface,
}

#[derive(Debug)]
pub(crate) struct Loaded {
    pub(crate) labels: Arc<LabelMap>,
    pub(crate) summary: LabelMapSummary,
    /// `None` only while a blocking task holds it, or while `pending` builds it.
    pub(crate) planner: Option<Planner>,
    /// The planner's set-up (anatomy: liver envelope, tumour models, distance structures) after
    /// an upload, running on the background pool; the upload is acknowledged without waiting.
    pub(crate) pending: Option<tokio::task::JoinHandle<Result<Result<Planner>>>>,
    /// Changes with every label-map load (reconstructions of an older one are dropped).
    pub(crate) generation: u64,
}

#[derive(Debug)]
pub(crate) struct State {
    pub(crate) display_name: String,
    pub(crate) created_ms: i64,
    /// Restored from the store on first use after a restart.
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
    pub(crate) memory: AtomicU64,
}

impl Loaded {
    /// Waits for a pending planner set-up (an error there is the operation's error, and comes
    /// again on the next try: the set-up is retried).
    pub(crate) async fn ready(&mut self) -> Result<&mut Planner> {
        // Awaited in place: a caller that goes away leaves the set-up for the next one.
        if let Some(pending) = self.pending.as_mut() {
            let outcome = pending.await;
            self.pending = None;
            match outcome.map_err(internal)?? {
                Ok(p) => self.planner = Some(p),
                Err(e) => {
                    let (labels, roles) = (Arc::clone(&self.labels), self.summary.roles.clone());
                    self.pending = Some(spawn_planner(labels, roles));
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

/// Builds the anatomy and an empty plan's planner for `labels` on the background pool.
pub(crate) fn spawn_planner(
    labels: Arc<LabelMap>,
    roles: RoleMap,
) -> tokio::task::JoinHandle<Result<Result<Planner>>> {
    tokio::spawn(pools::run(Priority::Background, move || {
        let t = std::time::Instant::now();
        let anatomy = Arc::new(Anatomy::new(&labels, &roles)?);
        tracing::debug!(ms = t.elapsed().as_secs_f64() * 1e3, "anatomy set up");
        Ok(Planner::new(anatomy, Plan::new(roles))?)
    }))
}

pub(crate) fn loaded_mut(st: &mut State) -> Result<&mut Loaded> {
    st.loaded.as_mut().ok_or_else(no_label_map)
}
