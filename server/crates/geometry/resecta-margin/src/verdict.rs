//! Per-vertex margins and classes of a sampled resection surface, and the global verdict
//! (the surgeons' request CB3): the minimum margin inside the liver refined over the continuous
//! surface, where it occurs, and the violating and warning areas.

use rayon::prelude::*;
use resecta_geom::{Real, Vec3};
use serde::Serialize;

use crate::error::MarginError;
use crate::field::{MarginField, Nearest};

/// The margin a resection must keep and the uncertainty band above it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MarginSettings {
    pub margin_mm: Real,
    pub band_mm: Real,
}

impl MarginSettings {
    /// Margin finite and > 0; band finite and ≥ 0.
    pub fn validate(&self) -> Result<(), MarginError> {
        if !(self.margin_mm.is_finite() && self.margin_mm > 0.0) {
            return Err(MarginError::Setting {
                what: "margin",
                bound: "> 0 mm",
                value: self.margin_mm,
            });
        }
        if !(self.band_mm.is_finite() && self.band_mm >= 0.0) {
            return Err(MarginError::Setting {
                what: "band",
                bound: "≥ 0 mm",
                value: self.band_mm,
            });
        }
        Ok(())
    }
}

/// What a surface vertex shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum MarginClass {
    /// Outside the liver: does not count (and may be hidden).
    Outside = 0,
    /// At least margin + band from every target tumour.
    Safe = 1,
    /// Within the band above the margin.
    Warning = 2,
    /// Closer than the margin.
    Violation = 3,
}

/// The surface at any (u, v) and the liver's inside level (> 0 inside, ≤ 0 outside).
pub trait SurfaceOracle: Sync {
    fn point(&self, u: Real, v: Real) -> Vec3;
    fn inside(&self, p: &Vec3) -> Real;
}

/// Per-vertex distance to the nearest target tumour (mm) and class.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SurfaceMargins {
    pub distance: Vec<Real>,
    pub class: Vec<MarginClass>,
}

/// The global verdict of one resection.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Verdict {
    /// Smallest distance from the part of the surface inside the liver to the tumours (`None`
    /// when no part of the surface is inside the liver).
    pub min_margin_mm: Option<Real>,
    /// Where it occurs (RAS) and its surface parameters.
    pub point: Option<Vec3>,
    pub uv: Option<[Real; 2]>,
    /// `min_margin_mm < margin`.
    pub violation: bool,
    /// Area inside the liver closer than the margin (mm²).
    pub violating_area_mm2: Real,
    /// Area inside the liver within the band above the margin (mm²).
    pub warning_area_mm2: Real,
    /// Area of the surface inside the liver (mm²).
    pub inside_area_mm2: Real,
}

/// Margins, classes and verdict of an ru×rv sample grid (`points[a·rv + b]` at
/// u = a/(ru−1), v = b/(rv−1)); `inside[k]` is the inside level at vertex k.
pub fn evaluate(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[Real],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
) -> Result<(SurfaceMargins, Verdict), MarginError> {
    settings.validate()?;
    if ru < 2 || rv < 2 {
        return Err(MarginError::Grid { ru, rv });
    }
    let n = ru.checked_mul(rv).ok_or(MarginError::Grid { ru, rv })?;
    for (what, got) in [("points", points.len()), ("inside levels", inside.len())] {
        if got != n {
            return Err(MarginError::Length {
                what,
                expected: n,
                got,
            });
        }
    }
    let mut nearest = vec![field.nearest(&Vec3::from_element(Real::NAN)); n];
    field.nearest_grid_into(rv, points, &mut nearest)?;
    let (m, w) = (settings.margin_mm, settings.margin_mm + settings.band_mm);
    // Exact answers where a class boundary lies between a distance and its lower bound.
    let uncertain: Vec<usize> = (0..n)
        .filter(|&k| {
            [m, w]
                .iter()
                .any(|&t| nearest[k].lower < t && t <= nearest[k].distance)
        })
        .collect();
    field.make_exact(points, &mut nearest, &uncertain);
    let distance: Vec<Real> = nearest.iter().map(|q| q.distance).collect();
    let class = distance
        .iter()
        .zip(inside)
        .map(|(&d, &i)| {
            if i <= 0.0 {
                MarginClass::Outside
            } else if d < m {
                MarginClass::Violation
            } else if d < w {
                MarginClass::Warning
            } else {
                MarginClass::Safe
            }
        })
        .collect();
    let mut verdict = areas(ru, rv, points, &distance, inside, m, w);
    let best = (0..n)
        .filter(|&k| inside[k] > 0.0)
        .min_by(|&a, &b| distance[a].total_cmp(&distance[b]));
    if let Some(k) = best {
        let start = [
            (k / rv) as Real / (ru - 1) as Real,
            (k % rv) as Real / (rv - 1) as Real,
        ];
        let (uv, p, q) = refine(field, oracle, start, nearest[k], points[k], [ru, rv]);
        let d = field.exact_from(&p, q).distance;
        verdict.min_margin_mm = Some(d);
        verdict.point = Some(p);
        verdict.uv = Some(uv);
        verdict.violation = d < m;
    }
    Ok((SurfaceMargins { distance, class }, verdict))
}

/// Minimises the distance over (u, v) around `start`, staying inside the liver: a 3×3 stencil
/// of step h, a Newton step on its quadratic fit, then h /= 4; never worse than `start`.
fn refine(
    field: &MarginField,
    oracle: &dyn SurfaceOracle,
    start: [Real; 2],
    q0: Nearest,
    p0: Vec3,
    [ru, rv]: [usize; 2],
) -> ([Real; 2], Vec3, Nearest) {
    let hint = q0.triangle;
    let eval = |uv: [Real; 2]| -> (Nearest, Vec3) {
        let p = oracle.point(uv[0], uv[1]);
        if oracle.inside(&p) > 0.0 {
            (field.nearest_hinted(&p, hint), p)
        } else {
            (field.nearest(&Vec3::from_element(Real::NAN)), p)
        }
    };
    let mut best_q = q0;
    let d0 = q0.distance;
    let clamp = |x: Real| x.clamp(0.0, 1.0);
    let (mut best, mut best_p, mut best_d) = (start, p0, d0);
    let mut h = [1.0 / (ru - 1) as Real, 1.0 / (rv - 1) as Real];
    for _ in 0..8 {
        let c = best;
        let mut vals = [[0.0; 3]; 3];
        let mut moved = None;
        for (a, row) in vals.iter_mut().enumerate() {
            for (b, val) in row.iter_mut().enumerate() {
                let uv = [
                    clamp(c[0] + (a as Real - 1.0) * h[0]),
                    clamp(c[1] + (b as Real - 1.0) * h[1]),
                ];
                let (q, p) = if a == 1 && b == 1 {
                    (best_q, best_p)
                } else {
                    eval(uv)
                };
                let d = q.distance;
                *val = d;
                if d < best_d && moved.as_ref().is_none_or(|&(md, _, _, _)| d < md) {
                    moved = Some((d, uv, p, q));
                }
            }
        }
        // Newton step on the quadratic through the stencil (when all nine are finite).
        if vals.iter().flatten().all(|v| v.is_finite()) {
            let gu = (vals[2][1] - vals[0][1]) / 2.0;
            let gv = (vals[1][2] - vals[1][0]) / 2.0;
            let huu = vals[2][1] - 2.0 * vals[1][1] + vals[0][1];
            let hvv = vals[1][2] - 2.0 * vals[1][1] + vals[1][0];
            let huv = (vals[2][2] - vals[2][0] - vals[0][2] + vals[0][0]) / 4.0;
            let det = huu * hvv - huv * huv;
            if huu > 0.0 && det > 0.0 {
                let su = (-(hvv * gu - huv * gv) / det).clamp(-1.0, 1.0);
                let sv = (-(huu * gv - huv * gu) / det).clamp(-1.0, 1.0);
                let uv = [clamp(c[0] + su * h[0]), clamp(c[1] + sv * h[1])];
                let (q, p) = eval(uv);
                let d = q.distance;
                if d < best_d && moved.as_ref().is_none_or(|&(md, _, _, _)| d < md) {
                    moved = Some((d, uv, p, q));
                }
            }
        }
        if let Some((d, uv, p, q)) = moved {
            (best, best_p, best_d, best_q) = (uv, p, d, q);
        }
        h = [h[0] / 4.0, h[1] / 4.0];
    }
    (best, best_p, best_q)
}

/// A polygon vertex with the three linear fields clipped against: inside, d − margin,
/// d − (margin + band).
#[derive(Debug, Clone, Copy)]
struct Vert {
    p: Vec3,
    f: [Real; 3],
}

/// Keeps the part of a convex polygon where field `k` is > 0 (`keep_positive`) or < 0.
fn clip(poly: &[Vert], k: usize, keep_positive: bool, out: &mut Vec<Vert>) {
    out.clear();
    let s = |v: &Vert| if keep_positive { v.f[k] } else { -v.f[k] };
    for (i, a) in poly.iter().enumerate() {
        let b = &poly[(i + 1) % poly.len()];
        let (sa, sb) = (s(a), s(b));
        if sa > 0.0 {
            out.push(*a);
        }
        if (sa > 0.0) != (sb > 0.0) {
            let t = sa / (sa - sb);
            out.push(Vert {
                p: a.p + (b.p - a.p) * t,
                f: std::array::from_fn(|j| a.f[j] + (b.f[j] - a.f[j]) * t),
            });
        }
    }
}

fn polygon_area(poly: &[Vert]) -> Real {
    if poly.len() < 3 {
        return 0.0;
    }
    let o = poly[0].p;
    let mut s = Vec3::zeros();
    for w in poly[1..].windows(2) {
        s += (w[0].p - o).cross(&(w[1].p - o));
    }
    s.norm() / 2.0
}

/// Inside, violating and warning areas: each grid triangle clipped by the linear interpolants
/// (exact for fields linear over the triangle). Summed per row, then in row order, so the
/// result does not depend on the thread count.
fn areas(
    ru: usize,
    rv: usize,
    points: &[Vec3],
    distance: &[Real],
    inside: &[Real],
    m: Real,
    w: Real,
) -> Verdict {
    let rows: Vec<[Real; 3]> = (0..ru - 1)
        .into_par_iter()
        .map(|a| {
            let mut sums = [0.0; 3];
            let (mut p1, mut p2, mut p3) = (Vec::new(), Vec::new(), Vec::new());
            let vert = |k: usize| Vert {
                p: points[k],
                f: [inside[k], distance[k] - m, distance[k] - w],
            };
            for b in 0..rv - 1 {
                let (k00, k10, k11, k01) = (
                    a * rv + b,
                    (a + 1) * rv + b,
                    (a + 1) * rv + b + 1,
                    a * rv + b + 1,
                );
                for tri in [[k00, k10, k11], [k00, k11, k01]] {
                    let t = tri.map(vert);
                    clip(&t, 0, true, &mut p1);
                    sums[0] += polygon_area(&p1);
                    clip(&p1, 1, false, &mut p2);
                    sums[1] += polygon_area(&p2);
                    clip(&p1, 2, false, &mut p3);
                    sums[2] += polygon_area(&p3);
                }
            }
            sums
        })
        .collect();
    let total = rows.iter().fold([0.0; 3], |acc, r| {
        [acc[0] + r[0], acc[1] + r[1], acc[2] + r[2]]
    });
    Verdict {
        inside_area_mm2: total[0],
        violating_area_mm2: total[1],
        warning_area_mm2: (total[2] - total[1]).max(0.0),
        ..Verdict::default()
    }
}
