//! The operation layer: every operation of the planning server, once, for the gRPC and HTTP
//! faces alike.
//!
//! Per session, one async mutex orders the operations. CPU work runs off the runtime (module
//! `pools`): small edits on single-thread quick pools, others on rayon's pool, heavy work (anatomy set-up after an upload or a restart,
//! volumes between edits, reconstruction) on an idle-class background pool, store I/O on the blocking pool, so a long
//! job never stalls the runtime or another session's edits. Watchers see an edit as soon as it is
//! computed; it is acknowledged only after its log record is durable in the store (a record that
//! cannot be stored rolls the edit back, and watchers get a snapshot of the plan as it was);
//! restarting replays the log to the same plan.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use resecta_delta::{
    DecodeLimits, EncodeOptions, SurfaceFrame, Topology, decode_mesh, encode_mesh,
};
use resecta_geom::{LabelMap, Plane, Real, Role, RoleMap, TriMesh, Vec3};
use resecta_io::mesh::{MeshFormat, WriteOptions, mesh_to_bytes};
use resecta_plan::{
    Anatomy, Change, History, LogEntry, Plan, PlanEvent, Planner, SlicePositions, SliceProjections,
    VolumeReport, slice_projections,
};
use resecta_recon::{
    McsdParams, ModelOptions, ParenchymaMethod, ReconError, SPECK_MM3, patient_models,
};
use resecta_store::{Blob, SessionRecord, SessionStore};
use serde::{Deserialize, Serialize};
use tokio::sync::{Mutex as AsyncMutex, mpsc};

use crate::api::{
    API_VERSION, DroppedComponents, EditOp, EditOutcome, LabelMapSource, LabelMapSummary, Limits,
    ModelInfo, ReconMethod, ReconOptions, ReconstructEvent, ResectionStatus, ServerInfo,
    SessionInfo, SessionState, Surface, SurfaceKind, Versioned,
};
use crate::error::{Missing, Quota, Result, SessionError};
use crate::labelmap;
use crate::pools::{self, Priority};
use crate::watch::{Hub, RingBounds, WatchStream};

/// Limits and tuning of a [`Service`].
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    pub max_sessions: usize,
    /// Voxels per label map.
    pub max_voxels: u64,
    /// Bytes of one upload (raw data or file).
    pub max_upload_bytes: u64,
    /// Estimated memory of all loaded sessions together.
    pub max_memory_bytes: u64,
    /// Sessions untouched for this long are deleted by [`Service::expire_idle`].
    pub idle_expiry: Option<Duration>,
    pub ring: RingBounds,
    pub encode: EncodeOptions,
    /// Volumes are recomputed once edits pause this long ...
    pub volumes_delay: Duration,
    /// ... or, during a continuous burst of edits (a drag), this long after its first edit ...
    pub volumes_max_interval: Duration,
    /// ... and such mid-drag recomputations, all sessions together, at most this many per
    /// second: with n sessions dragging at once each refreshes every max(volumes_max_interval,
    /// n / this) while dragging (a pause always refreshes), so many users' drags are not slowed
    /// by each other's volumetry.
    pub volumes_during_drags_per_s: f64,
    /// Depth of the parenchyma's screened Poisson reconstruction when a call names none.
    pub psr_depth: u32,
    /// Capabilities reported by [`Service::info`] (the edges add theirs, e.g. "tls").
    pub capabilities: Vec<String>,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            max_sessions: 64,
            max_voxels: 1 << 28,
            max_upload_bytes: 1 << 30,
            max_memory_bytes: 16 << 30,
            idle_expiry: Some(Duration::from_secs(7 * 24 * 3600)),
            ring: RingBounds {
                items: 1024,
                bytes: 64 << 20,
            },
            encode: EncodeOptions::exact(),
            volumes_delay: Duration::from_millis(150),
            volumes_max_interval: Duration::from_secs(1),
            volumes_during_drags_per_s: 4.0,
            psr_depth: 7,
            capabilities: Vec::new(),
        }
    }
}

/// Estimated resident bytes per voxel of a loaded session (label map, liver masks, volumetry).
const BYTES_PER_VOXEL: u64 = 8;
/// Display names: characters.
const MAX_DISPLAY_NAME: usize = 256;
/// Edits of surfaces of at most this many samples run on one thread (`pools`: no fork-join).
const QUICK_SAMPLES: usize = 10_000;
/// Last-access times are written at most this often per session (ms).
const TOUCH_EVERY_MS: i64 = 60_000;
const LABELMAP_BLOB: &str = "labelmap";
const SUMMARY_BLOB: &str = "summary";
const MODELS_BLOB: &str = "models";

/// A record of a session's plan log (`E`: the entry, borrowed when written).
#[derive(Debug, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum Record<E = LogEntry> {
    /// A new base plan (label-map load or import): what follows edits it.
    Reset {
        plan: String,
    },
    Entry {
        entry: E,
    },
}

fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// A gauge of operations in progress (queued for their session or running): +1 now, −1 on drop.
struct InFlight(&'static str);

impl InFlight {
    fn new(name: &'static str) -> Self {
        metrics::gauge!(name).increment(1.0);
        Self(name)
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        metrics::gauge!(self.0).decrement(1.0);
    }
}

fn no_label_map() -> SessionError {
    SessionError::Precondition(Missing::LabelMap, "the session has no label map".into())
}

fn internal(e: impl std::fmt::Display) -> SessionError {
    SessionError::Internal(e.to_string())
}

/// Runs `f` on the blocking pool.
async fn blocking<T: Send + 'static>(f: impl FnOnce() -> Result<T> + Send + 'static) -> Result<T> {
    tokio::task::spawn_blocking(f).await.map_err(internal)?
}

#[derive(Debug)]
struct Model {
    info: ModelInfo,
    mesh: TriMesh,
    surface: Surface,
}

#[derive(Debug)]
struct Loaded {
    labels: Arc<LabelMap>,
    summary: LabelMapSummary,
    /// `None` only while a blocking task holds it, or while `pending` builds it.
    planner: Option<Planner>,
    /// The planner's set-up (anatomy: liver envelope, tumour models, distance structures) after
    /// an upload, running on the background pool; the upload is acknowledged without waiting.
    pending: Option<tokio::task::JoinHandle<Result<Result<Planner>>>>,
    /// Changes with every label-map load (reconstructions of an older one are dropped).
    generation: u64,
}

#[derive(Debug)]
struct State {
    display_name: String,
    created_ms: i64,
    /// Restored from the store on first use after a restart.
    restored: bool,
    loaded: Option<Loaded>,
    models: Option<Arc<Vec<Model>>>,
    /// Acknowledged log records.
    version: u64,
    generation: u64,
}

#[derive(Debug)]
struct Session {
    id: String,
    state: Arc<AsyncMutex<State>>,
    hub: Arc<Hub>,
    last_touch_ms: AtomicI64,
    volumes_scheduled: AtomicBool,
    /// When the last edit was acknowledged (volume recomputation waits for a pause).
    last_edit: Mutex<std::time::Instant>,
    memory: std::sync::atomic::AtomicU64,
}

/// The operation layer over a [`SessionStore`].
#[derive(Debug)]
pub struct Service {
    store: Arc<dyn SessionStore>,
    config: ServiceConfig,
    sessions: Mutex<HashMap<String, Arc<Session>>>,
    /// Sessions with a volume recomputation scheduled (editing now or just paused).
    volumes_scheduled: AtomicUsize,
}

impl Loaded {
    /// Waits for a pending planner set-up (an error there is the operation's error, and comes
    /// again on the next try: the set-up is retried).
    async fn ready(&mut self) -> Result<&mut Planner> {
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

    async fn take_planner(&mut self) -> Result<Planner> {
        self.ready().await?;
        self.planner
            .take()
            .ok_or_else(|| internal("session planner is busy or was lost"))
    }
}

/// Builds the anatomy and an empty plan's planner for `labels` on the background pool.
fn spawn_planner(
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

fn check_display_name(name: &str) -> Result<()> {
    if name.is_empty() || name.chars().count() > MAX_DISPLAY_NAME {
        return Err(SessionError::Invalid(format!(
            "display name must have 1 to {MAX_DISPLAY_NAME} characters"
        )));
    }
    if name.chars().any(char::is_control) {
        return Err(SessionError::Invalid(
            "display name must not contain control characters".into(),
        ));
    }
    Ok(())
}

fn surface_kind(role: Role) -> SurfaceKind {
    match role {
        Role::Parenchyma => SurfaceKind::Parenchyma,
        Role::Tumor => SurfaceKind::Tumor,
        Role::Portal => SurfaceKind::Portal,
        Role::Hepatic => SurfaceKind::Hepatic,
        Role::Vessel => SurfaceKind::Vessel,
    }
}

impl Service {
    /// A service over `store`; sessions already stored are restored when first used.
    pub fn new(store: Arc<dyn SessionStore>, config: ServiceConfig) -> Self {
        Self {
            store,
            config,
            sessions: Mutex::new(HashMap::new()),
            volumes_scheduled: AtomicUsize::new(0),
        }
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
            },
        }
    }

    fn map(&self) -> Result<std::sync::MutexGuard<'_, HashMap<String, Arc<Session>>>> {
        self.sessions
            .lock()
            .map_err(|_| internal("session table lock poisoned"))
    }

    fn new_session(&self, rec: &SessionRecord, restored: bool) -> Arc<Session> {
        Arc::new(Session {
            id: rec.id.clone(),
            state: Arc::new(AsyncMutex::new(State {
                display_name: rec.display_name.clone(),
                created_ms: rec.created_ms,
                restored,
                loaded: None,
                models: None,
                version: 0,
                generation: 0,
            })),
            hub: Arc::new(Hub::new(self.config.ring, self.config.encode)),
            last_touch_ms: AtomicI64::new(rec.last_access_ms),
            volumes_scheduled: AtomicBool::new(false),
            last_edit: Mutex::new(std::time::Instant::now()),
            memory: std::sync::atomic::AtomicU64::new(0),
        })
    }

    /// The session `id`, from memory or the store; records the access.
    async fn session(&self, id: &str) -> Result<Arc<Session>> {
        let found = self.map()?.get(id).cloned();
        let session = match found {
            Some(s) => s,
            None => {
                let store = Arc::clone(&self.store);
                let key = id.to_owned();
                let rec = blocking(move || Ok(store.session(&key)?)).await?;
                let rec = rec.ok_or_else(|| SessionError::UnknownSession(id.to_owned()))?;
                let fresh = self.new_session(&rec, false);
                Arc::clone(self.map()?.entry(id.to_owned()).or_insert(fresh))
            }
        };
        let now = now_ms();
        if now - session.last_touch_ms.load(Ordering::Relaxed) >= TOUCH_EVERY_MS {
            session.last_touch_ms.store(now, Ordering::Relaxed);
            let store = Arc::clone(&self.store);
            let key = id.to_owned();
            // Off the request path: the access time only feeds idle expiry.
            tokio::spawn(blocking(move || {
                store
                    .touch(&key, now)
                    .inspect_err(|e| tracing::warn!(error = %e, "recording a session access"))?;
                Ok(())
            }));
        }
        Ok(session)
    }

    fn memory_in_use(&self) -> Result<u64> {
        Ok(self
            .map()?
            .values()
            .map(|s| s.memory.load(Ordering::Relaxed))
            .sum())
    }

    // ---- sessions -------------------------------------------------------------------------

    pub async fn create_session(&self, display_name: &str) -> Result<SessionInfo> {
        check_display_name(display_name)?;
        let store = Arc::clone(&self.store);
        let max = self.config.max_sessions;
        let now = now_ms();
        let rec = SessionRecord {
            id: uuid::Uuid::new_v4().simple().to_string(),
            display_name: display_name.to_owned(),
            created_ms: now,
            last_access_ms: now,
        };
        let stored = rec.clone();
        blocking(move || {
            let usage = store.usage()?;
            if usage.sessions >= max as u64 {
                return Err(SessionError::Quota(
                    Quota::Sessions,
                    format!("the server holds {} sessions, its limit", usage.sessions),
                ));
            }
            Ok(store.create_session(&stored)?)
        })
        .await?;
        let session = self.new_session(&rec, true);
        let loaded = {
            let mut map = self.map()?;
            map.insert(rec.id.clone(), Arc::clone(&session));
            map.len()
        };
        metrics::gauge!("resecta_sessions_loaded").set(loaded as f64);
        tracing::info!(session = %rec.id, "session created");
        self.describe(&session).await
    }

    pub async fn list_sessions(&self) -> Result<Vec<SessionInfo>> {
        let store = Arc::clone(&self.store);
        let records = blocking(move || Ok(store.sessions()?)).await?;
        let mut out = Vec::with_capacity(records.len());
        for rec in records {
            let loaded = self.map()?.get(&rec.id).cloned();
            match loaded {
                Some(s) => out.push(self.describe(&s).await?),
                None => out.push(self.describe_stored(rec).await?),
            }
        }
        Ok(out)
    }

    pub async fn get_session(&self, id: &str) -> Result<SessionInfo> {
        let s = self.session(id).await?;
        self.describe(&s).await
    }

    pub async fn delete_session(&self, id: &str) -> Result<()> {
        let store = Arc::clone(&self.store);
        let key = id.to_owned();
        let existed = blocking(move || Ok(store.delete_session(&key)?)).await?;
        let dropped = self.map()?.remove(id);
        if let Some(s) = &dropped {
            s.hub.close();
        }
        if !existed && dropped.is_none() {
            return Err(SessionError::UnknownSession(id.to_owned()));
        }
        tracing::info!(session = %id, "session deleted");
        Ok(())
    }

    /// Deletes sessions idle for longer than the configured expiry; returns how many.
    pub async fn expire_idle(&self) -> Result<usize> {
        let Some(expiry) = self.config.idle_expiry else {
            return Ok(0);
        };
        let before = now_ms() - i64::try_from(expiry.as_millis()).unwrap_or(i64::MAX);
        let store = Arc::clone(&self.store);
        let idle = blocking(move || Ok(store.idle_since(before)?)).await?;
        let mut n = 0;
        for id in idle {
            let recent = self
                .map()?
                .get(&id)
                .is_some_and(|s| s.last_touch_ms.load(Ordering::Relaxed) >= before);
            if !recent {
                self.delete_session(&id).await?;
                n += 1;
            }
        }
        Ok(n)
    }

    async fn describe(&self, s: &Arc<Session>) -> Result<SessionInfo> {
        let st = s.state.lock().await;
        if !st.restored {
            drop(st);
            let store = Arc::clone(&self.store);
            let key = s.id.clone();
            let rec = blocking(move || Ok(store.session(&key)?))
                .await?
                .ok_or_else(|| SessionError::UnknownSession(s.id.clone()))?;
            return self.describe_stored(rec).await;
        }
        Ok(SessionInfo {
            id: s.id.clone(),
            display_name: st.display_name.clone(),
            created_ms: st.created_ms,
            last_access_ms: s.last_touch_ms.load(Ordering::Relaxed),
            state: match (&st.loaded, &st.models) {
                (None, _) => SessionState::Empty,
                (Some(_), None) => SessionState::LabelMap,
                (Some(_), Some(_)) => SessionState::Ready,
            },
            plan_version: st.version,
            label_map: st.loaded.as_ref().map(|l| l.summary.clone()),
        })
    }

    /// A session not loaded in memory, from its record and small blobs only.
    async fn describe_stored(&self, rec: SessionRecord) -> Result<SessionInfo> {
        let store = Arc::clone(&self.store);
        let key = rec.id.clone();
        let (version, summary, models) = blocking(move || {
            let version = store.log_len(&key)?;
            let summary = store.blob(&key, SUMMARY_BLOB)?;
            let models = store.blob(&key, MODELS_BLOB)?.is_some();
            Ok((version, summary, models))
        })
        .await?;
        let summary: Option<LabelMapSummary> = summary
            .map(|b| serde_json::from_str(&b.meta_json))
            .transpose()
            .map_err(internal)?;
        Ok(SessionInfo {
            id: rec.id,
            display_name: rec.display_name,
            created_ms: rec.created_ms,
            last_access_ms: rec.last_access_ms,
            state: match (&summary, models) {
                (None, _) => SessionState::Empty,
                (Some(_), false) => SessionState::LabelMap,
                (Some(_), true) => SessionState::Ready,
            },
            plan_version: version,
            label_map: summary,
        })
    }

    /// Restores a session's label map, plan and models from the store (first use after a
    /// restart).
    async fn restore(&self, s: &Session, st: &mut State) -> Result<()> {
        if st.restored {
            return Ok(());
        }
        let store = Arc::clone(&self.store);
        let id = s.id.clone();
        let max_voxels = self.config.max_voxels;
        // The store on the blocking pool; decoding, replay and the planning set-up on the
        // background pool, as after an upload, so a restore never slows other sessions' edits.
        let stored = blocking(move || {
            let Some(rec) = store.session(&id)? else {
                return Err(SessionError::UnknownSession(id));
            };
            let version = store.log_len(&id)?;
            let labels = match store.blob(&id, LABELMAP_BLOB)? {
                None => None,
                Some(blob) => Some((blob, store.log(&id, 0)?)),
            };
            let models = store.blob(&id, MODELS_BLOB)?;
            Ok((rec, version, labels, models))
        })
        .await?;
        let restored = pools::run(Priority::Background, move || {
            let (rec, version, labels, models) = stored;
            let loaded = match labels {
                None => None,
                Some((blob, records)) => {
                    let (labels, roles) = labelmap::from_blob(&blob, max_voxels)?;
                    let mut base = Plan::new(roles.clone());
                    let mut entries = Vec::new();
                    for r in records {
                        match serde_json::from_str::<Record>(&r.json).map_err(internal)? {
                            Record::Reset { plan } => {
                                base = Plan::from_json(&plan)?;
                                entries.clear();
                            }
                            Record::Entry { entry } => entries.push(entry),
                        }
                    }
                    let anatomy = Arc::new(Anatomy::new(&labels, &roles)?);
                    let planner = Planner::resume(anatomy, History::replay(base, &entries)?)?;
                    let summary = labelmap::summary(&labels, &roles);
                    Some((Arc::new(labels), summary, planner))
                }
            };
            let models = models.map(|b| decode_models(&b)).transpose()?;
            Ok::<_, SessionError>((rec, version, loaded, models))
        })
        .await??;
        let (rec, version, loaded, models) = restored;
        st.display_name = rec.display_name;
        st.created_ms = rec.created_ms;
        st.version = version;
        st.restored = true;
        if let Some((labels, summary, planner)) = loaded {
            s.memory.store(
                labels.data().len() as u64 * BYTES_PER_VOXEL,
                Ordering::Relaxed,
            );
            s.hub.reset(version, planner.plan(), planner.states())?;
            st.loaded = Some(Loaded {
                labels,
                summary,
                planner: Some(planner),
                pending: None,
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

    /// The session, locked and restored.
    async fn open(&self, id: &str) -> Result<(Arc<Session>, tokio::sync::OwnedMutexGuard<State>)> {
        let s = self.session(id).await?;
        let mut st = Arc::clone(&s.state).lock_owned().await;
        self.restore(&s, &mut st).await?;
        Ok((s, st))
    }

    // ---- label maps and models --------------------------------------------------------------

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
        let need = labels.data().len() as u64 * BYTES_PER_VOXEL;
        let others = self.memory_in_use()? - s.memory.load(Ordering::Relaxed);
        if others + need > self.config.max_memory_bytes {
            return Err(SessionError::Quota(
                Quota::Memory,
                format!(
                    "a label map of {} voxels needs about {need} bytes; {} of the server's {} are in use",
                    labels.data().len(),
                    others,
                    self.config.max_memory_bytes
                ),
            ));
        }
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        let version = st.version;
        let (labels, summary, plan, version) = blocking(move || {
            let t = std::time::Instant::now();
            let summary = labelmap::summary(&labels, &roles);
            labelmap::check_roles(&roles, &summary.labels)?;
            let plan = Plan::new(roles.clone());
            let summary_blob = Blob {
                meta_json: serde_json::to_string(&summary).map_err(internal)?,
                data: Vec::new(),
            };
            store.put_blob(&key, LABELMAP_BLOB, &labelmap::to_blob(&labels, &roles)?)?;
            store.put_blob(&key, SUMMARY_BLOB, &summary_blob)?;
            store.delete_blob(&key, MODELS_BLOB)?;
            let record = serde_json::to_string(&Record::<LogEntry>::Reset {
                plan: plan.to_json()?,
            })
            .map_err(internal)?;
            let version = store.append(&key, version, &[record])?;
            tracing::debug!(session = %key, ms = t.elapsed().as_secs_f64() * 1e3, "label map stored");
            Ok((Arc::new(labels), summary, plan, version))
        })
        .await?;
        s.memory.store(need, Ordering::Relaxed);
        st.version = version;
        st.generation += 1;
        st.models = None;
        s.hub.reset(version, &plan, &BTreeMap::new())?;
        s.hub.publish_models(Vec::new())?;
        let pending = spawn_planner(Arc::clone(&labels), summary.roles.clone());
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

    /// The model options of `options`, or [`SessionError::Invalid`] naming the field out of
    /// range.
    fn recon_params(&self, options: &ReconOptions) -> Result<ModelOptions> {
        let depth = options.psr_depth.unwrap_or(self.config.psr_depth);
        if !(1..=10).contains(&depth) {
            return Err(SessionError::Invalid(format!(
                "psr_depth {depth} is outside 1..=10"
            )));
        }
        let defaults = McsdParams::default();
        let smoothing = options.smoothing.unwrap_or(defaults.smoothing);
        if !(0.0..=1.0).contains(&smoothing) {
            return Err(SessionError::Invalid(format!(
                "smoothing {smoothing} is outside [0, 1]"
            )));
        }
        let decimation = options.decimation.unwrap_or(defaults.decimation);
        if !(0.0..1.0).contains(&decimation) {
            return Err(SessionError::Invalid(format!(
                "decimation {decimation} is outside [0, 1)"
            )));
        }
        let parenchyma = match options.method {
            ReconMethod::Psr => ParenchymaMethod::Psr { depth },
            ReconMethod::Mcsd => ParenchymaMethod::Mcsd,
        };
        let model_options = ModelOptions {
            parenchyma,
            mcsd: McsdParams {
                smoothing,
                decimation,
            },
            split_components: options.split_components,
            min_component_mm3: options.min_component_mm3.unwrap_or(SPECK_MM3),
        };
        model_options
            .check()
            .map_err(|e| SessionError::Invalid(e.to_string()))?;
        Ok(model_options)
    }

    /// Builds the surface models (parenchyma by screened Poisson or, on request, MCSD; one MCSD
    /// model per vessel label and per tumour component, specks counted in `Done`) off the
    /// runtime with `options`, checked before anything starts.
    /// Events arrive on the returned channel; dropping it cancels the work.
    pub async fn reconstruct(
        self: &Arc<Self>,
        id: &str,
        options: ReconOptions,
    ) -> Result<mpsc::Receiver<Result<ReconstructEvent>>> {
        let model_options = self.recon_params(&options)?;
        let (s, st) = self.open(id).await?;
        let loaded = st.loaded.as_ref().ok_or_else(no_label_map)?;
        let labels = Arc::clone(&loaded.labels);
        let roles = loaded.summary.roles.clone();
        let generation = loaded.generation;
        drop(st);
        let (tx, rx) = mpsc::channel(64);
        let service = Arc::clone(self);
        tokio::spawn(async move {
            let started = std::time::Instant::now();
            let progress_tx = tx.clone();
            let built = pools::run(Priority::Background, move || {
                let mut done = 0usize;
                let mut progress = |name: &str| {
                    done += 1;
                    // The parenchyma (first, Poisson or the largest MCSD) dominates; the rest
                    // share what is left.
                    let fraction = 1.0 - 0.4 / done as Real;
                    let event = ReconstructEvent::Progress {
                        stage: format!("built {name}"),
                        fraction,
                    };
                    progress_tx.blocking_send(Ok(event)).is_ok()
                };
                patient_models(&labels, &roles, &model_options, &mut progress).map_err(
                    |e| match e {
                        ReconError::Cancelled => SessionError::Cancelled,
                        e @ (ReconError::NoLabels
                        | ReconError::LabelsAbsent { .. }
                        | ReconError::EmptyMask
                        | ReconError::InvalidParameter { .. }
                        | ReconError::Poisson(_)
                        | ReconError::Filter(_)
                        | ReconError::Isosurface(_)
                        | ReconError::Metrics(_)
                        | ReconError::Geometry(_)) => SessionError::Precondition(
                            Missing::Other,
                            format!("reconstruction: {e}"),
                        ),
                    },
                )
            })
            .await
            .and_then(|built| built);
            let result = match built {
                Ok(built) => {
                    let dropped = built
                        .dropped
                        .iter()
                        .map(|d| DroppedComponents {
                            kind: surface_kind(d.role),
                            count: d.components,
                            volume_ml: d.volume_mm3 / 1000.0,
                        })
                        .collect();
                    service
                        .install_models(&s, generation, built.models)
                        .await
                        .map(|infos| (infos, dropped))
                }
                Err(e) => Err(e),
            };
            let end = match result {
                Ok((infos, dropped)) => {
                    for model in &infos {
                        let _ = tx
                            .send(Ok(ReconstructEvent::Model {
                                model: model.clone(),
                            }))
                            .await;
                    }
                    Ok(ReconstructEvent::Done {
                        models: infos.len(),
                        time_ms: started.elapsed().as_secs_f64() * 1e3,
                        dropped,
                        min_component_mm3: model_options.min_component_mm3,
                    })
                }
                Err(e) => Err(e),
            };
            let _ = tx.send(end).await;
        });
        Ok(rx)
    }

    async fn install_models(
        &self,
        s: &Arc<Session>,
        generation: u64,
        built: Vec<resecta_recon::PatientModel>,
    ) -> Result<Vec<ModelInfo>> {
        let encode = self.config.encode;
        let models: Vec<Model> = built
            .into_iter()
            .map(|m| -> Result<Model> {
                let info = ModelInfo {
                    name: m.name(),
                    kind: surface_kind(m.role),
                    label: m.label.unwrap_or(0),
                    method: m.method.to_owned(),
                    triangles: m.mesh.triangles().len(),
                    vertices: m.mesh.vertices().len(),
                    volume_ml: m.mesh.signed_volume() / 1000.0,
                };
                let (topology, frame) = SurfaceFrame::from_trimesh(&m.mesh);
                let mesh = encode_mesh(&topology, &frame, &encode).map_err(internal)?;
                let surface = Surface::labelled(info.name.clone(), info.kind, info.label, mesh);
                Ok(Model {
                    info,
                    mesh: m.mesh,
                    surface,
                })
            })
            .collect::<Result<_>>()?;
        let mut st = s.state.lock().await;
        if st.generation != generation || st.loaded.is_none() {
            return Err(SessionError::Precondition(
                Missing::Other,
                "the label map changed during the reconstruction".into(),
            ));
        }
        let blob = encode_models(&models)?;
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        blocking(move || Ok(store.put_blob(&key, MODELS_BLOB, &blob)?)).await?;
        let infos = models.iter().map(|m| m.info.clone()).collect();
        s.hub
            .publish_models(models.iter().map(|m| m.surface.clone()).collect())?;
        st.models = Some(Arc::new(models));
        Ok(infos)
    }

    // ---- plan edits -----------------------------------------------------------------------

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
        if base_version != 0 && base_version != st.version {
            metrics::counter!("resecta_edits_rejected_total", "reason" => "stale_version")
                .increment(1);
            return Err(SessionError::StaleVersion {
                base: base_version,
                current: st.version,
            });
        }
        let version = st.version;
        let loaded = st.loaded.as_mut().ok_or_else(no_label_map)?;
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
            let r = apply_edit(&mut planner, op).and_then(|(change, record)| {
                match hub.publish_edit(version + 1, planner.plan(), planner.states(), &change) {
                    Ok(()) => Ok((change, record)),
                    Err(e) => {
                        roll_back(&mut planner, &id);
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
                    roll_back(&mut planner, &id);
                    planner
                })
                .await?;
                let shown = s.hub.reset(version, planner.plan(), planner.states());
                loaded.planner = Some(planner);
                shown?;
                return Err(e);
            }
        };
        debug_assert_eq!(new_version, version + 1, "one record appended");
        let resections = change
            .changed
            .iter()
            .filter_map(|name| {
                let resection = planner.plan().resection(name).ok()?.clone();
                let verdict = planner.state(name).ok().map(|s| s.verdict.clone());
                Some(ResectionStatus { resection, verdict })
            })
            .collect();
        let outcome = EditOutcome {
            plan_version: new_version,
            resections,
            removed: change.removed,
        };
        loaded.planner = Some(planner);
        st.version = new_version;
        drop(st);
        self.schedule_volumes(&s);
        metrics::histogram!("resecta_edit_seconds").record(started.elapsed().as_secs_f64());
        Ok(outcome)
    }

    /// Recomputes the volumes once the edits pause for `volumes_delay` (at the latest
    /// `volumes_max_interval` into a continuous burst) and publishes them. Volumetry holds the
    /// session, so it must not run between every two edits of a drag.
    fn schedule_volumes(self: &Arc<Self>, s: &Arc<Session>) {
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

    /// Replaces the plan by a `resecta-plan/1` document (its roles must be the label map's).
    pub async fn import_plan(&self, id: &str, json: &str, base_version: u64) -> Result<u64> {
        let plan = Plan::from_json(json)?;
        let (s, mut st) = self.open(id).await?;
        if base_version != 0 && base_version != st.version {
            return Err(SessionError::StaleVersion {
                base: base_version,
                current: st.version,
            });
        }
        let version = st.version;
        let loaded = loaded_mut(&mut st)?;
        if plan.roles != loaded.summary.roles {
            return Err(SessionError::Invalid(
                "the plan's role map differs from the loaded label map's".into(),
            ));
        }
        let anatomy = {
            let planner = loaded.ready().await?;
            planner.anatomy_shared()
        };
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        let (planner, new_version) = blocking(move || {
            let record = serde_json::to_string(&Record::<LogEntry>::Reset {
                plan: plan.to_json()?,
            })
            .map_err(internal)?;
            let planner = Planner::new(anatomy, plan)?;
            let v = store.append(&key, version, &[record])?;
            Ok((planner, v))
        })
        .await?;
        s.hub.reset(new_version, planner.plan(), planner.states())?;
        loaded.planner = Some(planner);
        st.version = new_version;
        Ok(new_version)
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
                    .map_err(|_| SessionError::ModelNotFound(name.to_owned()))?
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

    /// The session's event stream: from `since` when the server still holds what followed it,
    /// else from a snapshot.
    pub async fn watch(&self, id: &str, since: Option<u64>) -> Result<WatchStream> {
        let (s, _st) = self.open(id).await?;
        Ok(s.hub.subscribe(since))
    }
}

fn loaded_mut(st: &mut State) -> Result<&mut Loaded> {
    st.loaded.as_mut().ok_or_else(no_label_map)
}

/// Whether `op` is a small edit for a quick pool: a change to existing resections (no new
/// resection, resolution or target) while every surface has at most [`QUICK_SAMPLES`] samples.
fn is_quick(planner: &Planner, op: &EditOp) -> bool {
    let EditOp::Event { event } = op else {
        return false;
    };
    let reshapes = matches!(
        event,
        PlanEvent::AddResection { .. }
            | PlanEvent::SetResolution { .. }
            | PlanEvent::SetTarget { .. }
    );
    !reshapes
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
    let record = serde_json::to_string(&Record::Entry {
        entry: &change.entry,
    })
    .map_err(internal)?;
    Ok((change, record))
}

/// Rebuilds the planner without its last log entry (whose record could not be stored).
fn roll_back(planner: &mut Planner, id: &str) {
    let h = planner.history();
    let log = h.log();
    let restored = History::replay(h.base().clone(), &log[..log.len().saturating_sub(1)])
        .and_then(|h| Planner::resume(planner.anatomy_shared(), h));
    match restored {
        Ok(p) => *planner = p,
        Err(r) => {
            tracing::error!(session = %id, error = %r, "rollback after a storage failure failed")
        }
    }
}

/// Models as a blob: JSON infos with byte lengths, then the `RSMS` encodings back to back.
fn encode_models(models: &[Model]) -> Result<Blob> {
    let meta: Vec<(&ModelInfo, usize)> = models
        .iter()
        .map(|m| (&m.info, m.surface.mesh.len()))
        .collect();
    Ok(Blob {
        meta_json: serde_json::to_string(&meta).map_err(internal)?,
        data: models
            .iter()
            .flat_map(|m| m.surface.mesh.iter().copied())
            .collect(),
    })
}

fn decode_models(blob: &Blob) -> Result<Vec<Model>> {
    let meta: Vec<(ModelInfo, usize)> = serde_json::from_str(&blob.meta_json).map_err(internal)?;
    let mut at = 0usize;
    let mut out = Vec::with_capacity(meta.len());
    for (info, len) in meta {
        let bytes = at
            .checked_add(len)
            .and_then(|end| blob.data.get(at..end))
            .ok_or_else(|| internal("stored models are truncated"))?;
        at += len;
        let (topology, frame): (Topology, SurfaceFrame) =
            decode_mesh(bytes, &DecodeLimits::default()).map_err(internal)?;
        let vertices = frame
            .positions
            .iter()
            .map(|p| Vec3::new(Real::from(p[0]), Real::from(p[1]), Real::from(p[2])))
            .collect();
        let mesh = TriMesh::new(vertices, topology.triangles).map_err(internal)?;
        out.push(Model {
            surface: Surface::labelled(info.name.clone(), info.kind, info.label, bytes.to_vec()),
            info,
            mesh,
        });
    }
    Ok(out)
}
