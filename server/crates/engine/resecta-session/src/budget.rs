//! The memory budget: one admission controller for everything a session or a call holds in
//! memory. Each session carries standing charges (its label map with the planner's anatomy and
//! replay ring, its plan's surfaces, its models); work in flight (an upload being received, a
//! plan being computed, a reconstruction, a watcher's snapshot) holds a [`Reservation`]. A
//! reservation is checked and taken in one locked step before the work starts, so parallel
//! requests never pass the budget together, and it is given back on every path (dropped) or
//! settled as the session's new standing charge. The estimates are calibrated against the
//! server's resident memory (`docs/security.md`).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

use resecta_plan::{ComputeEngine, Plan};

use crate::error::{Quota, Result, SessionError};
use crate::support::internal;

/// Estimated resident bytes per voxel of a loaded label map: the labels, the planner's liver
/// masks and distance structures, and the volumetry's liver voxels.
pub(crate) const BYTES_PER_VOXEL: u64 = 8;
/// Estimated resident bytes per surface sample of a resection: the planner's surface, normals,
/// distances, classes and inside levels, the volumetry's cut input and the watch hub's last
/// frame and topology.
pub(crate) const BYTES_PER_SAMPLE: u64 = 256;
/// Fixed bytes of one resection (control net, verdict, names, caches).
const BYTES_PER_RESECTION: u64 = 64 << 10;
/// A watcher's snapshot (the encoded surfaces) and its copy on the wire, per surface sample.
const WATCH_BYTES_PER_SAMPLE: u64 = 128;
/// A watcher's fixed bytes (stream state, models' encoded meshes are shared).
const WATCH_BYTES: u64 = 256 << 10;
/// Bytes per node of the screened Poisson reconstruction's finest grid (multigrid levels,
/// right-hand side, solution, iso-surface work).
const BYTES_PER_PSR_NODE: u64 = 16;

/// The standing charges of a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Charge {
    /// The label map with its anatomy and the session's replay ring.
    LabelMap,
    /// The plan's resection surfaces.
    Plan,
    /// The reconstructed models.
    Models,
}

impl Charge {
    fn index(self) -> usize {
        self as usize
    }
}

/// What a reservation is for (named in the refusal).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Use {
    LabelMap,
    Plan,
    Reconstruction,
    PointCloud,
    Upload,
    Watcher,
}

impl Use {
    fn describe(self) -> &'static str {
        match self {
            Use::LabelMap => "the label map",
            Use::Plan => "the plan's surfaces",
            Use::Reconstruction => "the reconstruction",
            Use::PointCloud => "the point cloud's reconstruction",
            Use::Upload => "the upload",
            Use::Watcher => "the watch stream",
        }
    }
}

/// The server's memory budget and what is charged against it.
#[derive(Debug)]
pub(crate) struct Budget {
    max: u64,
    state: Mutex<Charged>,
}

#[derive(Debug, Default)]
struct Charged {
    sessions: HashMap<String, [u64; 3]>,
    /// Bytes of reservations not (yet) settled.
    reserved: u64,
}

impl Charged {
    fn total(&self) -> u64 {
        self.sessions
            .values()
            .flatten()
            .fold(self.reserved, |a, &b| a.saturating_add(b))
    }
}

/// Bytes of the budget held for work in flight: given back when dropped, or settled as a
/// session's standing charge by [`Reservation::settle`].
#[must_use]
#[derive(Debug)]
pub(crate) struct Reservation {
    budget: Arc<Budget>,
    what: Use,
    bytes: u64,
    /// The standing charge this reservation replaces while held (its bytes are not counted
    /// twice when the check is made).
    replaces: Option<(String, Charge)>,
}

impl Budget {
    pub(crate) fn new(max: u64) -> Arc<Self> {
        Arc::new(Self {
            max,
            state: Mutex::new(Charged::default()),
        })
    }

    fn lock(&self) -> Result<MutexGuard<'_, Charged>> {
        self.state
            .lock()
            .map_err(|_| internal("memory budget lock poisoned"))
    }

    pub(crate) fn max(&self) -> u64 {
        self.max
    }

    /// Bytes charged and reserved.
    pub(crate) fn in_use(&self) -> Result<u64> {
        Ok(self.lock()?.total())
    }

    /// Reserves `bytes` for `what`, or refuses with [`Quota::Memory`].
    pub(crate) fn reserve(self: &Arc<Self>, what: Use, bytes: u64) -> Result<Reservation> {
        self.take(what, bytes, None)
    }

    /// Reserves `bytes` for session `id`'s new `charge`, which will replace its present one:
    /// the present one is not counted in the check.
    pub(crate) fn reserve_replacing(
        self: &Arc<Self>,
        what: Use,
        bytes: u64,
        id: &str,
        charge: Charge,
    ) -> Result<Reservation> {
        self.take(what, bytes, Some((id.to_owned(), charge)))
    }

    fn take(
        self: &Arc<Self>,
        what: Use,
        bytes: u64,
        replaces: Option<(String, Charge)>,
    ) -> Result<Reservation> {
        let mut st = self.lock()?;
        let own = replaces.as_ref().map_or(0, |(id, c)| {
            st.sessions.get(id).map_or(0, |charges| charges[c.index()])
        });
        let others = st.total() - own;
        if others.saturating_add(bytes) > self.max {
            return Err(refusal(what, bytes, others, self.max));
        }
        st.reserved += bytes;
        Ok(Reservation {
            budget: Arc::clone(self),
            what,
            bytes,
            replaces,
        })
    }

    /// Sets a standing charge without a check (a session restored for a call is never refused;
    /// the background restorer checks first).
    pub(crate) fn set(&self, id: &str, charge: Charge, bytes: u64) -> Result<()> {
        self.lock()?.sessions.entry(id.to_owned()).or_default()[charge.index()] = bytes;
        Ok(())
    }

    /// Drops every standing charge of session `id`.
    pub(crate) fn release(&self, id: &str) -> Result<()> {
        self.lock()?.sessions.remove(id);
        Ok(())
    }
}

fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1 << 20))
}

fn refusal(what: Use, bytes: u64, others: u64, max: u64) -> SessionError {
    SessionError::Quota(
        Quota::Memory,
        format!(
            "{} needs about {}; {} of the server's memory budget of {} are in use",
            what.describe(),
            mib(bytes),
            mib(others),
            mib(max)
        ),
    )
}

impl Reservation {
    pub(crate) fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Reserves `extra` bytes more (an upload as it arrives), or refuses with
    /// [`Quota::Memory`] and keeps what it held.
    pub(crate) fn grow(&mut self, extra: u64) -> Result<()> {
        let mut st = self.budget.lock()?;
        let own = self.replaces.as_ref().map_or(0, |(id, c)| {
            st.sessions.get(id).map_or(0, |charges| charges[c.index()])
        });
        let others = st.total() - own - self.bytes;
        let bytes = self.bytes.saturating_add(extra);
        if others.saturating_add(bytes) > self.budget.max {
            return Err(refusal(self.what, bytes, others, self.budget.max));
        }
        st.reserved += extra;
        self.bytes = bytes;
        Ok(())
    }

    /// The work is done: `bytes` (at most what was reserved, e.g. a plan's surfaces without
    /// the transient of computing them) become session `id`'s `charge`, replacing the
    /// present one.
    pub(crate) fn settle(self, id: &str, charge: Charge, bytes: u64) -> Result<()> {
        let mut st = self.budget.lock()?;
        st.sessions.entry(id.to_owned()).or_default()[charge.index()] = bytes;
        Ok(())
        // `self` drops here, after the lock: the reservation is given back.
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if let Ok(mut st) = self.budget.state.lock() {
            st.reserved = st.reserved.saturating_sub(self.bytes);
        }
    }
}

/// The memory an upload being received holds: it grows as the bytes arrive, is refused beyond
/// the per-upload limit or the memory budget, and is given back when dropped (once the upload
/// has been decoded, or abandoned). A stalled upload holds only what it has sent.
#[derive(Debug)]
pub struct UploadMemory {
    reservation: Reservation,
    max_bytes: u64,
}

impl UploadMemory {
    pub(crate) fn new(budget: &Arc<Budget>, max_bytes: u64) -> Result<Self> {
        Ok(Self {
            reservation: budget.reserve(Use::Upload, 0)?,
            max_bytes,
        })
    }

    /// Bytes received so far.
    pub fn bytes(&self) -> u64 {
        self.reservation.bytes()
    }

    /// `bytes` more have arrived (or are announced, e.g. by a `Content-Length`).
    pub fn grow(&mut self, bytes: u64) -> Result<()> {
        let total = self.reservation.bytes().saturating_add(bytes);
        if total > self.max_bytes {
            return Err(SessionError::Quota(
                Quota::UploadBytes,
                format!(
                    "upload of more than {} bytes exceeds the limit of {} bytes",
                    total - 1,
                    self.max_bytes
                ),
            ));
        }
        self.reservation.grow(bytes)
    }
}

/// What a loaded label map of `voxels` voxels holds, with a replay ring of `ring_bytes`, for a
/// planner computing with `engine`.
pub(crate) fn label_map_bytes(voxels: u64, ring_bytes: u64, engine: &ComputeEngine) -> u64 {
    voxels
        .saturating_mul(BYTES_PER_VOXEL + engine.host_bytes_per_voxel)
        .saturating_add(ring_bytes)
}

/// Surface samples of a plan's resections.
pub(crate) fn plan_samples(plan: &Plan) -> u64 {
    plan.resections
        .iter()
        .map(|r| (r.resolution[0] * r.resolution[1]) as u64)
        .sum()
}

/// What a plan's resection states hold, with room to recompute its largest one beside the
/// old state (an edit that moves a surface needs no reservation of its own, so a drag is never
/// refused).
pub(crate) fn plan_bytes(plan: &Plan, per_sample: u64) -> u64 {
    let largest = plan
        .resections
        .iter()
        .map(|r| (r.resolution[0] * r.resolution[1]) as u64)
        .max()
        .unwrap_or(0);
    (plan_samples(plan) + largest) * per_sample + plan.resections.len() as u64 * BYTES_PER_RESECTION
}

/// Bytes per surface sample of a planner computing with `engine`.
pub(crate) fn sample_bytes(engine: &ComputeEngine) -> u64 {
    BYTES_PER_SAMPLE + engine.host_bytes_per_sample
}

/// What computing the change from `before` to `after` holds at its peak: the plan after it,
/// plus the new states of the resections it changes, which are built beside the old ones.
pub(crate) fn plan_change_bytes(after: &Plan, changed: &[String], per_sample: u64) -> u64 {
    let computed: u64 = after
        .resections
        .iter()
        .filter(|r| changed.contains(&r.name))
        .map(|r| (r.resolution[0] * r.resolution[1]) as u64 * per_sample)
        .sum();
    plan_bytes(after, per_sample) + computed
}

/// What adding a resection at `resolution` holds while computed.
pub(crate) fn added_resection_bytes(resolution: [usize; 2], per_sample: u64) -> u64 {
    2 * (resolution[0] * resolution[1]) as u64 * per_sample + BYTES_PER_RESECTION
}

/// What one watcher's snapshot of surfaces with `samples` samples holds.
pub(crate) fn watcher_bytes(samples: u64) -> u64 {
    WATCH_BYTES + samples * WATCH_BYTES_PER_SAMPLE
}

/// What a reconstruction on a label map of `voxels` voxels at Poisson depth `depth` holds at
/// its peak: the finest grid of (2^depth + 1)³ nodes and masks of the label map.
pub(crate) fn reconstruction_bytes(voxels: u64, depth: u32) -> u64 {
    let side = (1u64 << depth.min(20)) + 1;
    side.saturating_pow(3)
        .saturating_mul(BYTES_PER_PSR_NODE)
        .saturating_add(voxels.saturating_mul(BYTES_PER_VOXEL))
}

/// Bytes per point of a cloud while its normals and areas are computed (positions, normals and
/// areas copied, the k-d tree, the merged duplicates) besides its neighbour lists.
const BYTES_PER_CLOUD_POINT: u64 = 256;
/// Bytes per neighbour of a point (index and distance, both directions of the graph).
const BYTES_PER_CLOUD_NEIGHBOUR: u64 = 32;
/// Bytes of the surface per face-cell of the finest grid (a closed surface crossing the whole
/// bounding cube cuts about 6·4^d cells; vertices, normals, triangles and the encoded copy).
const BYTES_PER_SURFACE_CELL: u64 = 256;

/// What reconstructing a cloud of `points` points with `neighbours` neighbours at depth `depth`
/// holds at its peak: the point work, the Poisson grid hierarchy
/// ([`resecta_poisson::bytes_needed`]) and the surface.
pub(crate) fn cloud_bytes(points: usize, depth: u32, neighbours: usize) -> u64 {
    // Depths are checked (at most the solver's 10) before this; beyond 12 the grid alone
    // would not fit any budget, and the estimate saturates.
    if depth > resecta_poisson::MAX_DEPTH + 2 {
        return u64::MAX;
    }
    let points = points as u64;
    let per_point = BYTES_PER_CLOUD_POINT
        .saturating_add((neighbours as u64).saturating_mul(BYTES_PER_CLOUD_NEIGHBOUR));
    let cells = 6u64 << (2 * depth);
    resecta_poisson::bytes_needed(depth, 0)
        .saturating_add(points.saturating_mul(per_point))
        .saturating_add(cells.saturating_mul(BYTES_PER_SURFACE_CELL))
}

#[cfg(test)]
pub(crate) mod tests {
    use std::sync::Barrier;

    use super::*;

    /// How many of `threads` threads, started together, get `true` from `try_take(i)`.
    pub(crate) fn granted_in_parallel(
        threads: usize,
        try_take: impl Fn(usize) -> bool + Sync,
    ) -> usize {
        let barrier = Barrier::new(threads);
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|i| {
                    let (barrier, try_take) = (&barrier, &try_take);
                    scope.spawn(move || {
                        barrier.wait();
                        try_take(i)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap())
                .filter(|&ok| ok)
                .count()
        })
    }

    #[test]
    fn parallel_reservations_never_pass_the_budget() {
        const THREADS: usize = 32;
        let budget = Budget::new(1000);
        let granted = granted_in_parallel(THREADS, |i| {
            budget
                .reserve_replacing(Use::LabelMap, 300, &i.to_string(), Charge::LabelMap)
                .and_then(|r| r.settle(&i.to_string(), Charge::LabelMap, 300))
                .is_ok()
        });
        assert_eq!(granted, 3);
        assert_eq!(budget.in_use().unwrap(), 900);
        // Transient reservations race the same way.
        let budget = Budget::new(1000);
        let held = Mutex::new(Vec::new());
        let granted = granted_in_parallel(THREADS, |_| match budget.reserve(Use::Upload, 150) {
            Ok(r) => {
                held.lock().unwrap().push(r);
                true
            }
            Err(_) => false,
        });
        assert_eq!(granted, 6);
        drop(held);
        assert_eq!(budget.in_use().unwrap(), 0, "every reservation given back");
    }

    #[test]
    fn charges_are_per_session_and_kind_and_freed_with_the_session() {
        let budget = Budget::new(1000);
        budget.set("a", Charge::LabelMap, 500).unwrap();
        budget.set("a", Charge::Plan, 100).unwrap();
        // A reservation counts while held and is given back when dropped.
        let r = budget.reserve(Use::Watcher, 400).unwrap();
        assert_eq!(budget.in_use().unwrap(), 1000);
        let e = budget.reserve(Use::Plan, 1).unwrap_err();
        assert!(matches!(e, SessionError::Quota(Quota::Memory, _)), "{e}");
        assert!(e.to_string().contains("the plan's surfaces"), "{e}");
        drop(r);
        assert_eq!(budget.in_use().unwrap(), 600);
        // A new plan replaces the session's own: only the rest counts in the check, and the
        // settled charge replaces the old one.
        let r = budget
            .reserve_replacing(Use::Plan, 500, "a", Charge::Plan)
            .unwrap();
        r.settle("a", Charge::Plan, 450).unwrap();
        assert_eq!(budget.in_use().unwrap(), 950);
        assert!(
            budget
                .reserve_replacing(Use::Plan, 600, "a", Charge::Plan)
                .is_err()
        );
        budget.release("a").unwrap();
        assert_eq!(budget.in_use().unwrap(), 0);
    }

    #[test]
    fn a_growing_reservation_stops_at_the_budget_and_keeps_what_it_held() {
        let budget = Budget::new(1000);
        let other = budget.reserve(Use::Upload, 300).unwrap();
        let mut upload = budget.reserve(Use::Upload, 0).unwrap();
        upload.grow(400).unwrap();
        upload.grow(300).unwrap();
        assert_eq!(upload.bytes(), 700);
        let e = upload.grow(1).unwrap_err();
        assert!(e.to_string().contains("the upload needs about"), "{e}");
        assert_eq!(upload.bytes(), 700);
        assert_eq!(budget.in_use().unwrap(), 1000);
        drop(other);
        upload.grow(300).unwrap();
        drop(upload);
        assert_eq!(budget.in_use().unwrap(), 0);
    }

    #[test]
    fn estimates_grow_with_what_they_hold() {
        assert_eq!(label_map_bytes(1000, 64, &ComputeEngine::cpu()), 8064);
        let mut gpu = ComputeEngine::cpu();
        gpu.host_bytes_per_voxel = 16;
        assert_eq!(label_map_bytes(1000, 64, &gpu), 24064);
        assert!(reconstruction_bytes(0, 8) > 7 * reconstruction_bytes(0, 7));
        assert_eq!(
            reconstruction_bytes(1, 40),
            u64::MAX,
            "saturates, never wraps"
        );
        assert!(watcher_bytes(250_000) > watcher_bytes(0));
        // A cloud: the grid dominates at depth 8, the points at a million.
        assert!(cloud_bytes(1000, 8, 10) > 5 * cloud_bytes(1000, 7, 10));
        assert!(cloud_bytes(1_000_000, 5, 10) > 500_000_000);
        assert!(cloud_bytes(1000, 5, 64) > cloud_bytes(1000, 5, 10));
        assert_eq!(cloud_bytes(usize::MAX, 8, 64), u64::MAX, "saturates");
        assert_eq!(cloud_bytes(10, 40, 10), u64::MAX, "never overflows");
    }
}
