//! A session's watch hub: the frames clients last saw per resection, the replay ring of events
//! and the notification of new ones; and the stream one client reads.
//!
//! Streams pull: a client that keeps up reads every event from the ring; one that falls behind
//! the ring (or reconnects from an unknown sequence) gets a fresh snapshot instead. Memory is
//! bounded by the ring, never by slow clients.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};

use resecta_delta::{
    EncodeOptions, ReplayRing, Since, SurfaceFrame, Topology, encode_delta, encode_mesh,
};
use resecta_plan::{Change, Plan, Resection, ResectionState, Verdict, VolumeReport};
use tokio::sync::watch;

use crate::api::{ReplicaAddress, Surface, SurfaceKind, SurfaceUpdate, WatchBody, WatchEvent};
use crate::budget::Reservation;
use crate::error::{Result, SessionError};

/// Replay ring bounds per session.
#[derive(Debug, Clone, Copy)]
pub struct RingBounds {
    pub items: usize,
    pub bytes: usize,
}

#[derive(Debug)]
struct Shown {
    topology: Arc<Topology>,
    frame: SurfaceFrame,
}

#[derive(Debug)]
struct HubState {
    seq: u64,
    plan_version: u64,
    ring: ReplayRing<Arc<WatchEvent>>,
    shown: BTreeMap<String, Shown>,
    verdicts: BTreeMap<String, Verdict>,
    params: BTreeMap<String, Resection>,
    models: Arc<Vec<Surface>>,
    volumes: Option<VolumeReport>,
}

/// One session's watch state.
#[derive(Debug)]
pub struct Hub {
    state: Mutex<HubState>,
    notify: watch::Sender<u64>,
    encode: EncodeOptions,
    /// Set when the session moved to another replica: its streams end with `Elsewhere`.
    moved: Mutex<Option<Option<ReplicaAddress>>>,
}

fn frame_of(s: &ResectionState) -> SurfaceFrame {
    let f = |v: &resecta_geom::Vec3| [v.x as f32, v.y as f32, v.z as f32];
    SurfaceFrame {
        positions: s.surface.points().iter().map(f).collect(),
        normals: s.surface.normals().iter().map(f).collect(),
        margins: s.margins.distance.iter().map(|&d| d as f32).collect(),
        classes: s.margins.class.iter().map(|&c| c as u8).collect(),
    }
}

fn topology_of(s: &ResectionState) -> Topology {
    let [ru, rv] = s.surface.resolution();
    Topology {
        triangles: resecta_bezier::grid_triangles(ru, rv),
    }
}

/// Where a new hub's sequence numbers start: the time in milliseconds × 1024, so the numbers of
/// a session's hub after a restart (or a reload) are above every number its earlier hub handed
/// out (at under 1024 events per millisecond of its life), and a client resuming with one of
/// those gets a fresh snapshot, never deltas against another history. Below 2⁵³ (exact in
/// JSON) until the year 2248.
fn first_seq() -> u64 {
    let ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    u64::try_from(ms.saturating_mul(1024)).unwrap_or(u64::MAX / 2)
}

impl Hub {
    pub fn new(bounds: RingBounds, encode: EncodeOptions) -> Self {
        let first = first_seq();
        let (notify, _) = watch::channel(first);
        let mut ring = ReplayRing::new(bounds.items, bounds.bytes);
        ring.reset(first);
        Self {
            state: Mutex::new(HubState {
                seq: first,
                plan_version: 0,
                ring,
                shown: BTreeMap::new(),
                verdicts: BTreeMap::new(),
                params: BTreeMap::new(),
                models: Arc::new(Vec::new()),
                volumes: None,
            }),
            notify,
            encode,
            moved: Mutex::new(None),
        }
    }

    fn lock(&self) -> Result<MutexGuard<'_, HubState>> {
        self.state
            .lock()
            .map_err(|_| SessionError::Internal("watch hub lock poisoned".into()))
    }

    fn push(&self, st: &mut HubState, body: WatchBody) -> Result<()> {
        st.seq += 1;
        let event = Arc::new(WatchEvent {
            seq: st.seq,
            plan_version: st.plan_version,
            body,
        });
        let weight = event.weight();
        st.ring
            .push(st.seq, event, weight)
            .map_err(|e| SessionError::Internal(e.to_string()))?;
        self.notify.send_replace(st.seq);
        Ok(())
    }

    /// Publishes the resections a step changed (deltas where the topology is unchanged, whole
    /// meshes otherwise) and removed.
    pub fn publish_edit(
        &self,
        plan_version: u64,
        plan: &Plan,
        states: &BTreeMap<String, ResectionState>,
        change: &Change,
    ) -> Result<()> {
        let mut st = self.lock()?;
        st.plan_version = plan_version;
        let mut updates = Vec::new();
        let mut removed = Vec::new();
        let mut verdicts = BTreeMap::new();
        let mut params = BTreeMap::new();
        for name in change.changed.iter().chain(&change.removed) {
            let (Some(state), Ok(r)) = (states.get(name), plan.resection(name)) else {
                if st.shown.remove(name).is_some() {
                    st.verdicts.remove(name);
                    st.params.remove(name);
                    removed.push(name.clone());
                }
                continue;
            };
            params.insert(name.clone(), r.clone());
            st.params.insert(name.clone(), r.clone());
            let frame = frame_of(state);
            let (bytes, full, topology) = match st.shown.get(name) {
                Some(old) if old.frame.positions.len() == frame.positions.len() => {
                    let d = encode_delta(&old.frame, &frame, &self.encode)
                        .map_err(|e| SessionError::Internal(e.to_string()))?;
                    (d, false, Arc::clone(&old.topology))
                }
                _ => {
                    let t = Arc::new(topology_of(state));
                    let m = encode_mesh(&t, &frame, &self.encode)
                        .map_err(|e| SessionError::Internal(e.to_string()))?;
                    (m, true, t)
                }
            };
            updates.push(SurfaceUpdate {
                name: name.clone(),
                full,
                bytes,
            });
            verdicts.insert(name.clone(), state.verdict.clone());
            st.verdicts.insert(name.clone(), state.verdict.clone());
            st.shown.insert(name.clone(), Shown { topology, frame });
        }
        self.push(
            &mut st,
            WatchBody::Delta {
                updates,
                removed,
                verdicts,
                resections: params,
            },
        )
    }

    /// Replaces every resection surface (after a label-map load, an import or a restart): the
    /// ring restarts, so watching clients take a snapshot.
    pub fn reset(
        &self,
        plan_version: u64,
        plan: &Plan,
        states: &BTreeMap<String, ResectionState>,
    ) -> Result<()> {
        let mut st = self.lock()?;
        st.params = plan
            .resections
            .iter()
            .map(|r| (r.name.clone(), r.clone()))
            .collect();
        st.plan_version = plan_version;
        st.shown = states
            .iter()
            .map(|(n, s)| {
                let shown = Shown {
                    topology: Arc::new(topology_of(s)),
                    frame: frame_of(s),
                };
                (n.clone(), shown)
            })
            .collect();
        st.verdicts = states
            .iter()
            .map(|(n, s)| (n.clone(), s.verdict.clone()))
            .collect();
        st.volumes = None;
        st.seq += 1;
        let seq = st.seq;
        st.ring.reset(seq);
        self.notify.send_replace(seq);
        Ok(())
    }

    pub fn publish_models(&self, models: Vec<Surface>) -> Result<()> {
        let mut st = self.lock()?;
        st.models = Arc::new(models.clone());
        self.push(&mut st, WatchBody::Models { models })
    }

    pub fn publish_volumes(&self, plan_version: u64, volumes: VolumeReport) -> Result<()> {
        let mut st = self.lock()?;
        if plan_version != st.plan_version {
            return Ok(()); // stale: a newer edit will bring its own
        }
        st.volumes = Some(volumes.clone());
        self.push(&mut st, WatchBody::Volumes { volumes })
    }

    /// The whole current picture as one event at the current sequence number.
    pub fn snapshot(&self) -> Result<WatchEvent> {
        let st = self.lock()?;
        let resections = st
            .shown
            .iter()
            .map(|(name, s)| {
                Ok(Surface::new(
                    name.clone(),
                    SurfaceKind::Resection,
                    encode_mesh(&s.topology, &s.frame, &self.encode)
                        .map_err(|e| SessionError::Internal(e.to_string()))?,
                ))
            })
            .collect::<Result<_>>()?;
        Ok(WatchEvent {
            seq: st.seq,
            plan_version: st.plan_version,
            body: WatchBody::Snapshot {
                models: st.models.as_ref().clone(),
                resections,
                verdicts: st.verdicts.clone(),
                resection_params: st.params.clone(),
                volumes: st.volumes.clone(),
            },
        })
    }

    fn since(&self, seq: u64) -> Result<Since<Arc<WatchEvent>>> {
        Ok(self.lock()?.ring.since(seq))
    }

    /// A stream for one client: from `since` if the ring still holds what follows it, else from
    /// a snapshot.
    /// `memory` is what the stream's snapshot holds of the memory budget, given back with it.
    pub(crate) fn subscribe(
        self: &Arc<Self>,
        since: Option<u64>,
        memory: Option<Reservation>,
    ) -> WatchStream {
        metrics::gauge!("resecta_watchers").increment(1.0);
        WatchStream {
            hub: Arc::clone(self),
            rx: self.notify.subscribe(),
            cursor: since,
            pending: VecDeque::new(),
            ended: false,
            _memory: memory,
        }
    }

    /// Streams open on this hub.
    pub fn watchers(&self) -> usize {
        self.notify.receiver_count()
    }

    /// Ends every stream (the session is gone).
    pub fn close(&self) {
        self.notify.send_replace(u64::MAX);
    }

    /// Ends every stream with [`SessionError::Elsewhere`]: another replica holds the session
    /// now (at `at`, when known).
    pub fn close_moved(&self, at: Option<ReplicaAddress>) {
        if let Ok(mut m) = self.moved.lock() {
            *m = Some(at);
        }
        self.close();
    }

    /// Why streams end: `Elsewhere` if the session moved, else `None` (deleted, stopping).
    fn end(&self) -> Option<SessionError> {
        let moved = self.moved.lock().ok()?.clone()?;
        Some(SessionError::Elsewhere(moved))
    }
}

/// One client's view of a session's events.
#[derive(Debug)]
pub struct WatchStream {
    hub: Arc<Hub>,
    rx: watch::Receiver<u64>,
    /// Last sequence number delivered (`None`: a snapshot is due).
    cursor: Option<u64>,
    pending: VecDeque<Arc<WatchEvent>>,
    /// The stream has ended (after its last event or error).
    ended: bool,
    _memory: Option<Reservation>,
}

impl Drop for WatchStream {
    fn drop(&mut self) {
        metrics::gauge!("resecta_watchers").decrement(1.0);
    }
}

impl WatchStream {
    /// The next event; `None` when the session is deleted or the server stops.
    pub async fn next(&mut self) -> Option<Result<Arc<WatchEvent>>> {
        loop {
            if let Some(e) = self.pending.pop_front() {
                self.cursor = Some(e.seq);
                return Some(Ok(e));
            }
            if *self.rx.borrow_and_update() == u64::MAX || self.ended {
                return self.finish();
            }
            let Some(cursor) = self.cursor else {
                return Some(self.hub.snapshot().map(|s| {
                    self.cursor = Some(s.seq);
                    Arc::new(s)
                }));
            };
            match self.hub.since(cursor) {
                Err(e) => return Some(Err(e)),
                Ok(Since::Gap) => self.cursor = None,
                Ok(Since::Items(items)) if !items.is_empty() => {
                    self.pending.extend(items.into_iter().map(|(_, e)| e));
                }
                Ok(Since::Items(_)) => {
                    if self.rx.changed().await.is_err() {
                        return self.finish();
                    }
                }
            }
        }
    }

    /// The end of the stream: once, the reason the session moved, if it did.
    fn finish(&mut self) -> Option<Result<Arc<WatchEvent>>> {
        if std::mem::replace(&mut self.ended, true) {
            return None;
        }
        self.hub.end().map(Err)
    }
}
