//! The deformable cutting plane (CP, thesis Sec. 2.5.2 and 7.4, after Konrad-Verse et al.).
//!
//! - **Plane**: PCA of every trace point: centre c (Eq. 7.7), axes E₁, E₂ of the two largest
//!   eigenvalues, extents lᵢ = 4√eᵢ (Eq. 7.6), origin `c − l₁/2·E₁ − l₂/2·E₂` (Eq. 7.8).
//! - **Grid**: [`CP_SHORT_QUADS`] square quads of side h = l₂/30 along the short axis E₂ and
//!   n = ⌈l₁/h⌉ along E₁, centred on c; u runs along E₂ (31 vertices), v along E₁ (n + 1).
//! - **Fit**: the traces, densified to h/2 steps, pull their nearest vertices along the plane
//!   normal N onto them (a vertex several trace points reach takes their mean height); then
//!   Laplacian smoothing moves every other vertex to the mean of its neighbours, iterated to
//!   convergence (the discrete harmonic height field through the trace vertices; over-relaxed
//!   Gauss–Seidel until no vertex moves more than 1e-12 of the largest trace height).
//! - **Deformations** (in order): the vertex nearest the point's projection moves by exactly
//!   `offset_mm` along N, every vertex at in-plane distance d < R from it by
//!   `offset·½(1 + cos(πd/R))`, nothing at d ≥ R.
//! - **Surface**: the grid's bilinear patches; derivatives (for normals and curvature) are the
//!   grid's central differences (one-sided at the border), interpolated bilinearly.

use resecta_geom::{CutSurface, Pca, Real, SurfacePoint, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::TraceError;
use crate::{check_traces, vec3};

/// Quads along the plane's short axis (Sec. 7.4).
pub const CP_SHORT_QUADS: usize = 30;
/// Most quads along the long axis (a plane at most ten times longer than wide).
pub const MAX_LONG_QUADS: usize = 10 * CP_SHORT_QUADS;
/// Most deformations of one resection.
pub const MAX_DEFORMATIONS: usize = 256;
/// Largest radius of influence (mm).
pub const MAX_RADIUS_MM: Real = 200.0;
/// Largest deformation offset (mm, either way).
pub const MAX_OFFSET_MM: Real = 100.0;
/// Laplacian smoothing stops when no vertex moves more than this times the largest trace
/// height (at least 1 mm) in a sweep.
const SMOOTH_TOLERANCE: Real = 1e-12;
const MAX_SWEEPS: usize = 20_000;
/// Most points the densified traces hold (longer traces are densified more coarsely).
const MAX_DENSE_POINTS: Real = 200_000.0;

/// A local deformation: a cosine bump of `offset_mm` along the plane normal, centred on the
/// grid vertex nearest `point`, vanishing at `radius_mm`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Deformation {
    pub point: [Real; 3],
    pub offset_mm: Real,
    pub radius_mm: Real,
}

impl Deformation {
    /// Checks ranges; `index` names it in the error.
    pub fn validate(&self, index: usize) -> Result<(), TraceError> {
        let bad = |what: String| TraceError::Deformation { index, what };
        if !self.point.iter().all(|c| c.is_finite() && c.abs() <= 1.0e5) {
            return Err(bad(format!("point {:?} must be finite", self.point)));
        }
        if !(self.offset_mm.is_finite() && self.offset_mm.abs() <= MAX_OFFSET_MM) {
            return Err(bad(format!(
                "offset_mm must be finite and within ±{MAX_OFFSET_MM} mm, got {}",
                self.offset_mm
            )));
        }
        if !(self.radius_mm.is_finite() && self.radius_mm > 0.0 && self.radius_mm <= MAX_RADIUS_MM)
        {
            return Err(bad(format!(
                "radius_mm must be > 0 and ≤ {MAX_RADIUS_MM} mm, got {}",
                self.radius_mm
            )));
        }
        Ok(())
    }
}

/// A CP resection surface.
#[derive(Debug, Clone, PartialEq)]
pub struct CpSurface {
    origin: Vec3,
    /// Along u (short axis), along v (long axis), normal.
    axes: [Vec3; 3],
    h: Real,
    /// Vertices along u and v.
    nu: usize,
    nv: usize,
    /// Height along the normal per vertex, `a·nv + b`.
    heights: Vec<Real>,
    /// Per-vertex ∂H/∂a, ∂H/∂b, ∂²H/∂a², ∂²H/∂a∂b, ∂²H/∂b² (grid steps).
    diffs: Vec<[Real; 5]>,
    speeds: [Real; 2],
}

/// Points every `step` along a polyline (its vertices included).
fn densify(trace: &[[Real; 3]], step: Real) -> Vec<Vec3> {
    let mut out = vec![vec3(trace[0])];
    for w in trace.windows(2) {
        let (a, b) = (vec3(w[0]), vec3(w[1]));
        let n = ((b - a).norm() / step).ceil().max(1.0) as usize;
        out.extend((1..=n).map(|k| a + (b - a) * (k as Real / n as Real)));
    }
    out
}

impl CpSurface {
    /// The fitted plane of `traces` with `deformations` applied in order.
    pub fn new(
        traces: &[Vec<[Real; 3]>],
        deformations: &[Deformation],
    ) -> Result<Self, TraceError> {
        check_traces(traces, 1)?;
        if deformations.len() > MAX_DEFORMATIONS {
            return Err(TraceError::Deformation {
                index: deformations.len() - 1,
                what: format!("at most {MAX_DEFORMATIONS} deformations"),
            });
        }
        for (k, d) in deformations.iter().enumerate() {
            d.validate(k)?;
        }
        let all: Vec<Vec3> = traces.iter().flatten().map(|&p| vec3(p)).collect();
        let pca = Pca::of_points(&all).map_err(|e| TraceError::NoPlane(e.to_string()))?;
        let [e1, e2, _] = pca.eigenvalues;
        let (l1, l2) = (4.0 * e1.sqrt(), 4.0 * e2.sqrt());
        if !(l2 >= 1.0 && l2 >= 1e-3 * l1) {
            return Err(TraceError::NoPlane(format!(
                "they are nearly collinear: extents {l1:.1} × {l2:.2} mm"
            )));
        }
        let h = l2 / CP_SHORT_QUADS as Real;
        let long = (l1 / h).ceil() as usize;
        if long > MAX_LONG_QUADS {
            return Err(TraceError::NoPlane(format!(
                "the plane would be {long} quads long: at most {MAX_LONG_QUADS} (ten times its width)"
            )));
        }
        let (nu, nv) = (CP_SHORT_QUADS + 1, long.max(1) + 1);
        let [a1, a2, normal] = pca.axes;
        let c = pca.mean;
        let origin = c - a1 * (h * (nv - 1) as Real / 2.0) - a2 * (l2 / 2.0);
        let mut s = Self {
            origin,
            axes: [a2, a1, normal],
            h,
            nu,
            nv,
            heights: vec![0.0; nu * nv],
            diffs: Vec::new(),
            speeds: [0.0; 2],
        };
        s.fit(traces);
        for (k, d) in deformations.iter().enumerate() {
            s.deform(k, d)?;
        }
        s.finish();
        Ok(s)
    }

    /// Grid coordinates (a, b) of `p`'s projection, in grid steps.
    fn grid_coords(&self, p: Vec3) -> (Real, Real) {
        let d = p - self.origin;
        (d.dot(&self.axes[0]) / self.h, d.dot(&self.axes[1]) / self.h)
    }

    fn nearest_vertex(&self, p: Vec3) -> (usize, usize) {
        let (a, b) = self.grid_coords(p);
        let clamp = |x: Real, n: usize| x.round().clamp(0.0, (n - 1) as Real) as usize;
        (clamp(a, self.nu), clamp(b, self.nv))
    }

    fn fit(&mut self, traces: &[Vec<[Real; 3]>]) {
        let (nu, nv) = (self.nu, self.nv);
        let mut sum = vec![0.0; nu * nv];
        let mut count = vec![0u32; nu * nv];
        let centre_height = self.origin.dot(&self.axes[2]);
        let length: Real = traces
            .iter()
            .flat_map(|t| t.windows(2))
            .map(|w| (vec3(w[1]) - vec3(w[0])).norm())
            .sum();
        let step = (self.h / 2.0).max(length / MAX_DENSE_POINTS);
        for trace in traces {
            for p in densify(trace, step) {
                let (a, b) = self.nearest_vertex(p);
                sum[a * nv + b] += p.dot(&self.axes[2]) - centre_height;
                count[a * nv + b] += 1;
            }
        }
        let fixed: Vec<bool> = count.iter().map(|&c| c > 0).collect();
        for k in 0..nu * nv {
            if fixed[k] {
                self.heights[k] = sum[k] / Real::from(count[k]);
            }
        }
        let scale = self.heights.iter().fold(1.0, |m: Real, h| m.max(h.abs()));
        // Laplacian smoothing to convergence (Gauss–Seidel, over-relaxed).
        let omega = 2.0 / (1.0 + (std::f64::consts::PI / nu.max(nv) as Real).sin());
        let h = &mut self.heights;
        for _ in 0..MAX_SWEEPS {
            let mut moved: Real = 0.0;
            for a in 0..nu {
                for b in 0..nv {
                    let k = a * nv + b;
                    if fixed[k] {
                        continue;
                    }
                    let (mut s, mut n) = (0.0, 0.0);
                    if a > 0 {
                        s += h[k - nv];
                        n += 1.0;
                    }
                    if a + 1 < nu {
                        s += h[k + nv];
                        n += 1.0;
                    }
                    if b > 0 {
                        s += h[k - 1];
                        n += 1.0;
                    }
                    if b + 1 < nv {
                        s += h[k + 1];
                        n += 1.0;
                    }
                    let step = omega * (s / n - h[k]);
                    h[k] += step;
                    moved = moved.max(step.abs());
                }
            }
            if moved <= SMOOTH_TOLERANCE * scale {
                break;
            }
        }
    }

    fn deform(&mut self, index: usize, d: &Deformation) -> Result<(), TraceError> {
        let (a, b) = self.grid_coords(vec3(d.point));
        let reach = |x: Real, n: usize| (-0.5..=(n - 1) as Real + 0.5).contains(&x);
        if !(reach(a, self.nu) && reach(b, self.nv)) {
            return Err(TraceError::Deformation {
                index,
                what: format!("point {:?} lies beyond the cutting plane's extent", d.point),
            });
        }
        let (ca, cb) = self.nearest_vertex(vec3(d.point));
        let r = d.radius_mm / self.h;
        for a in 0..self.nu {
            for b in 0..self.nv {
                let dist =
                    ((a as Real - ca as Real).powi(2) + (b as Real - cb as Real).powi(2)).sqrt();
                if dist < r {
                    let w = 0.5 * (1.0 + (std::f64::consts::PI * dist / r).cos());
                    self.heights[a * self.nv + b] += d.offset_mm * w;
                }
            }
        }
        Ok(())
    }

    /// Per-vertex differences and speed bounds.
    fn finish(&mut self) {
        let (nu, nv) = (self.nu, self.nv);
        let h = |a: usize, b: usize| self.heights[a * nv + b];
        // Central first differences (one-sided at the border); second differences at the
        // nearest vertex that has both neighbours.
        let d1 = |a: usize, n: usize, f: &dyn Fn(usize) -> Real| -> Real {
            if a == 0 {
                f(1) - f(0)
            } else if a + 1 == n {
                f(a) - f(a - 1)
            } else {
                0.5 * (f(a + 1) - f(a - 1))
            }
        };
        let d2 = |a: usize, n: usize, f: &dyn Fn(usize) -> Real| -> Real {
            let c = a.clamp(1, n - 2);
            f(c + 1) - 2.0 * f(c) + f(c - 1)
        };
        let mut diffs = Vec::with_capacity(nu * nv);
        for a in 0..nu {
            for b in 0..nv {
                let ha = d1(a, nu, &|x| h(x, b));
                let hb = d1(b, nv, &|y| h(a, y));
                let haa = d2(a, nu, &|x| h(x, b));
                let hbb = if nv >= 3 {
                    d2(b, nv, &|y| h(a, y))
                } else {
                    0.0
                };
                let hab = d1(a, nu, &|x| d1(b, nv, &|y| h(x, y)));
                diffs.push([ha, hb, haa, hab, hbb]);
            }
        }
        self.diffs = diffs;
        self.speeds = crate::ds::sampled_speeds(self, nu, nv);
    }

    /// Vertices along u (short axis) and v (long axis): the grid the planner samples.
    pub fn dims(&self) -> [usize; 2] {
        [self.nu, self.nv]
    }
    /// Quad side (mm).
    pub fn quad_mm(&self) -> Real {
        self.h
    }
    /// The plane's unit normal N (heights and deformations go along it).
    pub fn normal(&self) -> Vec3 {
        self.axes[2]
    }
    /// Vertex (a, b) in RAS.
    pub fn vertex(&self, a: usize, b: usize) -> Vec3 {
        let [eu, ev, n] = self.axes;
        self.origin
            + eu * (a as Real * self.h)
            + ev * (b as Real * self.h)
            + n * self.heights[a * self.nv + b]
    }
}

impl CutSurface for CpSurface {
    fn at(&self, u: Real, v: Real) -> SurfacePoint {
        let (nu, nv) = (self.nu, self.nv);
        let (x, y) = (
            u.clamp(0.0, 1.0) * (nu - 1) as Real,
            v.clamp(0.0, 1.0) * (nv - 1) as Real,
        );
        let (a0, b0) = (
            (x.floor() as usize).min(nu - 2),
            (y.floor() as usize).min(nv.saturating_sub(2)),
        );
        let (fa, fb) = (x - a0 as Real, y - b0 as Real);
        let b1 = (b0 + 1).min(nv - 1);
        let corners = [
            (a0, b0, (1.0 - fa) * (1.0 - fb)),
            (a0 + 1, b0, fa * (1.0 - fb)),
            (a0, b1, (1.0 - fa) * fb),
            (a0 + 1, b1, fa * fb),
        ];
        let (mut height, mut d) = (0.0, [0.0; 5]);
        for (a, b, w) in corners {
            height += w * self.heights[a * nv + b];
            for (acc, x) in d.iter_mut().zip(self.diffs[a * nv + b]) {
                *acc += w * x;
            }
        }
        let [eu, ev, n] = self.axes;
        // Grid steps per unit parameter.
        let (su, sv) = ((nu - 1) as Real, (nv - 1).max(1) as Real);
        SurfacePoint {
            p: self.origin + eu * (x * self.h) + ev * (y * self.h) + n * height,
            du: (eu * self.h + n * d[0]) * su,
            dv: (ev * self.h + n * d[1]) * sv,
            duu: n * (d[2] * su * su),
            duv: n * (d[3] * su * sv),
            dvv: n * (d[4] * sv * sv),
        }
    }

    fn speeds(&self) -> [Real; 2] {
        self.speeds
    }
}
