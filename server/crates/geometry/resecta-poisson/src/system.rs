//! The seam between assembling the screened Poisson system and solving it.
//!
//! [`crate::solve_with`] assembles the hierarchy once on the host ([`System`]: right-hand sides
//! and screening weights splatted on the finest level and restricted to the coarser ones) and
//! hands it to a [`MultigridSolver`]. Every solver runs the same schedule on the same system:
//! full multigrid from the coarsest level ([`COARSEST_SWEEPS`] sweeps there), then V-cycles at
//! the finest level until the relative residual is at most `tolerance` or `max_cycles` ran;
//! red–black Gauss–Seidel (colour 0, then 1), full weighting, trilinear prolongation, `f32`.
//! [`CpuMultigrid`] is the reference; `resecta-gpu` has the device's.

use resecta_isosurface::{CpuClassifier, NodeClassifier};
use std::sync::Arc;

use resecta_geom::Real;

pub use crate::multigrid::COARSEST_SWEEPS;
use crate::{CpuSobel, PoissonError, PoissonParams, SobelPass};

/// One level of `lap·L x + diag(d) x = b` on `n³` nodes (`i` fastest), `L` the 7-point graph
/// Laplacian with free boundaries.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemLevel {
    pub n: usize,
    /// Laplacian coefficient (`2^(finest − level)`).
    pub lap: f32,
    pub b: Vec<f32>,
    pub diag: Vec<f32>,
}

/// The assembled hierarchy, coarsest (2³ nodes) first, finest last.
#[derive(Debug, Clone, PartialEq)]
pub struct System {
    pub levels: Vec<SystemLevel>,
}

/// A solver's answer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Solution {
    /// The finest level's unknowns.
    pub x: Vec<f32>,
    /// V-cycles after full multigrid.
    pub cycles: u32,
    /// Relative residual after full multigrid and after each further V-cycle.
    pub residuals: Vec<Real>,
}

/// Runs the multigrid schedule of this module on an assembled [`System`].
pub trait MultigridSolver: Send + Sync {
    /// Where it runs (`"cpu"`, `"gpu"`).
    fn backend(&self) -> &'static str;
    /// Solves `system` with `params`' `tolerance`, `max_cycles` and `sweeps`. Device failures
    /// are [`PoissonError::Backend`].
    fn solve(&self, system: System, params: &PoissonParams) -> Result<Solution, PoissonError>;
}

/// The reference solver: rayon over z-planes, bitwise independent of the thread count.
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuMultigrid;

impl MultigridSolver for CpuMultigrid {
    fn backend(&self) -> &'static str {
        "cpu"
    }
    fn solve(&self, system: System, params: &PoissonParams) -> Result<Solution, PoissonError> {
        Ok(crate::multigrid::solve_cpu(system, params))
    }
}

/// The passes of a Poisson reconstruction that may run on a device, shared by options and
/// services: a [`MultigridSolver`] and a [`SobelPass`]; [`PoissonSolver::cpu`] by default.
#[derive(Clone)]
pub struct PoissonSolver {
    solver: Arc<dyn MultigridSolver>,
    sobel: Arc<dyn SobelPass>,
    classifier: Arc<dyn NodeClassifier>,
}

impl PoissonSolver {
    /// `solver` with the CPU's Sobel pass.
    pub fn new(solver: impl MultigridSolver + 'static) -> Self {
        Self {
            solver: Arc::new(solver),
            sobel: Arc::new(CpuSobel),
            classifier: Arc::new(CpuClassifier),
        }
    }
    /// The same, with `classifier` classifying the field's nodes for the iso-surface.
    pub fn with_classifier(mut self, classifier: impl NodeClassifier + 'static) -> Self {
        self.classifier = Arc::new(classifier);
        self
    }
    /// Classifies the field's nodes for the iso-surface (`resecta_isosurface::extract_with`).
    pub fn classifier(&self) -> &dyn NodeClassifier {
        &*self.classifier
    }
    /// The same, with `sobel` computing the oriented points' gradients.
    pub fn with_sobel(mut self, sobel: impl SobelPass + 'static) -> Self {
        self.sobel = Arc::new(sobel);
        self
    }
    pub fn cpu() -> Self {
        Self::new(CpuMultigrid)
    }
    /// Where the multigrid runs.
    pub fn backend(&self) -> &'static str {
        self.solver.backend()
    }
    pub fn solver(&self) -> &dyn MultigridSolver {
        &*self.solver
    }
    pub fn sobel(&self) -> &dyn SobelPass {
        &*self.sobel
    }
}

impl Default for PoissonSolver {
    fn default() -> Self {
        Self::cpu()
    }
}

impl std::fmt::Debug for PoissonSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoissonSolver")
            .field("backend", &self.backend())
            .field("sobel", &self.sobel.backend())
            .field("classifier", &self.classifier.backend())
            .finish_non_exhaustive()
    }
}
