//! The seam between the planner and whatever evaluates its surfaces: [`SurfaceEvaluator`]
//! (implemented here by [`MleEvaluator<f64>`], elsewhere by GPU evaluators) and the
//! [`SurfaceEngine`] factory a planner is given ([`SurfaceEngine::cpu`] by default).

use std::sync::Arc;

use crate::error::BezierError;
use crate::mle::MleEvaluator;
use crate::scalar::P3;
use crate::types::{ControlNet, Outputs, Resolution, SurfaceGrid};

/// A stateful evaluator of one surface's points and unit normals (f64, millimetres). Setters
/// invalidate what they affect; [`SurfaceEvaluator::evaluate_into`] recomputes what is stale.
pub trait SurfaceEvaluator: Send + Sync + std::fmt::Debug {
    /// `"cpu"`, `"wgpu"`, …: where the evaluation runs.
    fn backend(&self) -> &'static str;
    /// Current control net.
    fn net(&self) -> &ControlNet<f64>;
    /// Current resolution.
    fn resolution(&self) -> Resolution;
    /// A new net (any M×N).
    fn set_net(&mut self, net: ControlNet<f64>);
    /// New coordinates for the same M×N.
    fn set_control_points(&mut self, points: &[P3<f64>]) -> Result<(), BezierError>;
    /// Moves `P_ij`.
    fn set_control_point(&mut self, i: usize, j: usize, p: P3<f64>) -> Result<(), BezierError>;
    /// A new resolution.
    fn set_resolution(&mut self, resolution: Resolution);
    /// Fills every array of `grid` (made with [`Outputs::Normals`] at the evaluator's
    /// resolution): points, ∂S/∂u, ∂S/∂v and unit normals with the degenerate-sample handling
    /// of [`crate::normals`]. [`BezierError::Device`] when the device failed.
    fn evaluate_into(&mut self, grid: &mut SurfaceGrid<f64>) -> Result<(), BezierError>;
    /// The evaluator as `Any`, for a device that chains its own work onto this evaluator's
    /// (e.g. measuring the samples where they were computed); `None` by default.
    fn as_any_mut(&mut self) -> Option<&mut dyn std::any::Any> {
        None
    }
}

impl SurfaceEvaluator for MleEvaluator<f64> {
    fn backend(&self) -> &'static str {
        "cpu"
    }
    fn net(&self) -> &ControlNet<f64> {
        MleEvaluator::net(self)
    }
    fn resolution(&self) -> Resolution {
        MleEvaluator::resolution(self)
    }
    fn set_net(&mut self, net: ControlNet<f64>) {
        MleEvaluator::set_net(self, net);
    }
    fn set_control_points(&mut self, points: &[P3<f64>]) -> Result<(), BezierError> {
        MleEvaluator::set_control_points(self, points)
    }
    fn set_control_point(&mut self, i: usize, j: usize, p: P3<f64>) -> Result<(), BezierError> {
        MleEvaluator::set_control_point(self, i, j, p)
    }
    fn set_resolution(&mut self, resolution: Resolution) {
        MleEvaluator::set_resolution(self, resolution);
    }
    fn evaluate_into(&mut self, grid: &mut SurfaceGrid<f64>) -> Result<(), BezierError> {
        if grid.outputs() != Outputs::Normals {
            return Err(BezierError::MissingOutput("normals"));
        }
        MleEvaluator::evaluate_into(self, grid)
    }
}

type Make = dyn Fn(ControlNet<f64>, Resolution) -> Result<Box<dyn SurfaceEvaluator>, BezierError>
    + Send
    + Sync;

/// Makes the evaluator of each new surface; a planner is given one. Cheap to clone (shared).
#[derive(Clone)]
pub struct SurfaceEngine {
    backend: &'static str,
    make: Arc<Make>,
}

impl SurfaceEngine {
    /// An engine named `backend` (what its evaluators' [`SurfaceEvaluator::backend`] says).
    pub fn new(
        backend: &'static str,
        make: impl Fn(ControlNet<f64>, Resolution) -> Result<Box<dyn SurfaceEvaluator>, BezierError>
        + Send
        + Sync
        + 'static,
    ) -> Self {
        Self {
            backend,
            make: Arc::new(make),
        }
    }
    /// The engine of [`MleEvaluator`]s: the default, and the fallback after a device failure.
    pub fn cpu() -> Self {
        Self::new("cpu", |net, res| Ok(cpu_evaluator(net, res)))
    }
    /// Where its evaluators run.
    pub fn backend(&self) -> &'static str {
        self.backend
    }
    /// An evaluator for `net` at `resolution` (nothing evaluated yet).
    pub fn make(
        &self,
        net: ControlNet<f64>,
        resolution: Resolution,
    ) -> Result<Box<dyn SurfaceEvaluator>, BezierError> {
        (self.make)(net, resolution)
    }
}

impl Default for SurfaceEngine {
    fn default() -> Self {
        Self::cpu()
    }
}

impl std::fmt::Debug for SurfaceEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SurfaceEngine")
            .field("backend", &self.backend)
            .finish_non_exhaustive()
    }
}

/// The CPU evaluator ([`MleEvaluator<f64>`]) for a net at a resolution.
pub fn cpu_evaluator(net: ControlNet<f64>, resolution: Resolution) -> Box<dyn SurfaceEvaluator> {
    Box::new(MleEvaluator::new(net, resolution))
}
