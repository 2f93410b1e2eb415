//! Drawing on slices (DS, thesis Sec. 2.5.1 and 7.4, Table 7.1).
//!
//! Choices where the thesis leaves details open:
//! - **Slices**: traces lie on axis-aligned RAS slices (axial S, coronal A, sagittal R), all of
//!   one orientation, each on its own slice; a trace's points may differ by at most
//!   [`SLICE_TOLERANCE_MM`] along the slice normal. The order of the traces is the slices'
//!   order, whatever order they were drawn in.
//! - **Direction**: the first trace (in slice order) runs from its end with the smaller in-slice
//!   coordinates (R then A for axial slices, A then S for sagittal, S then R for coronal); a
//!   trace drawn the other way round than its predecessor is reversed (the one whose ends pair
//!   with the predecessor's ends over the shorter total distance wins). The surface is thus the
//!   same whichever way and in whichever order the traces were drawn.
//! - **Resampling**: each trace is resampled to [`DS_POINTS_PER_TRACE`] points equally spaced by
//!   arc length (parametric linear interpolation of the drawn polyline).
//! - **Surface**: the tensor product of piecewise quadratic Lagrange interpolation along the
//!   traces (parameter: arc length, uniform after resampling) and across them (parameter: the
//!   slices' positions, so unequal slice gaps keep their geometry): bi-quadratic on every piece,
//!   through every resampled point, spanning exactly the first to the last trace. A surface that
//!   ends inside the liver (traces not reaching its edge, first or last slice inside it) is an
//!   incomplete cut, which volumetry reports with the point.

use resecta_geom::{CutSurface, Real, SurfacePoint, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::TraceError;
use crate::quadratic::weights;
use crate::{check_traces, vec3};

fn arr(v: Vec3) -> [Real; 3] {
    [v.x, v.y, v.z]
}

/// Points per resampled trace (Table 7.1's 20).
pub const DS_POINTS_PER_TRACE: usize = 20;
/// Fewest traces of a DS surface (quadratic interpolation needs three).
pub const MIN_TRACES: usize = 3;
/// How far (mm) a trace's points may leave its slice along the slice normal.
pub const SLICE_TOLERANCE_MM: Real = 0.01;

/// The orientation of the slices traces are drawn on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SliceOrientation {
    /// Normal S (z).
    Axial,
    /// Normal A (y).
    Coronal,
    /// Normal R (x).
    Sagittal,
}

impl SliceOrientation {
    /// The RAS axis along the slice normal.
    pub fn axis(self) -> usize {
        match self {
            SliceOrientation::Axial => 2,
            SliceOrientation::Coronal => 1,
            SliceOrientation::Sagittal => 0,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            SliceOrientation::Axial => "axial",
            SliceOrientation::Coronal => "coronal",
            SliceOrientation::Sagittal => "sagittal",
        }
    }
    const ALL: [SliceOrientation; 3] = [
        SliceOrientation::Axial,
        SliceOrientation::Coronal,
        SliceOrientation::Sagittal,
    ];
}

/// A DS resection surface: u along the traces, v across them (first to last slice).
#[derive(Debug, Clone, PartialEq)]
pub struct DsSurface {
    orientation: SliceOrientation,
    /// Resampled traces in slice order: node (i, t) at `i·k + t`.
    nodes: Vec<Vec3>,
    k: usize,
    u_knots: Vec<Real>,
    v_knots: Vec<Real>,
    /// Slice positions (mm) of the traces, ascending.
    slices: Vec<Real>,
    speeds: [Real; 2],
}

fn spread(trace: &[[Real; 3]], axis: usize) -> Real {
    let (lo, hi) = trace
        .iter()
        .fold((Real::INFINITY, Real::NEG_INFINITY), |(a, b), p| {
            (a.min(p[axis]), b.max(p[axis]))
        });
    hi - lo
}

/// The orientation every trace lies in; ties (traces flat in two axes) go to the axis along
/// which the traces' slices are distinct, then axial, coronal, sagittal.
fn orientation(traces: &[Vec<[Real; 3]>]) -> Result<SliceOrientation, TraceError> {
    let flat = |t: &[[Real; 3]], o: SliceOrientation| spread(t, o.axis()) <= SLICE_TOLERANCE_MM;
    for (t, trace) in traces.iter().enumerate() {
        if !SliceOrientation::ALL.iter().any(|&o| flat(trace, o)) {
            return Err(TraceError::NotOnSlice {
                trace: t,
                tolerance_mm: SLICE_TOLERANCE_MM,
            });
        }
    }
    let shared: Vec<SliceOrientation> = SliceOrientation::ALL
        .into_iter()
        .filter(|&o| traces.iter().all(|t| flat(t, o)))
        .collect();
    let distinct = |o: SliceOrientation| {
        let mut pos: Vec<Real> = traces.iter().map(|t| t[0][o.axis()]).collect();
        pos.sort_by(Real::total_cmp);
        pos.windows(2).all(|w| w[1] - w[0] > SLICE_TOLERANCE_MM)
    };
    if let Some(&o) = shared.iter().find(|&&o| distinct(o)).or(shared.first()) {
        return Ok(o);
    }
    // No orientation is shared: name the first trace off the first trace's orientation.
    let first = SliceOrientation::ALL
        .into_iter()
        .find(|&o| flat(&traces[0], o))
        .unwrap_or(SliceOrientation::Axial);
    let trace = traces.iter().position(|t| !flat(t, first)).unwrap_or(0);
    Err(TraceError::MixedOrientations {
        trace,
        expected: first.name(),
    })
}

/// In-slice 2-D coordinates of `p` for slices normal to `axis`.
fn in_slice(p: [Real; 3], axis: usize) -> [Real; 2] {
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    [p[a], p[b]]
}

fn cross2(a: [Real; 2], b: [Real; 2]) -> Real {
    a[0] * b[1] - a[1] * b[0]
}

fn sub2(a: [Real; 2], b: [Real; 2]) -> [Real; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

/// Whether closed segments pq and rs cross (touching counts).
fn segments_cross(p: [Real; 2], q: [Real; 2], r: [Real; 2], s: [Real; 2]) -> bool {
    let d1 = cross2(sub2(q, p), sub2(r, p));
    let d2 = cross2(sub2(q, p), sub2(s, p));
    let d3 = cross2(sub2(s, r), sub2(p, r));
    let d4 = cross2(sub2(s, r), sub2(q, r));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    let on = |a: [Real; 2], b: [Real; 2], c: [Real; 2], d: Real| {
        d == 0.0
            && c[0] >= a[0].min(b[0])
            && c[0] <= a[0].max(b[0])
            && c[1] >= a[1].min(b[1])
            && c[1] <= a[1].max(b[1])
    };
    on(p, q, r, d1) || on(p, q, s, d2) || on(r, s, p, d3) || on(r, s, q, d4)
}

/// The first pair of non-adjacent segments of a polyline that cross (zero-length segments
/// skipped).
pub(crate) fn self_intersection(pts: &[[Real; 2]]) -> Option<(usize, usize)> {
    let segs: Vec<usize> = (0..pts.len() - 1)
        .filter(|&i| pts[i] != pts[i + 1])
        .collect();
    for (x, &i) in segs.iter().enumerate() {
        for &j in segs.iter().skip(x + 2) {
            if segments_cross(pts[i], pts[i + 1], pts[j], pts[j + 1]) {
                return Some((i, j));
            }
        }
    }
    None
}

/// `count` points equally spaced by arc length along a polyline of positive length.
pub(crate) fn resample(trace: &[Vec3], count: usize) -> Vec<Vec3> {
    let mut cum = vec![0.0];
    for w in trace.windows(2) {
        cum.push(cum.last().copied().unwrap_or(0.0) + (w[1] - w[0]).norm());
    }
    let total = cum.last().copied().unwrap_or(0.0);
    let mut seg = 0;
    (0..count)
        .map(|k| {
            let s = total * k as Real / (count - 1) as Real;
            while seg + 2 < cum.len() && cum[seg + 1] < s {
                seg += 1;
            }
            let len = cum[seg + 1] - cum[seg];
            let f = if len > 0.0 {
                ((s - cum[seg]) / len).clamp(0.0, 1.0)
            } else {
                0.0
            };
            trace[seg] + (trace[seg + 1] - trace[seg]) * f
        })
        .collect()
}

impl DsSurface {
    /// The surface of `traces` (each a polyline in RAS mm, in any order and direction).
    pub fn new(traces: &[Vec<[Real; 3]>]) -> Result<Self, TraceError> {
        check_traces(traces, MIN_TRACES)?;
        let orientation = orientation(traces)?;
        let axis = orientation.axis();
        for (t, trace) in traces.iter().enumerate() {
            if trace.iter().all(|p| *p == trace[0]) {
                return Err(TraceError::NoLength { trace: t });
            }
            let flat: Vec<[Real; 2]> = trace.iter().map(|&p| in_slice(p, axis)).collect();
            if let Some((first, second)) = self_intersection(&flat) {
                return Err(TraceError::SelfIntersecting {
                    trace: t,
                    first,
                    second,
                });
            }
        }
        // Slice order.
        let position = |t: &[[Real; 3]]| t.iter().map(|p| p[axis]).sum::<Real>() / t.len() as Real;
        let mut order: Vec<usize> = (0..traces.len()).collect();
        order.sort_by(|&a, &b| position(&traces[a]).total_cmp(&position(&traces[b])));
        for w in order.windows(2) {
            let (pa, pb) = (position(&traces[w[0]]), position(&traces[w[1]]));
            if pb - pa <= SLICE_TOLERANCE_MM {
                return Err(TraceError::SameSlice {
                    a: w[0].min(w[1]),
                    b: w[0].max(w[1]),
                    orientation: orientation.name(),
                    position_mm: pa,
                });
            }
        }
        let slices: Vec<Real> = order.iter().map(|&t| position(&traces[t])).collect();
        // Resample, each trace running the way its predecessor runs.
        let mut resampled: Vec<Vec<Vec3>> = Vec::with_capacity(order.len());
        for &t in &order {
            let pts: Vec<Vec3> = traces[t].iter().map(|&p| vec3(p)).collect();
            let mut r = resample(&pts, DS_POINTS_PER_TRACE);
            let (c, d) = (r[0], r[DS_POINTS_PER_TRACE - 1]);
            let reverse = match resampled.last() {
                Some(prev) => {
                    let (a, b) = (prev[0], prev[DS_POINTS_PER_TRACE - 1]);
                    (c - b).norm() + (d - a).norm() < (c - a).norm() + (d - b).norm()
                }
                // The first trace starts at its end with the smaller in-slice coordinates.
                None => {
                    let (c2, d2) = (in_slice(arr(c), axis), in_slice(arr(d), axis));
                    c2[0]
                        .total_cmp(&d2[0])
                        .then(c2[1].total_cmp(&d2[1]))
                        .is_gt()
                }
            };
            if reverse {
                r.reverse();
            }
            resampled.push(r);
        }
        let k = order.len();
        let nodes = (0..DS_POINTS_PER_TRACE * k)
            .map(|x| resampled[x % k][x / k])
            .collect();
        let (s0, s1) = (slices[0], slices[k - 1]);
        let v_knots = slices.iter().map(|&s| (s - s0) / (s1 - s0)).collect();
        let u_knots = (0..DS_POINTS_PER_TRACE)
            .map(|i| i as Real / (DS_POINTS_PER_TRACE - 1) as Real)
            .collect();
        let mut surface = Self {
            orientation,
            nodes,
            k,
            u_knots,
            v_knots,
            slices,
            speeds: [0.0; 2],
        };
        surface.speeds = sampled_speeds(&surface, 4 * DS_POINTS_PER_TRACE, 4 * k);
        Ok(surface)
    }

    pub fn orientation(&self) -> SliceOrientation {
        self.orientation
    }
    /// Slice positions (mm along the slice normal) of the traces, ascending.
    pub fn slices(&self) -> &[Real] {
        &self.slices
    }
    /// The resampled traces in slice order, [`DS_POINTS_PER_TRACE`] points each.
    pub fn resampled(&self) -> Vec<Vec<Vec3>> {
        (0..self.k)
            .map(|t| {
                (0..DS_POINTS_PER_TRACE)
                    .map(|i| self.nodes[i * self.k + t])
                    .collect()
            })
            .collect()
    }
}

/// Speed bounds of a surface from its nu×nv samples: the longest step along u (v) times the
/// steps per unit parameter, grown by 5 % (steps are chords). Exact for a bilinear grid sampled
/// at its vertices.
pub(crate) fn sampled_speeds(s: &dyn CutSurface, nu: usize, nv: usize) -> [Real; 2] {
    let p = |a: usize, b: usize| {
        s.at(
            resecta_geom::grid_param(a, nu),
            resecta_geom::grid_param(b, nv),
        )
        .p
    };
    let pts: Vec<Vec3> = (0..nu * nv).map(|k| p(k / nv, k % nv)).collect();
    let su = (0..(nu - 1) * nv)
        .map(|k| (pts[k + nv] - pts[k]).norm())
        .fold(0.0, Real::max);
    let sv = (0..nu * nv)
        .filter(|k| k % nv + 1 < nv)
        .map(|k| (pts[k + 1] - pts[k]).norm())
        .fold(0.0, Real::max);
    [1.05 * su * (nu - 1) as Real, 1.05 * sv * (nv - 1) as Real]
}

impl CutSurface for DsSurface {
    fn at(&self, u: Real, v: Real) -> SurfacePoint {
        let (wu, wv) = (weights(&self.u_knots, u), weights(&self.v_knots, v));
        let mut s = SurfacePoint {
            p: Vec3::zeros(),
            du: Vec3::zeros(),
            dv: Vec3::zeros(),
            duu: Vec3::zeros(),
            duv: Vec3::zeros(),
            dvv: Vec3::zeros(),
        };
        for a in 0..3 {
            for b in 0..3 {
                let n = self.nodes[(wu.first + a) * self.k + wv.first + b];
                s.p += n * (wu.w[a] * wv.w[b]);
                s.du += n * (wu.d1[a] * wv.w[b]);
                s.dv += n * (wu.w[a] * wv.d1[b]);
                s.duu += n * (wu.d2[a] * wv.w[b]);
                s.duv += n * (wu.d1[a] * wv.d1[b]);
                s.dvv += n * (wu.w[a] * wv.d2[b]);
            }
        }
        s
    }

    fn speeds(&self) -> [Real; 2] {
        self.speeds
    }
}
