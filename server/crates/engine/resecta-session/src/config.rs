//! Limits and tuning of the operation layer.

use std::time::Duration;

use resecta_delta::EncodeOptions;
use resecta_plan::ComputeEngine;
use resecta_recon::PoissonSolver;

use crate::api::ComputeInfo;
use crate::watch::RingBounds;

/// One replica of several sharing a store: who it is, and how long its session leases last
/// without renewal (renewed every third of it).
#[derive(Debug, Clone)]
pub struct ReplicaConfig {
    pub replica: resecta_store::Replica,
    pub lease: Duration,
}

impl ReplicaConfig {
    /// The default lease: a dead replica's sessions move after at most this long.
    pub const DEFAULT_LEASE: Duration = Duration::from_secs(3);
}

/// Limits and tuning of a [`Service`](crate::Service).
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    pub max_sessions: usize,
    /// Voxels per label map.
    pub max_voxels: u64,
    /// Bytes of one upload (raw data or file).
    pub max_upload_bytes: u64,
    /// Estimated memory of all loaded sessions together.
    pub max_memory_bytes: u64,
    /// Sessions untouched for this long are deleted by
    /// [`Service::expire_idle`](crate::Service::expire_idle).
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
    /// Most points of one point cloud ([`Service::reconstruct_points`](crate::Service::reconstruct_points)).
    pub max_cloud_points: usize,
    /// Largest PSR depth of a point cloud (depths are `1..=max_cloud_depth`; at most 10, the
    /// solver's): the dense grid of depth d holds (2^d + 1)³ nodes.
    pub max_cloud_depth: u32,
    /// Capabilities reported by [`Service::info`](crate::Service::info) (the edges add theirs,
    /// e.g. "tls").
    pub capabilities: Vec<String>,
    /// Makes the surface evaluators and sample probes of every session's planner (the CPU's by
    /// default); a session whose device fails continues on the CPU.
    pub compute_engine: ComputeEngine,
    /// What [`Service::info`](crate::Service::info) reports of `compute_engine`.
    pub compute: ComputeInfo,
    /// Solves the Poisson systems of reconstructions and point clouds (the CPU's by default);
    /// a device failure reruns that reconstruction on the CPU.
    pub poisson_solver: PoissonSolver,
    /// Set when several replicas share the store: sessions are then held under leases
    /// (`ownership`), one replica at a time.
    pub replica: Option<ReplicaConfig>,
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
            max_cloud_points: 1_000_000,
            max_cloud_depth: 8,
            capabilities: Vec::new(),
            compute_engine: ComputeEngine::cpu(),
            compute: ComputeInfo::default(),
            poisson_solver: PoissonSolver::cpu(),
            replica: None,
        }
    }
}
