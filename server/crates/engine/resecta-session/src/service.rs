//! The operation layer: every operation of the planning server, once, for the gRPC and HTTP
//! faces alike.
//!
//! Per session, one async mutex orders the operations. CPU work runs off the runtime (module
//! `pools`): small edits on single-thread quick pools, others on rayon's pool, the planner set-up
//! after an upload or a restore on a set-up pool, other heavy work (volumes between edits,
//! reconstruction) on an idle-class background pool, store I/O on the blocking pool, so a long
//! job never stalls the runtime or another session's edits. Watchers see an edit as soon as it is
//! computed; it is acknowledged only after its log record is durable in the store (a record that
//! cannot be stored rolls the edit back, and watchers get a snapshot of the plan as it was);
//! restarting replays the log to the same plan.
//!
//! [`Service`] is the front: it holds the store, the configuration and the session table, and
//! each operation is written once in the part whose job it is: `registry` (the `Registry`: the
//! sessions held, the session and memory quotas as reservations, idle selection; no store),
//! `sessions` (creating, listing, deleting, expiring sessions over the store), `log` (records,
//! blobs, replay, rollback: the storage format), `edits` (plan changes and imports), `volumes`
//! (volumetry; `VolumeTiming` says when it is recomputed), `recon` (reconstruction, point
//! clouds); `state` is what a session holds in memory. This module keeps restoring, opening,
//! upload and the read-only exports.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use resecta_geom::RoleMap;
use resecta_io::mesh::{MeshFormat, WriteOptions, mesh_to_bytes};
use resecta_plan::{
    LabelSlice, Resectogram, RiskMap, SliceAxis, SlicePositions, SliceProjections, label_slice,
    slice_projections,
};
use resecta_store::SessionStore;

use crate::api::{API_VERSION, LabelMapSource, LabelMapSummary, Limits, ServerInfo, Versioned};
use crate::budget::{
    Budget, Charge, UploadMemory, Use, label_map_bytes, plan_bytes, plan_samples, sample_bytes,
    watcher_bytes,
};
use crate::config::ServiceConfig;
use crate::error::{Missing, Quota, Result, SessionError};
use crate::labelmap;
use crate::log;
use crate::pools::{self, Priority};
use crate::registry::Registry;
use crate::state::{
    Loaded, Session, SetUp, State, damaged, loaded_mut, models_bytes, no_label_map, spawn_planner,
};
use crate::support::{blocking, internal};
use crate::watch::WatchStream;

/// The operation layer over a [`SessionStore`].
#[derive(Debug)]
pub struct Service {
    pub(crate) store: Arc<dyn SessionStore>,
    pub(crate) config: ServiceConfig,
    /// The sessions held in memory and the session quota.
    pub(crate) registry: Arc<Registry<Session>>,
    /// The memory budget: what sessions hold and what work in flight reserves.
    pub(crate) budget: Arc<Budget>,
    /// Sessions with a volume recomputation scheduled (editing now or just paused).
    pub(crate) volumes_scheduled: AtomicUsize,
    /// Set once the server drains before a stop.
    pub(crate) draining: AtomicBool,
}

impl Service {
    /// A service over `store`; sessions already stored are restored when first used.
    pub fn new(store: Arc<dyn SessionStore>, config: ServiceConfig) -> Self {
        Self {
            store,
            registry: Arc::new(Registry::new(config.max_sessions)),
            budget: Budget::new(config.max_memory_bytes),
            config,
            volumes_scheduled: AtomicUsize::new(0),
            draining: AtomicBool::new(false),
        }
    }

    /// Marks the server as draining: [`Self::ready`] fails from now on.
    pub fn begin_drain(&self) {
        self.draining.store(true, Ordering::Release);
    }

    /// Whether the server takes work: not draining, and its store answers.
    pub async fn ready(&self) -> Result<()> {
        if self.draining.load(Ordering::Acquire) {
            return Err(SessionError::Precondition(
                Missing::Other,
                "the server is draining".into(),
            ));
        }
        let store = Arc::clone(&self.store);
        blocking(move || Ok(store.session("readyz")?)).await?;
        Ok(())
    }

    /// Bytes a session's replay ring may hold.
    pub(crate) fn ring_bytes(&self) -> u64 {
        self.config.ring.bytes as u64
    }

    pub fn config(&self) -> &ServiceConfig {
        &self.config
    }

    pub fn info(&self) -> ServerInfo {
        // What this server does with its configuration: `zstd` / `quantized` only when mesh
        // payloads are compressed / quantised; then the edges' own (`tls`, `auth`), each once.
        let encode = &self.config.encode;
        let mut capabilities = vec![
            "psr".to_owned(),
            "mcsd".to_owned(),
            "watch-deltas".to_owned(),
        ];
        let configured = [
            (encode.zstd_level.is_some(), "zstd"),
            (encode.quantise.is_some(), "quantized"),
        ];
        capabilities.extend(configured.iter().filter(|c| c.0).map(|c| c.1.to_owned()));
        for c in &self.config.capabilities {
            if !capabilities.contains(c) {
                capabilities.push(c.clone());
            }
        }
        ServerInfo {
            version: env!("CARGO_PKG_VERSION"),
            api_version: API_VERSION,
            capabilities,
            limits: Limits {
                max_sessions: self.config.max_sessions,
                max_voxels: self.config.max_voxels,
                max_upload_bytes: self.config.max_upload_bytes,
                max_memory_bytes: self.config.max_memory_bytes,
                max_cloud_points: self.config.max_cloud_points,
                max_cloud_depth: self.config.max_cloud_depth,
            },
            compute: self.config.compute.clone(),
        }
    }

    /// Restores a session's label map, plan and models from the store (in the background at
    /// start-up, or on first use): the label map and the plan at once, the planner's set-up
    /// (anatomy, then the plan's resections) on the set-up pool, where the next call
    /// that needs the planner waits for it; watchers see the resections once it is built.
    /// `admit`: the session comes back only if its label map, plan and models fit the memory
    /// budget (the background restorer); a call's session always does.
    pub(crate) async fn restore(&self, s: &Session, st: &mut State, admit: bool) -> Result<()> {
        if st.restored {
            return Ok(());
        }
        if s.damaged.load(Ordering::Acquire) {
            return Err(damaged());
        }
        let store = Arc::clone(&self.store);
        let id = s.id.clone();
        let max_voxels = self.config.max_voxels;
        // The store on the blocking pool; decoding and replay on a worker pool.
        let stored = blocking(move || log::load(&*store, &id)).await?;
        let restored = match pools::run(Priority::SetUp, move || log::rebuild(stored, max_voxels))
            .await?
        {
            Ok(r) => r,
            Err(e) => {
                // Stored data that does not decode or replay within this build's bounds: the
                // session is reported damaged (never retried, never breaking listings).
                tracing::warn!(session = %s.id, error = %e, "stored session cannot be restored");
                s.damaged.store(true, Ordering::Release);
                return Err(damaged());
            }
        };
        let log::Restored {
            rec,
            version,
            loaded,
            models,
        } = restored;
        let voxels = loaded.as_ref().map_or(0, |l| l.0.data().len() as u64);
        let charges = [
            (
                Charge::LabelMap,
                if loaded.is_some() {
                    label_map_bytes(voxels, self.ring_bytes(), &self.config.compute_engine)
                } else {
                    0
                },
            ),
            (
                Charge::Plan,
                loaded.as_ref().map_or(0, |l| {
                    plan_bytes(l.3.plan(), sample_bytes(&self.config.compute_engine))
                }),
            ),
            (Charge::Models, models.as_deref().map_or(0, models_bytes)),
        ];
        // Held until the charges are set, so parallel work cannot take the room meanwhile.
        let _room = if admit {
            Some(
                self.budget
                    .reserve(Use::LabelMap, charges.iter().map(|c| c.1).sum())?,
            )
        } else {
            None
        };
        for (charge, bytes) in charges {
            self.budget.set(&s.id, charge, bytes)?;
        }
        st.display_name = rec.display_name;
        st.created_ms = rec.created_ms;
        st.version = version;
        st.restored = true;
        if let Some((labels, summary, roles, history)) = loaded {
            let setup = SetUp {
                labels: Arc::clone(&labels),
                roles,
                history: Some(history),
                deleted: Arc::clone(&s.deleted),
                engine: self.config.compute_engine.clone(),
            };
            let pending =
                spawn_planner(setup, Priority::SetUp, Some((Arc::clone(&s.hub), version)));
            st.loaded = Some(Loaded {
                labels,
                summary,
                planner: None,
                pending: Some(pending),
                generation: 0,
            });
        }
        if let Some(models) = models {
            s.hub
                .publish_models(models.iter().map(|m| m.surface.clone()).collect())?;
            st.models = Some(Arc::new(models));
        }
        tracing::info!(session = %s.id, version, "session restored");
        Ok(())
    }

    /// Restores every stored session in the background, most recently used first, one at a
    /// time (its planner set up before the next starts), while the memory budget allows; a call
    /// for a session the restorer has not reached restores that one at once, beside it.
    /// Restoring records no access (idle expiry is unchanged).
    pub fn restore_in_background(self: &Arc<Self>) -> tokio::task::JoinHandle<()> {
        let service = Arc::clone(self);
        tokio::spawn(async move {
            let started = std::time::Instant::now();
            match service.restore_all().await {
                Ok(n) => tracing::info!(
                    sessions = n,
                    ms = started.elapsed().as_secs_f64() * 1e3,
                    "sessions restored in the background"
                ),
                Err(e) => tracing::warn!(error = %e, "restoring sessions in the background"),
            }
        })
    }

    async fn restore_all(&self) -> Result<usize> {
        if self.config.replica.is_some() {
            // Replicas restore a session when a call claims it.
            return Ok(0);
        }
        let store = Arc::clone(&self.store);
        let mut records = blocking(move || Ok(store.sessions()?)).await?;
        records.sort_by(|a, b| {
            b.last_access_ms
                .cmp(&a.last_access_ms)
                .then(b.created_ms.cmp(&a.created_ms))
        });
        let mut n = 0;
        for rec in records {
            let store = Arc::clone(&self.store);
            let key = rec.id.clone();
            let Ok((_, summary, _)) = blocking(move || log::stored_summary(&*store, &key)).await
            else {
                continue;
            };
            // A first check before the log is read (the restore checks again, with the plan).
            let voxels = summary.map_or(0, |s| s.dims.iter().map(|&d| d as u64).product::<u64>());
            if self.budget.in_use()?
                + label_map_bytes(voxels, self.ring_bytes(), &self.config.compute_engine)
                > self.budget.max()
            {
                tracing::info!(session = %rec.id, "not restored in the background: memory budget");
                continue;
            }
            let Ok(s) = self.session_unrecorded(&rec.id).await else {
                continue;
            };
            let mut st = Arc::clone(&s.state).lock_owned().await;
            if st.restored {
                continue;
            }
            let restored = match self.restore(&s, &mut st, true).await {
                Ok(()) => match st.loaded.as_mut() {
                    Some(loaded) => loaded.ready().await.map(|_| ()),
                    None => Ok(()),
                },
                Err(e) => Err(e),
            };
            match restored {
                Ok(()) => n += 1,
                Err(SessionError::Cancelled | SessionError::UnknownSession(_)) => {}
                Err(SessionError::Quota(..)) => {
                    tracing::info!(session = %rec.id, "not restored in the background: memory budget");
                }
                Err(e) => tracing::warn!(session = %rec.id, error = %e, "background restore"),
            }
        }
        Ok(n)
    }

    /// The session, locked and restored.
    pub(crate) async fn open(
        &self,
        id: &str,
    ) -> Result<(Arc<Session>, tokio::sync::OwnedMutexGuard<State>)> {
        let s = self.session(id).await?;
        let mut st = Arc::clone(&s.state).lock_owned().await;
        self.restore(&s, &mut st, false).await?;
        Ok((s, st))
    }

    // ---- label maps and models --------------------------------------------------------------

    /// Memory for an upload about to be received, grown by the face as its bytes arrive and
    /// held until [`Self::upload_label_map`] returns.
    pub fn admit_upload(&self) -> Result<UploadMemory> {
        UploadMemory::new(&self.budget, self.config.max_upload_bytes)
    }

    /// Loads a label map with its role map, replacing any earlier one (the plan starts anew:
    /// an empty plan on the new roles).
    pub async fn upload_label_map(
        &self,
        id: &str,
        source: LabelMapSource,
        roles: RoleMap,
    ) -> Result<LabelMapSummary> {
        let bytes = match &source {
            LabelMapSource::Raw(r) => r.data.len(),
            LabelMapSource::File { bytes, .. } => bytes.len(),
        } as u64;
        if bytes > self.config.max_upload_bytes {
            return Err(SessionError::Quota(
                Quota::UploadBytes,
                format!(
                    "upload of {bytes} bytes exceeds the limit of {} bytes",
                    self.config.max_upload_bytes
                ),
            ));
        }
        let (s, mut st) = self.open(id).await?;
        let max_voxels = self.config.max_voxels;
        let t0 = std::time::Instant::now();
        let labels = blocking(move || labelmap::decode(&source, max_voxels)).await?;
        tracing::debug!(session = %s.id, ms = t0.elapsed().as_secs_f64() * 1e3, "label map decoded");
        let need = label_map_bytes(
            labels.data().len() as u64,
            self.ring_bytes(),
            &self.config.compute_engine,
        );
        let reserved =
            self.budget
                .reserve_replacing(Use::LabelMap, need, &s.id, Charge::LabelMap)?;
        let labels = Arc::new(labels);
        let summary = {
            let (labels, roles) = (Arc::clone(&labels), roles.clone());
            blocking(move || {
                let summary = labelmap::summary(&labels, &roles);
                labelmap::check_roles(&roles, &summary.labels)?;
                Ok(summary)
            })
            .await?
        };
        // The planner's set-up starts before the label map is stored: it overlaps the store
        // write, and is cancelled (dropped) if the write fails.
        let setup = SetUp {
            labels: Arc::clone(&labels),
            roles: summary.roles.clone(),
            history: None,
            deleted: Arc::clone(&s.deleted),
            engine: self.config.compute_engine.clone(),
        };
        let pending = spawn_planner(setup, Priority::SetUp, None);
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        let version = st.version;
        let stored = Arc::clone(&labels);
        let roles = summary.roles.clone();
        let kept = summary.clone();
        let stored = blocking(move || {
            let t = std::time::Instant::now();
            let (plan, version) =
                log::store_label_map(&*store, &key, version, &stored, &roles, &kept)?;
            tracing::debug!(session = %key, ms = t.elapsed().as_secs_f64() * 1e3, "label map stored");
            Ok((plan, version))
        })
        .await;
        let (plan, version) = match stored {
            Ok(r) => r,
            Err(e) => return Err(self.store_failed(&s.id, e).await),
        };
        reserved.settle(&s.id, Charge::LabelMap, need)?;
        // The plan starts anew (empty), and the models are gone.
        self.budget.set(&s.id, Charge::Plan, 0)?;
        self.budget.set(&s.id, Charge::Models, 0)?;
        st.version = version;
        st.generation += 1;
        st.models = None;
        s.hub.reset(version, &plan, &BTreeMap::new())?;
        s.hub.publish_models(Vec::new())?;
        st.loaded = Some(Loaded {
            labels,
            summary: summary.clone(),
            planner: None,
            pending: Some(pending),
            generation: st.generation,
        });
        tracing::info!(session = %s.id, voxels = summary.dims.iter().product::<usize>(), "label map loaded");
        Ok(summary)
    }

    /// The current plan as a `resecta-plan/1` document, with its plan version.
    pub async fn export_plan(&self, id: &str) -> Result<Versioned<String>> {
        let (_, mut st) = self.open(id).await?;
        let plan_version = st.version;
        let loaded = loaded_mut(&mut st)?;
        let planner = loaded.ready().await?;
        Ok(Versioned {
            plan_version,
            value: planner.plan().to_json()?,
        })
    }

    /// A model or resection surface as mesh file bytes.
    pub async fn export_model(&self, id: &str, name: &str, format: MeshFormat) -> Result<Vec<u8>> {
        let (_, mut st) = self.open(id).await?;
        let mesh = match st
            .models
            .as_ref()
            .and_then(|m| m.iter().find(|m| m.info.name == name))
        {
            Some(m) => m.mesh.clone(),
            None => {
                let loaded = loaded_mut(&mut st)?;
                let planner = loaded.ready().await?;
                planner
                    .state(name)
                    .map_err(|_| SessionError::ModelNotFound)?
                    .mesh()?
            }
        };
        blocking(move || {
            mesh_to_bytes(&mesh, format, &WriteOptions::default(), "model").map_err(internal)
        })
        .await
    }

    /// Intersections of a resection surface with axis-aligned slice planes.
    pub async fn slices(
        &self,
        id: &str,
        name: &str,
        at: SlicePositions,
    ) -> Result<SliceProjections> {
        let (_, mut st) = self.open(id).await?;
        let loaded = loaded_mut(&mut st)?;
        let planner = loaded.ready().await?;
        let mesh = planner.state(name)?.mesh()?;
        Ok(slice_projections(&mesh, &at)?)
    }

    /// A resection's resectogram, with the plan version it shows.
    pub async fn resectogram(
        &self,
        id: &str,
        name: &str,
        width: usize,
        height: usize,
    ) -> Result<Versioned<Resectogram>> {
        let (_, mut st) = self.open(id).await?;
        let plan_version = st.version;
        let loaded = loaded_mut(&mut st)?;
        let planner = loaded.ready().await?;
        Ok(Versioned {
            plan_version,
            value: planner.resectogram(name, width, height)?,
        })
    }

    /// The plan's risk map, with the plan version it shows.
    pub async fn risk_map(&self, id: &str) -> Result<Versioned<RiskMap>> {
        let (_, mut st) = self.open(id).await?;
        let plan_version = st.version;
        let loaded = loaded_mut(&mut st)?;
        let planner = loaded.ready().await?;
        let value = planner.risk_map()?.ok_or_else(|| {
            SessionError::Precondition(
                Missing::Other,
                "no risk map: the label map has no usable portal or hepatic vessels, or a \
                 resection does not cut the liver completely"
                    .into(),
            )
        })?;
        Ok(Versioned {
            plan_version,
            value,
        })
    }

    /// One plane of the label map as a raster of labels (nearest neighbour), computed off the
    /// runtime and without holding the session, so edits go on meanwhile.
    pub async fn label_slice(
        &self,
        id: &str,
        axis: SliceAxis,
        position_mm: f64,
        pixel_mm: Option<f64>,
    ) -> Result<LabelSlice> {
        let (_, st) = self.open(id).await?;
        let labels = Arc::clone(&st.loaded.as_ref().ok_or_else(no_label_map)?.labels);
        drop(st);
        blocking(move || Ok(label_slice(&labels, axis, position_mm, pixel_mm)?)).await
    }

    /// The session's event stream: from `since` when the server still holds what followed it,
    /// else from a snapshot.
    pub async fn watch(&self, id: &str, since: Option<u64>) -> Result<WatchStream> {
        let (s, mut st) = self.open(id).await?;
        // A restored session's resections reach its hub once its planner is set up.
        if let Some(loaded) = st.loaded.as_mut()
            && loaded.unpublished()
        {
            loaded.ready().await?;
        }
        let samples = st
            .loaded
            .as_ref()
            .and_then(|l| l.planner.as_ref())
            .map_or(0, |p| plan_samples(p.plan()));
        let memory = self.budget.reserve(Use::Watcher, watcher_bytes(samples))?;
        Ok(s.hub.subscribe(since, Some(memory)))
    }
}
