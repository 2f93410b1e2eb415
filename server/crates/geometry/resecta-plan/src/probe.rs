//! The seam between the planner and an accelerator that measures a resection's samples where
//! its surface is evaluated: [`SampleProbe`] (the surface, then every sample's inside level and
//! exact tumour distance, one device round trip when both run on one device), [`ProbeEngine`]
//! (makes one per resection and target) and [`ComputeEngine`] (what a planner is given: its
//! surface engine and, optionally, a probe engine and its volumetry's accelerator). Without a probe engine the planner measures
//! on the CPU (inside levels by lookup, distances through `resecta_margin::evaluate_reusing`).

use std::sync::Arc;

use resecta_bezier::{BezierError, SurfaceEngine, SurfaceEvaluator, SurfaceGrid};
use resecta_geom::Real;
use resecta_volumetry::AcceleratorFactory;

use crate::anatomy::Anatomy;
use crate::engine::TargetModel;

/// Measures one resection's samples against its anatomy and target.
pub trait SampleProbe: Send + Sync + std::fmt::Debug {
    /// Evaluates `surface` into `grid` (as [`SurfaceEvaluator::evaluate_into`]), then fills
    /// `inside` with each sample's [`Anatomy::inside_level`] and `distance` with its exact
    /// distance (mm) to the target's tumours (`resecta_margin::MarginField::nearest`), both
    /// resized to the sample count. [`BezierError::Device`] when the device failed: the planner
    /// then measures on the CPU.
    fn measure(
        &mut self,
        surface: &mut dyn SurfaceEvaluator,
        grid: &mut SurfaceGrid<Real>,
        inside: &mut Vec<Real>,
        distance: &mut Vec<Real>,
    ) -> Result<(), BezierError>;
}

type MakeProbe = dyn Fn(&Arc<Anatomy>, &Arc<TargetModel>) -> Result<Box<dyn SampleProbe>, BezierError>
    + Send
    + Sync;

/// Makes the probe of a resection for its anatomy and target. Cheap to clone (shared).
#[derive(Clone)]
pub struct ProbeEngine {
    backend: &'static str,
    make: Arc<MakeProbe>,
}

impl ProbeEngine {
    /// An engine named `backend`.
    pub fn new(
        backend: &'static str,
        make: impl Fn(&Arc<Anatomy>, &Arc<TargetModel>) -> Result<Box<dyn SampleProbe>, BezierError>
        + Send
        + Sync
        + 'static,
    ) -> Self {
        Self {
            backend,
            make: Arc::new(make),
        }
    }
    /// Where its probes run.
    pub fn backend(&self) -> &'static str {
        self.backend
    }
    /// A probe for `target` in `anatomy`.
    pub fn make(
        &self,
        anatomy: &Arc<Anatomy>,
        target: &Arc<TargetModel>,
    ) -> Result<Box<dyn SampleProbe>, BezierError> {
        (self.make)(anatomy, target)
    }
}

impl std::fmt::Debug for ProbeEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProbeEngine")
            .field("backend", &self.backend)
            .finish_non_exhaustive()
    }
}

/// Where a planner computes: its surfaces' evaluators and, optionally, the probes measuring
/// their samples. The default is the CPU for both.
#[derive(Debug, Clone, Default)]
pub struct ComputeEngine {
    pub surfaces: SurfaceEngine,
    pub probes: Option<ProbeEngine>,
    /// Makes the accelerator of the planner's volumetry (band and side components of its cuts;
    /// each cut falls back to the CPU when it fails).
    pub volumetry: Option<AcceleratorFactory>,
    /// Host memory its evaluators and probes hold per surface sample beyond the planner's own
    /// buffers (a device's staging buffers; all its buffers on a software device), for memory
    /// budgets.
    pub host_bytes_per_sample: u64,
    /// Host memory its volumetry accelerator holds per label-map voxel (all its buffers on a
    /// software device).
    pub host_bytes_per_voxel: u64,
}

impl ComputeEngine {
    /// The CPU: the default, and the fallback after a device failure.
    pub fn cpu() -> Self {
        Self::default()
    }
    /// Where the surfaces are evaluated (`"cpu"`, `"wgpu"`, …).
    pub fn backend(&self) -> &'static str {
        self.surfaces.backend()
    }
}

impl From<SurfaceEngine> for ComputeEngine {
    fn from(surfaces: SurfaceEngine) -> Self {
        Self {
            surfaces,
            probes: None,
            volumetry: None,
            host_bytes_per_sample: 0,
            host_bytes_per_voxel: 0,
        }
    }
}
