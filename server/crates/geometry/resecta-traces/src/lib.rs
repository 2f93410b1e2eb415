//! Resection surfaces from traces: the two methods surgeons meet in commercial suites, which the
//! thesis' Paper II (Sec. 2.5, 7.4, Table 7.1) compares with Bézier resections.
//!
//! - [`DsSurface`] — **drawing on slices**: 3 or more traces on parallel slices of one
//!   orientation, each resampled to 20 points by arc length, joined by parametric quadratic
//!   interpolation across the traces (and along them): a piecewise bi-quadratic surface through
//!   every resampled trace point.
//! - [`CpSurface`] — **deformable cutting plane**: traces on the liver surface (typically a
//!   ring) give a PCA plane (Eq. 7.6–7.8) with a 30×n grid of square quads; the vertices nearest
//!   the traces move along the plane normal onto them, the others are Laplacian-smoothed to
//!   convergence, and [`Deformation`]s push a cosine bump within a radius of influence.
//!
//! Both are [`resecta_geom::CutSurface`]s, so margins, volumetry and metrics treat them as they
//! treat Bézier surfaces.

pub mod cp;
pub mod ds;
pub mod error;
mod quadratic;

pub use cp::{CP_SHORT_QUADS, CpSurface, Deformation, MAX_DEFORMATIONS, MAX_LONG_QUADS};
pub use ds::{DS_POINTS_PER_TRACE, DsSurface, MIN_TRACES, SLICE_TOLERANCE_MM, SliceOrientation};
pub use error::TraceError;

/// Most traces one resection holds.
pub const MAX_TRACES: usize = 32;
/// Most points one trace holds.
pub const MAX_TRACE_POINTS: usize = 4096;
/// Fewest points of one trace.
pub const MIN_TRACE_POINTS: usize = 3;

use resecta_geom::{Real, Vec3};

pub(crate) fn vec3(p: [Real; 3]) -> Vec3 {
    Vec3::new(p[0], p[1], p[2])
}

/// Checks counts and finiteness of a set of traces; `min_traces` fewest traces.
pub(crate) fn check_traces(traces: &[Vec<[Real; 3]>], min_traces: usize) -> Result<(), TraceError> {
    if traces.len() < min_traces || traces.len() > MAX_TRACES {
        return Err(TraceError::TraceCount {
            got: traces.len(),
            min: min_traces,
            max: MAX_TRACES,
        });
    }
    for (t, trace) in traces.iter().enumerate() {
        if trace.len() < MIN_TRACE_POINTS || trace.len() > MAX_TRACE_POINTS {
            return Err(TraceError::PointCount {
                trace: t,
                got: trace.len(),
            });
        }
        if let Some(k) = trace
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite() && c.abs() <= 1.0e5))
        {
            return Err(TraceError::NonFinite { trace: t, point: k });
        }
    }
    Ok(())
}
