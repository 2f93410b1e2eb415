//! Plan quality metrics of the thesis' Sec. 7.4, per resection: how the margin is kept, how far
//! the resected volume is from a reference plan's, and how smooth the cut is where it matters
//! (Eq. 7.10's mean curvature over the surface inside the liver). Curvature is in mm⁻¹, the
//! unit of every other length here (the thesis prints m⁻¹: 0.01 m⁻¹ = 1e-5 mm⁻¹).

use rayon::prelude::*;
use resecta_geom::{Real, grid_param};
use serde::{Deserialize, Serialize};

use crate::engine::ResectionState;

/// Below this margin deviation (mm) a resection violates its margin (the thesis' −0.01 mm).
pub const VIOLATION_DEVIATION_MM: Real = -0.01;

/// One resection's metrics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ResectionMetrics {
    /// Minimum tumour distance over the surface inside the liver minus the margin (mm):
    /// negative falls short of the margin, below [`VIOLATION_DEVIATION_MM`] is a violation;
    /// `None` when no sample is inside the liver.
    pub margin_deviation_mm: Option<Real>,
    /// `100·(V − V_ref)/V_ref` against the reference plan's resection of the same name; `None`
    /// without one, or when either cut is incomplete.
    pub volume_deviation_pct: Option<Real>,
    /// Median |H| (Eq. 7.10) over the samples inside the liver (mm⁻¹); `None` when none is
    /// inside (samples without a tangent plane are left out).
    pub median_abs_mean_curvature_per_mm: Option<Real>,
}

/// The metrics of a resection's state with margin `margin_mm`, without a volume deviation
/// (see [`volume_deviation_pct`]).
pub fn resection_metrics(state: &ResectionState, margin_mm: Real) -> ResectionMetrics {
    ResectionMetrics {
        margin_deviation_mm: state.verdict.min_margin_mm.map(|d| d - margin_mm),
        volume_deviation_pct: None,
        median_abs_mean_curvature_per_mm: median_abs_mean_curvature(state),
    }
}

/// `100·(V − V_ref)/V_ref` (ml); `None` when either is absent (an incomplete cut) or V_ref ≤ 0.
pub fn volume_deviation_pct(resected_ml: Option<Real>, reference_ml: Option<Real>) -> Option<Real> {
    match (resected_ml, reference_ml) {
        (Some(v), Some(r)) if r > 0.0 => Some(100.0 * (v - r) / r),
        _ => None,
    }
}

/// Median |H| over the state's samples inside the liver (inside level > 0).
pub fn median_abs_mean_curvature(state: &ResectionState) -> Option<Real> {
    let [ru, rv] = state.surface.resolution();
    let surface = state.surface.cut_surface();
    let mut h: Vec<Real> = (0..ru * rv)
        .into_par_iter()
        .filter(|&k| state.inside.get(k).is_some_and(|&l| l > 0.0))
        .filter_map(|k| {
            surface
                .at(grid_param(k / rv, ru), grid_param(k % rv, rv))
                .mean_curvature()
        })
        .map(Real::abs)
        .collect();
    median(&mut h)
}

fn median(values: &mut [Real]) -> Option<Real> {
    values.sort_by(Real::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(values[n / 2]),
        _ => Some(0.5 * (values[n / 2 - 1] + values[n / 2])),
    }
}

#[cfg(test)]
mod tests {
    use super::median;

    #[test]
    fn medians_of_odd_even_and_empty_sets() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&mut []), None);
    }
}
