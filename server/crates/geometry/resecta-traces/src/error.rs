//! Why a set of traces (or a deformation) makes no surface; every message names the trace.

use thiserror::Error;

use crate::{MAX_TRACE_POINTS, MIN_TRACE_POINTS};

#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum TraceError {
    #[error("{got} traces: a surface needs {min}..={max}")]
    TraceCount { got: usize, min: usize, max: usize },
    #[error("trace {trace} has {got} points: each needs {MIN_TRACE_POINTS}..={MAX_TRACE_POINTS}")]
    PointCount { trace: usize, got: usize },
    #[error("trace {trace}, point {point}: coordinates must be finite and within ±100 m")]
    NonFinite { trace: usize, point: usize },
    #[error("trace {trace} has no length (all its points coincide)")]
    NoLength { trace: usize },
    #[error(
        "trace {trace} does not lie on one axial, coronal or sagittal slice (its points differ by more than {tolerance_mm} mm in every axis)"
    )]
    NotOnSlice { trace: usize, tolerance_mm: f64 },
    #[error(
        "traces must lie on slices of one orientation: trace {trace} is not on a {expected} slice"
    )]
    MixedOrientations {
        trace: usize,
        expected: &'static str,
    },
    #[error("traces {a} and {b} lie on the same {orientation} slice at {position_mm:.2} mm")]
    SameSlice {
        a: usize,
        b: usize,
        orientation: &'static str,
        position_mm: f64,
    },
    #[error("trace {trace} intersects itself (segments {first} and {second} cross)")]
    SelfIntersecting {
        trace: usize,
        first: usize,
        second: usize,
    },
    #[error("the traces do not span a plane ({0})")]
    NoPlane(String),
    #[error("deformation {index}: {what}")]
    Deformation { index: usize, what: String },
}
