//! Per-vertex margins and classes of a sampled resection surface, and the global verdict.

use rayon::prelude::*;
use resecta_geom::{Real, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::MarginError;
use crate::field::{MarginField, check_len};

/// Safety margin and warning band (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MarginSettings {
    /// Closer than this to a tumour is a violation.
    pub margin_mm: f64,
    /// Within `margin_mm + band_mm` (but not a violation) is a warning.
    pub band_mm: f64,
}

impl MarginSettings {
    /// Checks margin > 0 and band ≥ 0, both finite.
    pub fn validate(&self) -> Result<(), MarginError> {
        if !(self.margin_mm.is_finite() && self.margin_mm > 0.0) {
            return Err(MarginError::BadMargin(self.margin_mm));
        }
        if !(self.band_mm.is_finite() && self.band_mm >= 0.0) {
            return Err(MarginError::BadBand(self.band_mm));
        }
        Ok(())
    }

    /// Class of a vertex at `distance` from the tumours with inside level `inside`.
    #[inline]
    pub fn classify(&self, distance: Real, inside: Real) -> MarginClass {
        if inside.is_nan() || inside <= 0.0 {
            MarginClass::Outside
        } else if distance < self.margin_mm {
            MarginClass::Violation
        } else if distance < self.margin_mm + self.band_mm {
            MarginClass::Warning
        } else {
            MarginClass::Safe
        }
    }
}

/// Margin class of a surface vertex.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
pub enum MarginClass {
    /// Outside the liver (inside level ≤ 0): does not count.
    Outside = 0,
    Safe = 1,
    /// Within the warning band beyond the margin.
    Warning = 2,
    /// Closer than the margin.
    Violation = 3,
}

/// What the verdict needs from the caller: the surface at any (u, v) ∈ [0, 1]² and the liver's
/// inside level (> 0 inside, ≤ 0 outside; e.g. a trilinear mask − 0.5).
pub trait SurfaceOracle {
    fn point(&self, u: f64, v: f64) -> Vec3;
    fn inside(&self, p: &Vec3) -> f64;
}

/// Per-vertex distances (mm) and classes, index `i·rv + j`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SurfaceMargins {
    pub distance: Vec<f64>,
    pub class: Vec<MarginClass>,
}

/// Global verdict over the part of the surface inside the liver.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// Smallest distance to a tumour over the surface inside the liver, refined between samples;
    /// `None` if no vertex is inside.
    pub min_margin_mm: Option<f64>,
    /// Where it is attained (serialised as `[x, y, z]`).
    #[serde(with = "opt_vec3")]
    pub point: Option<Vec3>,
    pub uv: Option<[f64; 2]>,
    /// `min_margin_mm < margin_mm`.
    pub violation: bool,
    /// Area inside the liver closer than the margin (linear interpolants on the grid triangles).
    pub violating_area_mm2: f64,
    /// Area inside the liver within the band beyond the margin.
    pub warning_area_mm2: f64,
    /// Area inside the liver.
    pub inside_area_mm2: f64,
    /// For tumours measured as voxel boundaries ([`MarginField::with_voxel_cell`]): half the
    /// voxel's extent along the direction of the minimum. `min_margin_mm` is the exact distance
    /// to the segmented voxels taken as cubes; the nearest tumour voxel centre lies at most this
    /// much farther (to first order in the cut's curvature). `None` otherwise.
    #[serde(default)]
    pub margin_uncertainty_mm: Option<f64>,
}

/// Per-vertex distances from [`evaluate`] inside the liver and possibly within margin + band
/// exceed the exact ones by at most this (mm); classes, the refined minimum and its point are
/// exact.
pub const TOLERANCE_MM: Real = 0.01;

/// Outside the liver distances only colour the hidden part of the surface and feed the clipped
/// areas' interpolation across the boundary: within this (mm).
pub const OUTSIDE_TOLERANCE_MM: Real = 0.25;

/// Inside the liver, a sample whose distance is certainly beyond margin + band (by
/// [`MarginField::lower_bound`]) is safe whatever its exact value; its distance only colours the
/// safe part of the surface: within this (mm).
pub const FAR_TOLERANCE_MM: Real = 0.25;

/// Search steps shrink to this in u and v ...
const UV_TOLERANCE: Real = 1e-6;
/// ... or until they move the surface point by less than this (mm).
const SPACE_TOLERANCE: Real = 1e-4;
/// Most refinement starts (vertex-grid local minima).
const MAX_STARTS: usize = 4;
/// Most rounds (4-point queries) per refinement start.
const MAX_ROUNDS: usize = 200;

/// Distances of one surface's samples kept between evaluations (see [`evaluate_reusing`]): per
/// sample, the point its distance was computed at and how far that distance may exceed the
/// exact one there (its slack).
#[derive(Debug, Clone, Default)]
pub struct MarginMemo {
    /// [`MarginField::id`] of the field the distances are to.
    field: u64,
    ru: usize,
    rv: usize,
    points: Vec<Vec3>,
    distance: Vec<Real>,
    slack: Vec<Real>,
    reused: usize,
}

impl MarginMemo {
    /// Samples whose distance the last evaluation kept without a query.
    pub fn reused(&self) -> usize {
        self.reused
    }

    fn holds(&self, field: &MarginField, ru: usize, rv: usize) -> bool {
        self.field == field.id() && (self.ru, self.rv) == (ru, rv) && self.points.len() == ru * rv
    }

    /// What the memo says of sample k now. The exact distance lies in [d − slack − δ, d + δ]
    /// (1-Lipschitz; δ the distance it moved). If the exact distances over its grid cells
    /// (within `radius` of it) are all beyond margin + band, its class is Safe and its value moves
    /// no clipped area: it keeps d while slack + δ stays within its tolerance, else it is at
    /// least far. Outside the liver with all its neighbours it only colours and keeps d within
    /// its tolerance too.
    fn recall(&self, grid: &Grid<'_>, k: usize, beyond: Real) -> Recall {
        let delta = (grid.points[k] - self.points[k]).norm();
        let (d, slack) = (self.distance[k], self.slack[k]);
        let clear = d - slack - delta - radius(grid.points, grid.ru, grid.rv, k) > beyond;
        let (tolerance, unseen) = if grid.inside[k] > 0.0 {
            (FAR_TOLERANCE_MM, clear)
        } else {
            let alone = || {
                neighbours(grid.ru, grid.rv, k)
                    .iter()
                    .all(|&(ok, m)| !ok || grid.inside[m] <= 0.0)
            };
            (OUTSIDE_TOLERANCE_MM, clear || alone())
        };
        match (unseen, delta + slack <= tolerance) {
            (true, true) => Recall::Keep(delta),
            (true, false) if grid.inside[k] > 0.0 => Recall::Far,
            _ => Recall::Unknown,
        }
    }
}

/// What a [`MarginMemo`] tells of a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Recall {
    /// Keeps its distance; the exact one may exceed it by this much.
    Keep(Real),
    /// Inside, with its cells certainly beyond margin + band, but moved too far to keep its value.
    Far,
    Unknown,
}

/// Per-vertex margins and classes for a sampled ru×rv grid (index `i·rv + j`, u along i), plus the
/// verdict. `inside[k]` is the inside level at vertex k.
pub fn evaluate(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
) -> Result<(SurfaceMargins, Verdict), MarginError> {
    let mut margins = SurfaceMargins::default();
    let verdict = evaluate_into(
        field,
        ru,
        rv,
        points,
        inside,
        settings,
        oracle,
        &mut margins,
    )?;
    Ok((margins, verdict))
}

/// [`evaluate`] into reused buffers (resized to ru·rv).
pub fn evaluate_into(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
    out: &mut SurfaceMargins,
) -> Result<Verdict, MarginError> {
    evaluate_with(field, ru, rv, points, inside, settings, oracle, None, out)
}

/// [`evaluate_into`] for one surface evaluated again and again (a drag): samples that moved
/// little since their distance was computed keep it without a query, while it stays within their
/// tolerance ([`FAR_TOLERANCE_MM`] inside the liver and certainly beyond margin + band,
/// [`OUTSIDE_TOLERANCE_MM`] outside) — such a kept distance may also be below the exact one, by
/// at most the distance the sample moved. Distances computed for `memo` use half those
/// tolerances, so a sample may move the other half before it is queried again. Classes, the
/// refined minimum and its point are as [`evaluate_into`]'s. `memo` starts empty and is
/// renewed when the field or the grid changes.
pub fn evaluate_reusing(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
    memo: &mut MarginMemo,
    out: &mut SurfaceMargins,
) -> Result<Verdict, MarginError> {
    evaluate_with(
        field,
        ru,
        rv,
        points,
        inside,
        settings,
        oracle,
        Some(memo),
        out,
    )
}

fn evaluate_with(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
    memo: Option<&mut MarginMemo>,
    out: &mut SurfaceMargins,
) -> Result<Verdict, MarginError> {
    let n = check_grid(ru, rv, points, inside, settings)?;
    out.distance.resize(n, 0.0);
    out.class.resize(n, MarginClass::Outside);
    let (m, w) = (settings.margin_mm, settings.margin_mm + settings.band_mm);
    let valid = memo.as_deref().filter(|mm| mm.holds(field, ru, rv));
    let recall: Vec<Recall> = match valid {
        Some(mm) => {
            let grid = Grid {
                ru,
                rv,
                points,
                inside,
                distance: &[],
            };
            (0..n)
                .into_par_iter()
                .map(|k| mm.recall(&grid, k, w))
                .collect()
        }
        None => vec![Recall::Unknown; n],
    };
    // kept[k]: Some(how far the exact distance may exceed the kept one).
    let kept: Vec<Option<Real>> = recall
        .iter()
        .map(|r| match r {
            Recall::Keep(delta) => Some(*delta),
            Recall::Far | Recall::Unknown => None,
        })
        .collect();
    if let Some(mm) = valid {
        for (k, d) in out.distance.iter_mut().enumerate() {
            if kept[k].is_some() {
                *d = mm.distance[k];
            }
        }
    }
    // Inside samples certainly beyond margin + band are safe whatever their exact distance.
    let far: Vec<bool> = (0..n)
        .into_par_iter()
        .map(|k| {
            inside[k] > 0.0 && (recall[k] != Recall::Unknown || field.lower_bound(&points[k]) > w)
        })
        .collect();
    // The share of a loose tolerance a computed distance may use (the rest is for moving).
    let share = if memo.is_some() { 0.5 } else { 1.0 };
    let tolerance = |k: usize| match (kept[k].is_some(), inside[k] > 0.0, far[k]) {
        (true, _, _) => Real::INFINITY,
        (false, false, _) => share * OUTSIDE_TOLERANCE_MM,
        (false, true, true) => share * FAR_TOLERANCE_MM,
        (false, true, false) => TOLERANCE_MM,
    };
    field.distances_grid_within(ru, rv, points, tolerance, &mut out.distance)?;
    // Slack of the distances computed in this call.
    let mut fresh: Vec<Option<Real>> = (0..n)
        .map(|k| kept[k].is_none().then(|| tolerance(k)))
        .collect();
    // A distance at most TOLERANCE_MM above a class threshold may belong below it: make those
    // exact, so classes (and what counts as a violation) are those of the exact distances.
    let near = |d: Real, t: Real| d >= t && d < t + TOLERANCE_MM;
    for (k, d) in out.distance.iter_mut().enumerate() {
        if inside[k] > 0.0 && (near(*d, m) || near(*d, w)) {
            *d = field.nearest(&points[k]).distance;
            fresh[k] = Some(0.0);
        }
    }
    // A far sample whose cells might hold the minimum is made exact too, so the refined minimum
    // starts from the same vertices as with exact distances everywhere: the minimum over its
    // cells is at least its exact distance minus its neighbourhood radius, and no more than the
    // lowest bound above an inside sample's exact distance.
    let lowest = (0..n)
        .filter(|&k| inside[k] > 0.0)
        .map(|k| out.distance[k] + kept[k].unwrap_or(0.0))
        .fold(Real::INFINITY, Real::min);
    for k in 0..n {
        if far[k] && out.distance[k] - FAR_TOLERANCE_MM - radius(points, ru, rv, k) < lowest {
            out.distance[k] = field.nearest(&points[k]).distance;
            fresh[k] = Some(0.0);
        }
    }
    if let Some(mm) = memo {
        if !mm.holds(field, ru, rv) {
            *mm = MarginMemo {
                field: field.id(),
                ru,
                rv,
                points: vec![Vec3::zeros(); n],
                distance: vec![Real::NAN; n],
                slack: vec![Real::INFINITY; n],
                reused: 0,
            };
        }
        mm.reused = fresh.iter().filter(|s| s.is_none()).count();
        for (k, slack) in fresh.iter().enumerate() {
            if let Some(slack) = slack {
                mm.points[k] = points[k];
                mm.distance[k] = out.distance[k];
                mm.slack[k] = *slack;
            }
        }
    }
    Ok(finish(field, ru, rv, points, inside, settings, oracle, out))
}

/// [`evaluate_into`] for distances computed elsewhere (an accelerator): `out.distance` holds
/// every sample's exact distance on entry; fills the classes and returns the verdict, exactly
/// as [`evaluate_into`] would from the same distances.
pub fn evaluate_exact_into(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
    out: &mut SurfaceMargins,
) -> Result<Verdict, MarginError> {
    let n = check_grid(ru, rv, points, inside, settings)?;
    check_len("distances", n, out.distance.len())?;
    out.class.resize(n, MarginClass::Outside);
    Ok(finish(field, ru, rv, points, inside, settings, oracle, out))
}

/// Checks the settings and that `points` and `inside` hold the ru×rv samples (ru, rv ≥ 2):
/// their count.
fn check_grid(
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
) -> Result<usize, MarginError> {
    settings.validate()?;
    if ru < 2 || rv < 2 {
        return Err(MarginError::GridTooSmall { ru, rv });
    }
    let n = ru
        .checked_mul(rv)
        .ok_or(MarginError::GridTooSmall { ru, rv })?;
    check_len("surface points", n, points.len())?;
    check_len("inside levels", n, inside.len())?;
    Ok(n)
}

/// Classes from the final distances, the clipped areas and the refined minimum.
#[allow(clippy::too_many_arguments)]
fn finish(
    field: &MarginField,
    ru: usize,
    rv: usize,
    points: &[Vec3],
    inside: &[f64],
    settings: &MarginSettings,
    oracle: &dyn SurfaceOracle,
    out: &mut SurfaceMargins,
) -> Verdict {
    for ((c, &d), &s) in out.class.iter_mut().zip(&out.distance).zip(inside) {
        *c = settings.classify(d, s);
    }
    let grid = Grid {
        ru,
        rv,
        points,
        inside,
        distance: &out.distance,
    };
    let areas = grid.areas(settings);
    let minimum = grid.minimum(field, oracle);
    let margin_uncertainty_mm = minimum.and_then(|m| {
        let towards = (m.point - field.nearest(&m.point).point).try_normalize(1e-12);
        field.half_voxel_extent(towards.as_ref())
    });
    Verdict {
        min_margin_mm: minimum.map(|m| m.distance),
        point: minimum.map(|m| m.point),
        uv: minimum.map(|m| m.uv),
        violation: minimum.is_some_and(|m| m.distance < settings.margin_mm),
        violating_area_mm2: areas.violating,
        warning_area_mm2: areas.warning,
        inside_area_mm2: areas.inside,
        margin_uncertainty_mm,
    }
}

/// The 8 neighbours of vertex k of an ru×rv grid, each with whether it exists; direct
/// neighbours first (most vertices are rejected as local minima by one of them).
fn neighbours(ru: usize, rv: usize, k: usize) -> [(bool, usize); 8] {
    let (i, j) = (k / rv, k % rv);
    let (up, down, left, right) = (i > 0, i + 1 < ru, j > 0, j + 1 < rv);
    [
        (left, k.wrapping_sub(1)),
        (right, k + 1),
        (up, k.wrapping_sub(rv)),
        (down, k + rv),
        (up && left, k.wrapping_sub(rv + 1)),
        (up && right, k.wrapping_sub(rv).wrapping_add(1)),
        (down && left, (k + rv).wrapping_sub(1)),
        (down && right, k + rv + 1),
    ]
}

/// Radius of vertex k's 2×2-cell neighbourhood: its largest distance to a neighbour.
fn radius(points: &[Vec3], ru: usize, rv: usize, k: usize) -> Real {
    neighbours(ru, rv, k)
        .iter()
        .filter(|(ok, _)| *ok)
        .map(|&(_, m)| (points[m] - points[k]).norm())
        .fold(0.0, Real::max)
}

struct Grid<'a> {
    ru: usize,
    rv: usize,
    points: &'a [Vec3],
    inside: &'a [f64],
    distance: &'a [f64],
}

#[derive(Debug, Clone, Copy, Default)]
struct Areas {
    violating: Real,
    warning: Real,
    inside: Real,
}

#[derive(Debug, Clone, Copy)]
struct Minimum {
    distance: Real,
    point: Vec3,
    uv: [Real; 2],
}

/// A polygon corner with the linear fields clipped against: [inside, margin − d, margin + band − d].
#[derive(Debug, Clone, Copy)]
struct Corner {
    p: Vec3,
    f: [Real; 3],
}

/// A convex polygon of at most 3 + 3 corners (a triangle clipped by up to three lines).
#[derive(Debug, Clone, Copy)]
struct Polygon {
    n: usize,
    c: [Corner; 6],
}

impl Polygon {
    /// Triangle `p` with the values of the three fields at its corners.
    fn triangle(p: [Vec3; 3], f: [[Real; 3]; 3]) -> Self {
        let corner = |i: usize| Corner {
            p: p[i],
            f: [f[0][i], f[1][i], f[2][i]],
        };
        let mut c = [corner(0); 6];
        c[1] = corner(1);
        c[2] = corner(2);
        Self { n: 3, c }
    }

    /// The part where field `k` is positive (exact for fields linear over the polygon).
    fn clip(&self, k: usize) -> Self {
        let mut out = Self { n: 0, c: self.c };
        for i in 0..self.n {
            let (a, b) = (&self.c[i], &self.c[(i + 1) % self.n]);
            let (fa, fb) = (a.f[k], b.f[k]);
            if fa > 0.0 {
                out.c[out.n] = *a;
                out.n += 1;
            }
            if (fa > 0.0) != (fb > 0.0) {
                let t = fa / (fa - fb);
                out.c[out.n] = Corner {
                    p: a.p + (b.p - a.p) * t,
                    f: std::array::from_fn(|m| a.f[m] + (b.f[m] - a.f[m]) * t),
                };
                out.n += 1;
            }
        }
        out
    }

    fn area(&self) -> Real {
        if self.n < 3 {
            return 0.0;
        }
        let o = self.c[0].p;
        let mut s = Vec3::zeros();
        for i in 1..self.n - 1 {
            s += (self.c[i].p - o).cross(&(self.c[i + 1].p - o));
        }
        0.5 * s.norm()
    }

    /// Sign of field `k` over the corners: `Some(true)` all positive, `Some(false)` none.
    fn all_positive(&self, k: usize) -> Option<bool> {
        let pos = self.c[..self.n].iter().filter(|c| c.f[k] > 0.0).count();
        match pos {
            0 => Some(false),
            p if p == self.n => Some(true),
            _ => None,
        }
    }

    /// Area where field `k` is positive.
    fn area_where(&self, k: usize, full: Real) -> (Real, Option<Self>) {
        match self.all_positive(k) {
            Some(true) => (full, None),
            Some(false) => (0.0, None),
            None => {
                let c = self.clip(k);
                (c.area(), Some(c))
            }
        }
    }
}

impl Grid<'_> {
    /// Areas of the grid triangles (as `resecta_bezier::grid_triangles`) clipped by the linear
    /// interpolants of the inside level and the distance; triangles entirely on one side of a
    /// level skip the clipping, and triangles with a non-finite corner value are left out. Summed
    /// per row in parallel, then rows in order (deterministic).
    fn areas(&self, s: &MarginSettings) -> Areas {
        let rv = self.rv;
        let (margin, warn) = (s.margin_mm, s.margin_mm + s.band_mm);
        let rows: Vec<Areas> = (0..self.ru - 1)
            .into_par_iter()
            .map(|a| {
                let mut acc = Areas::default();
                for b in 0..rv - 1 {
                    let q = [
                        a * rv + b,
                        (a + 1) * rv + b,
                        (a + 1) * rv + b + 1,
                        a * rv + b + 1,
                    ];
                    // Whole quad inside and on one side of both levels: no clipping.
                    let (h, d) = (q.map(|k| self.inside[k]), q.map(|k| self.distance[k]));
                    if h.iter().all(|&h| h.is_nan() || h <= 0.0) {
                        continue;
                    }
                    let (dmin, dmax) = (
                        d.iter().fold(Real::INFINITY, |m, &x| m.min(x)),
                        d.iter().fold(Real::NEG_INFINITY, |m, &x| m.max(x)),
                    );
                    let uniform = dmax < margin || dmin >= warn || (dmin >= margin && dmax < warn);
                    if uniform
                        && h.iter().all(|&h| h > 0.0 && h.is_finite())
                        && dmin.is_finite()
                        && dmax.is_finite()
                    {
                        let p = q.map(|k| self.points[k]);
                        let (e1, e2, e3) = (p[1] - p[0], p[2] - p[0], p[3] - p[0]);
                        let area = 0.5 * (e1.cross(&e2).norm() + e2.cross(&e3).norm());
                        acc.inside += area;
                        if dmax < margin {
                            acc.violating += area;
                        } else if dmax < warn {
                            acc.warning += area;
                        }
                        continue;
                    }
                    for tri in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                        let h = tri.map(|k| self.inside[k]);
                        let inside_count = h.iter().filter(|&&h| h > 0.0).count();
                        if inside_count == 0 {
                            continue;
                        }
                        let d = tri.map(|k| self.distance[k]);
                        let p = tri.map(|k| self.points[k]);
                        // A finite distance implies a finite point.
                        if !h.iter().chain(&d).all(|x| x.is_finite()) {
                            continue;
                        }
                        let full = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
                        let (dmin, dmax) = (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]));
                        if inside_count == 3
                            && (dmax < margin || dmin >= warn || (dmin >= margin && dmax < warn))
                        {
                            acc.inside += full;
                            if dmax < margin {
                                acc.violating += full;
                            } else if dmax < warn {
                                acc.warning += full;
                            }
                            continue;
                        }
                        let poly =
                            Polygon::triangle(p, [h, d.map(|d| margin - d), d.map(|d| warn - d)]);
                        let (inside, clipped) = poly.area_where(0, full);
                        if inside <= 0.0 {
                            continue;
                        }
                        let poly = clipped.unwrap_or(poly);
                        acc.inside += inside;
                        let (violating, _) = poly.area_where(1, inside);
                        let (warned, _) = poly.area_where(2, inside);
                        acc.violating += violating;
                        acc.warning += (warned - violating).max(0.0);
                    }
                }
                acc
            })
            .collect();
        rows.iter().fold(Areas::default(), |t, r| Areas {
            violating: t.violating + r.violating,
            warning: t.warning + r.warning,
            inside: t.inside + r.inside,
        })
    }

    fn uv(&self, k: usize) -> [Real; 2] {
        [
            (k / self.rv) as Real / (self.ru - 1) as Real,
            (k % self.rv) as Real / (self.rv - 1) as Real,
        ]
    }

    /// Inside vertices that are local minima of the distance among their inside 8-neighbours
    /// (ties broken by index), by increasing distance, each with the radius of its 2×2-cell
    /// neighbourhood (largest distance to a neighbour).
    fn local_minima(&self) -> Vec<(usize, Real)> {
        let (ru, rv) = (self.ru, self.rv);
        let d = self.distance;
        let usable = |k: usize| self.inside[k] > 0.0 && !d[k].is_nan();
        // (distance, index) of m below that of k.
        let lower = |m: usize, k: usize| usable(m) && (d[m] < d[k] || (d[m] == d[k] && m < k));
        let mut out: Vec<(usize, Real)> = (0..ru * rv)
            .into_par_iter()
            .filter(|&k| {
                usable(k)
                    && !neighbours(ru, rv, k)
                        .iter()
                        .any(|&(ok, m)| ok && lower(m, k))
            })
            .map(|k| (k, radius(self.points, ru, rv, k)))
            .collect();
        out.sort_by(|a, b| d[a.0].total_cmp(&d[b.0]).then(a.0.cmp(&b.0)));
        out
    }

    /// The refined minimum over the inside part: searches in (u, v) from the best vertex-grid
    /// local minima, each kept to the cells around its vertex and to inside points. A further
    /// start is tried (up to [`MAX_STARTS`]) only if its vertex distance minus its neighbourhood
    /// radius (a 1-Lipschitz bound for the cells around it) is below the best found so far.
    fn minimum(&self, field: &MarginField, oracle: &dyn SurfaceOracle) -> Option<Minimum> {
        let starts = self.local_minima();
        let mut best: Option<Minimum> = None;
        for &(k, radius) in starts.iter().take(MAX_STARTS) {
            // Vertex distances may be TOLERANCE_MM above the exact ones.
            if best.is_some_and(|b| self.distance[k] - TOLERANCE_MM - radius >= b.distance) {
                continue;
            }
            let m = self.refine(k, field, oracle);
            if best.is_none_or(|b| m.distance < b.distance) {
                best = Some(m);
            }
        }
        best
    }

    /// Compass search from vertex k over the cells around it. Each round measures the four
    /// neighbours at ±step in u and v together (one 4-point query) and moves to the best that
    /// improves (doubling that axis' step, up to the initial half cell). A neighbour outside the
    /// liver is first projected back onto it (Newton steps along the gradient of the inside level
    /// in (u, v)), so the search slides along the liver boundary where the minimum lies on it. If
    /// none improves, each step shrinks towards the minimiser of the parabola through the three
    /// values on its axis (by 1/16 to 1/2; 1/2 after a projection). Stops when both steps are
    /// below [`UV_TOLERANCE`] or move the surface by less than [`SPACE_TOLERANCE`].
    fn refine(&self, k: usize, field: &MarginField, oracle: &dyn SurfaceOracle) -> Minimum {
        let (ru, rv) = (self.ru, self.rv);
        let (du, dv) = (1.0 / (ru - 1) as Real, 1.0 / (rv - 1) as Real);
        let (i, j) = (k / rv, k % rv);
        let [u0, v0] = self.uv(k);
        let lo = [(u0 - du).max(0.0), (v0 - dv).max(0.0)];
        let hi = [(u0 + du).min(1.0), (v0 + dv).min(1.0)];
        // mm per unit of u and v around the vertex (largest neighbouring edge).
        let edge = |m: usize| (self.points[m] - self.points[k]).norm();
        let scale = [
            [i.saturating_sub(1), (i + 1).min(ru - 1)]
                .iter()
                .map(|&a| edge(a * rv + j))
                .fold(0.0, Real::max)
                / du,
            [j.saturating_sub(1), (j + 1).min(rv - 1)]
                .iter()
                .map(|&b| edge(i * rv + b))
                .fold(0.0, Real::max)
                / dv,
        ];
        let region = Region {
            lo,
            hi,
            delta: [1e-3 * du, 1e-3 * dv],
            oracle,
        };
        let mut best = Minimum {
            distance: field.nearest(&self.points[k]).distance,
            point: self.points[k],
            uv: [u0, v0],
        };
        let initial = [0.5 * du, 0.5 * dv];
        let mut step = initial;
        const DIRS: [(usize, Real); 4] = [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)];
        for _ in 0..MAX_ROUNDS {
            let candidates = DIRS.map(|(axis, sign)| {
                let mut uv = best.uv;
                uv[axis] = (uv[axis] + sign * step[axis]).clamp(lo[axis], hi[axis]);
                if uv == best.uv {
                    None
                } else {
                    region.feasible(uv)
                }
            });
            let pts = candidates.map(|c| c.map_or(best.point, |c| c.1));
            let near = field.nearest_group(&pts);
            let values: [Real; 4] =
                std::array::from_fn(|l| candidates[l].map_or(Real::INFINITY, |_| near[l].distance));
            let winner = (0..4)
                .filter(|&l| values[l] < best.distance)
                .min_by(|&a, &b| values[a].total_cmp(&values[b]));
            if let Some((l, c)) = winner.and_then(|l| candidates[l].map(|c| (l, c))) {
                best = Minimum {
                    distance: values[l],
                    point: c.1,
                    uv: c.0,
                };
                let axis = DIRS[l].0;
                step[axis] = (2.0 * step[axis]).min(initial[axis]);
                continue;
            }
            for axis in 0..2 {
                let (fp, fm) = (values[2 * axis], values[2 * axis + 1]);
                let projected = [2 * axis, 2 * axis + 1]
                    .iter()
                    .any(|&l| candidates[l].is_some_and(|c| c.2));
                let curvature = fp + fm - 2.0 * best.distance;
                let factor = if !projected && fp.is_finite() && fm.is_finite() && curvature > 0.0 {
                    let offset = 0.5 * (fm - fp) / curvature;
                    (1.5 * offset.abs()).clamp(1.0 / 16.0, 0.5)
                } else {
                    0.5
                };
                step[axis] *= factor;
            }
            if (step[0] < UV_TOLERANCE && step[1] < UV_TOLERANCE)
                || (step[0] * scale[0] < SPACE_TOLERANCE && step[1] * scale[1] < SPACE_TOLERANCE)
            {
                break;
            }
        }
        best
    }
}

/// The part of the (u, v) box `[lo, hi]` inside the liver.
struct Region<'a> {
    lo: [Real; 2],
    hi: [Real; 2],
    /// Finite-difference steps in u and v.
    delta: [Real; 2],
    oracle: &'a dyn SurfaceOracle,
}

impl Region<'_> {
    /// `uv` with its surface point if inside the liver, else its projection onto the liver by
    /// up to 4 Newton steps along the (u, v) gradient of the inside level (aiming 1 % past the
    /// zero level), flagged `true`; `None` if that fails.
    fn feasible(&self, uv: [Real; 2]) -> Option<([Real; 2], Vec3, bool)> {
        let o = self.oracle;
        let level = |uv: [Real; 2]| {
            let p = o.point(uv[0], uv[1]);
            (o.inside(&p), p)
        };
        let (mut h, mut p) = level(uv);
        if h > 0.0 {
            return Some((uv, p, false));
        }
        let mut uv = uv;
        for _ in 0..4 {
            let g: [Real; 2] = std::array::from_fn(|a| {
                let mut s = uv;
                s[a] += self.delta[a];
                (level(s).0 - h) / self.delta[a]
            });
            let gg = g[0] * g[0] + g[1] * g[1];
            if !(h.is_finite() && gg > 0.0 && gg.is_finite()) {
                return None;
            }
            let t = -1.01 * h / gg;
            uv = std::array::from_fn(|a| (uv[a] + t * g[a]).clamp(self.lo[a], self.hi[a]));
            (h, p) = level(uv);
            if h > 0.0 {
                return Some((uv, p, true));
            }
        }
        None
    }
}

/// Serde for `Option<Vec3>` as `Option<[f64; 3]>` (nalgebra is built without serde).
mod opt_vec3 {
    use resecta_geom::Vec3;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(v: &Option<Vec3>, s: S) -> Result<S::Ok, S::Error> {
        v.map(<[f64; 3]>::from).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec3>, D::Error> {
        Ok(Option::<[f64; 3]>::deserialize(d)?.map(Vec3::from))
    }
}
