//! Uniform access to the three evaluators for benchmarks and the CLI (`resecta bench bezier`).

use rayon::prelude::*;

use crate::brf::brf_into;
use crate::error::BezierError;
use crate::mat::MatEvaluator;
use crate::mle::MleEvaluator;
use crate::scalar::{BezierScalar, P3};
use crate::types::{ControlNet, Outputs, Resolution, SurfaceGrid};

/// Evaluation method of chapter 8.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Brute force, Eq. 8.1–8.2.
    Brf,
    /// Matrix / power form, Eq. 8.4.
    Mat,
    /// Multi-level evaluation, Sec. 8.4.
    Mle,
}

impl Method {
    /// All methods, in the thesis' order.
    pub const ALL: [Method; 3] = [Method::Brf, Method::Mat, Method::Mle];
    /// Lower-case name ("brf", "mat", "mle").
    pub fn name(self) -> &'static str {
        match self {
            Method::Brf => "brf",
            Method::Mat => "mat",
            Method::Mle => "mle",
        }
    }
}

#[derive(Debug, Clone)]
enum State<T> {
    Brf(ControlNet<T>),
    Mat(MatEvaluator<T>),
    Mle(Box<MleEvaluator<T>>),
}

/// A prepared evaluator with its output grid, so [`Prepared::run`] times exactly one surface
/// update under requirement A (levels 2–3 or G already built; no allocation).
#[derive(Debug, Clone)]
pub struct Prepared<T> {
    state: State<T>,
    grid: SurfaceGrid<T>,
}

impl<T: BezierScalar> Prepared<T> {
    /// Builds the evaluator state and output buffers, and runs once (warm-up).
    pub fn new(
        method: Method,
        net: ControlNet<T>,
        resolution: Resolution,
        outputs: Outputs,
    ) -> Result<Self, BezierError> {
        let state = match method {
            Method::Brf => State::Brf(net),
            Method::Mat => State::Mat(MatEvaluator::new(net)),
            Method::Mle => State::Mle(Box::new(MleEvaluator::new(net, resolution))),
        };
        let mut p = Self {
            state,
            grid: SurfaceGrid::zeroed(resolution, outputs),
        };
        p.run()?;
        Ok(p)
    }
    /// The method.
    pub fn method(&self) -> Method {
        match self.state {
            State::Brf(_) => Method::Brf,
            State::Mat(_) => Method::Mat,
            State::Mle(_) => Method::Mle,
        }
    }
    /// One evaluation into the held grid (threads: the current rayon pool).
    pub fn run(&mut self) -> Result<(), BezierError> {
        match &mut self.state {
            State::Brf(net) => brf_into(net, &mut self.grid),
            State::Mat(e) => e.evaluate_into(&mut self.grid),
            State::Mle(e) => e.evaluate_into(&mut self.grid)?,
        }
        Ok(())
    }
    /// Moves the control points (requirement A); MAT recomputes G here, as it would per update.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        match &mut self.state {
            State::Brf(net) => net.set_points(points),
            State::Mat(e) => e.set_control_points(points),
            State::Mle(e) => e.set_control_points(points),
        }
    }
    /// Result of the last run.
    pub fn output(&self) -> &SurfaceGrid<T> {
        &self.grid
    }
}

/// Memory-write ceiling: stores `value` into every coordinate of `out` (the same bytes a
/// points-only evaluation writes), rows in parallel on the current rayon pool. Time it to express
/// evaluator throughput as a fraction of plain streaming stores.
pub fn write_ceiling<T: BezierScalar>(out: &mut [P3<T>], value: T) {
    out.as_flattened_mut()
        .par_chunks_mut(1 << 14)
        .for_each(|chunk| chunk.fill(value));
}
