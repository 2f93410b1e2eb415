//! A resection: a cut surface — a tensor-product Bézier surface given by its control points,
//! a surface drawn on slices (DS) or a deformable cutting plane (CP) given by traces — in RAS,
//! with the safety margin it must keep from its target tumours.

use std::sync::Arc;

use resecta_bezier::{ControlNet, MAX_CONTROL_POINTS};
use resecta_geom::{CutSurface, Mat3, Real, Vec3};
use resecta_traces::{CpSurface, Deformation, DsSurface};
use serde::{Deserialize, Serialize};

use crate::error::PlanError;

/// Default safety margin (mm), the usual oncological 10 mm.
pub const DEFAULT_MARGIN_MM: Real = 10.0;
/// Default uncertainty band (mm) above the margin in which the surface is shown as a warning.
pub const DEFAULT_BAND_MM: Real = 5.0;
/// Default interactive surface resolution (the thesis' 40×40).
pub const DEFAULT_RESOLUTION: [usize; 2] = [40, 40];
/// Most tumour labels one target names.
pub const MAX_TARGET_LABELS: usize = 64;
/// Most points one target picks components with.
pub const MAX_TARGET_POINTS: usize = 32;
/// Smallest surface resolution per direction.
pub const MIN_RESOLUTION: usize = 2;
/// Largest surface resolution per direction.
pub const MAX_RESOLUTION: usize = 500;
/// Fewest control points per grid direction (the most is [`MAX_CONTROL_POINTS`]).
pub const MIN_CONTROL_POINTS: usize = 2;
/// Largest absolute angle of one rotation (degrees): ten turns.
pub const MAX_ANGLE_DEG: Real = 3600.0;
/// Largest margin or band (mm).
pub const MAX_MARGIN_MM: Real = 100.0;
/// Coordinates beyond ±this (mm) are refused (no patient is a kilometre wide).
pub const MAX_COORDINATE_MM: Real = 1.0e5;
/// Longest resection name (bytes).
pub const MAX_NAME_LEN: usize = 128;

/// The kind of resection surface (thesis Table 7.1).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResectionKind {
    /// A Bézier surface given by its control points (`grid`, `control_points`).
    #[default]
    Bezier,
    /// Drawn on slices: 3 or more `traces` on parallel slices.
    Ds,
    /// A deformable cutting plane: `traces` on the liver surface and `deformations`.
    Cp,
}

impl ResectionKind {
    pub fn name(self) -> &'static str {
        match self {
            ResectionKind::Bezier => "Bézier",
            ResectionKind::Ds => "DS",
            ResectionKind::Cp => "CP",
        }
    }
}

/// Which tumours a resection must keep its margin from and resect: tumour labels (empty: every
/// tumour label of the role map) and, optionally, points picking single tumour components (the
/// component containing each point, or the nearest within 5 mm).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub labels: Vec<u16>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub points: Vec<[Real; 3]>,
}

/// One virtual resection, as stored in plan files (everything needed to rebuild it, nothing of
/// a session).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Resection {
    pub name: String,
    #[serde(default)]
    pub kind: ResectionKind,
    /// Bézier: control points per direction [m (along u), n (along v)]; [0, 0] for the others.
    #[serde(default, skip_serializing_if = "grid_is_none")]
    pub grid: [usize; 2],
    /// Bézier: m·n points, row-major: index i·n + j is P_ij; empty for the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub control_points: Vec<[Real; 3]>,
    /// DS and CP: the traces (polylines in RAS mm); empty for Bézier.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub traces: Vec<Vec<[Real; 3]>>,
    /// CP: local deformations, applied in order; empty for the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub deformations: Vec<Deformation>,
    #[serde(default = "default_margin")]
    pub margin_mm: Real,
    #[serde(default = "default_band")]
    pub band_mm: Real,
    #[serde(default, skip_serializing_if = "target_is_default")]
    pub target: Target,
    /// Surface samples per direction [ru, rv].
    #[serde(default = "default_resolution")]
    pub resolution: [usize; 2],
}

fn default_margin() -> Real {
    DEFAULT_MARGIN_MM
}
fn default_band() -> Real {
    DEFAULT_BAND_MM
}
fn default_resolution() -> [usize; 2] {
    DEFAULT_RESOLUTION
}
fn grid_is_none(g: &[usize; 2]) -> bool {
    *g == [0, 0]
}
fn target_is_default(t: &Target) -> bool {
    t == &Target::default()
}

/// A group of control points moved together (thesis Sec. 7.3.6), for any m×n grid by rings:
/// ring k holds the points whose distance (in grid steps) to the border of the grid is k.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Group {
    /// Every point not on the border (the 4 inner points of a 4×4 grid).
    Inner,
    /// The border ring (the 12 outer points of a 4×4 grid).
    Outer,
    /// Ring k (0 = outer).
    Ring(usize),
    /// Every point.
    All,
}

impl Group {
    /// Whether P_ij of an m×n grid belongs to the group.
    pub fn contains(self, m: usize, n: usize, i: usize, j: usize) -> bool {
        let ring = i.min(j).min(m - 1 - i).min(n - 1 - j);
        match self {
            Group::Inner => ring > 0,
            Group::Outer => ring == 0,
            Group::Ring(k) => ring == k,
            Group::All => true,
        }
    }
}

pub(crate) fn vec3(p: [Real; 3]) -> Vec3 {
    Vec3::new(p[0], p[1], p[2])
}

pub(crate) fn arr(v: Vec3) -> [Real; 3] {
    [v.x, v.y, v.z]
}

pub(crate) fn check_point(what: impl Fn() -> String, p: [Real; 3]) -> Result<(), PlanError> {
    if p.iter()
        .all(|c| c.is_finite() && c.abs() <= MAX_COORDINATE_MM)
    {
        Ok(())
    } else {
        Err(PlanError::NonFinite {
            what: what(),
            value: p,
        })
    }
}

pub(crate) fn check_length(what: &str, value: Real, min_exclusive: bool) -> Result<(), String> {
    let ok = value.is_finite()
        && value <= MAX_MARGIN_MM
        && if min_exclusive {
            value > 0.0
        } else {
            value >= 0.0
        };
    if ok {
        Ok(())
    } else {
        let bound = if min_exclusive { "> 0" } else { "≥ 0" };
        Err(format!(
            "{what} must be finite, {bound} and ≤ {MAX_MARGIN_MM} mm, got {value}"
        ))
    }
}

impl Resection {
    /// A Bézier resection with default margin, band and resolution.
    pub fn new(name: &str, grid: [usize; 2], control_points: Vec<[Real; 3]>) -> Self {
        Self {
            name: name.to_owned(),
            kind: ResectionKind::Bezier,
            grid,
            control_points,
            traces: Vec::new(),
            deformations: Vec::new(),
            margin_mm: DEFAULT_MARGIN_MM,
            band_mm: DEFAULT_BAND_MM,
            target: Target::default(),
            resolution: DEFAULT_RESOLUTION,
        }
    }

    /// Checks every field; the error names the resection and what is wrong.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |what: String| PlanError::resection(&self.name, what);
        if self.name.trim().is_empty() || self.name.len() > MAX_NAME_LEN {
            return Err(bad(format!(
                "name must be 1..={MAX_NAME_LEN} bytes and not blank"
            )));
        }
        match self.kind {
            ResectionKind::Bezier => self.validate_net()?,
            ResectionKind::Ds | ResectionKind::Cp => {
                self.shape()?;
            }
        }
        check_length("margin_mm", self.margin_mm, true).map_err(bad)?;
        check_length("band_mm", self.band_mm, false).map_err(bad)?;
        let [ru, rv] = self.resolution;
        let sides = MIN_RESOLUTION..=MAX_RESOLUTION;
        if !sides.contains(&ru) || !sides.contains(&rv) {
            return Err(bad(format!(
                "resolution {ru}×{rv}: each side must be {MIN_RESOLUTION}..={MAX_RESOLUTION}"
            )));
        }
        if self.target.labels.len() > MAX_TARGET_LABELS
            || self.target.points.len() > MAX_TARGET_POINTS
        {
            return Err(bad(format!(
                "target: at most {MAX_TARGET_LABELS} labels and {MAX_TARGET_POINTS} points"
            )));
        }
        for (k, &p) in self.target.points.iter().enumerate() {
            check_point(|| format!("resection {:?}: target point {k}", self.name), p)?;
        }
        Ok(())
    }

    fn validate_net(&self) -> Result<(), PlanError> {
        let bad = |what: String| PlanError::resection(&self.name, what);
        if !self.traces.is_empty() || !self.deformations.is_empty() {
            return Err(bad(
                "a Bézier resection has control points, not traces or deformations".into(),
            ));
        }
        let [m, n] = self.grid;
        let sides = MIN_CONTROL_POINTS..=MAX_CONTROL_POINTS;
        if !sides.contains(&m) || !sides.contains(&n) {
            return Err(bad(format!(
                "grid {m}×{n}: each side must be {MIN_CONTROL_POINTS}..={MAX_CONTROL_POINTS}"
            )));
        }
        if self.control_points.len() != m * n {
            return Err(bad(format!(
                "grid {m}×{n} needs {} control points, got {}",
                m * n,
                self.control_points.len()
            )));
        }
        for (k, &p) in self.control_points.iter().enumerate() {
            check_point(
                || format!("resection {:?}: control point {k}", self.name),
                p,
            )?;
        }
        Ok(())
    }

    /// A DS resection of `traces` with default margin, band and resolution.
    pub fn ds(name: &str, traces: Vec<Vec<[Real; 3]>>) -> Self {
        Self {
            kind: ResectionKind::Ds,
            grid: [0, 0],
            control_points: Vec::new(),
            traces,
            ..Self::new(name, [0, 0], Vec::new())
        }
    }

    /// A CP resection of `traces` and `deformations` with default margin and band.
    pub fn cp(name: &str, traces: Vec<Vec<[Real; 3]>>, deformations: Vec<Deformation>) -> Self {
        Self {
            kind: ResectionKind::Cp,
            deformations,
            ..Self::ds(name, traces)
        }
    }

    /// The cut surface (a DS or CP surface built from the traces: an error names what is wrong
    /// with them).
    pub fn shape(&self) -> Result<Arc<dyn CutSurface>, PlanError> {
        Ok(self.sampled_shape()?.0)
    }

    /// The cut surface and the samples per direction the planner evaluates it at: the
    /// resolution, or a CP's vertex grid (the surface is built once).
    pub fn sampled_shape(&self) -> Result<(Arc<dyn CutSurface>, [usize; 2]), PlanError> {
        let bad = |what: String| PlanError::resection(&self.name, what);
        let no_net = || {
            if self.grid == [0, 0] && self.control_points.is_empty() {
                Ok(())
            } else {
                Err(bad(format!(
                    "a {} resection is given by its traces, not a control grid",
                    self.kind.name()
                )))
            }
        };
        Ok(match self.kind {
            ResectionKind::Bezier => (Arc::new(self.net()?), self.resolution),
            ResectionKind::Ds => {
                no_net()?;
                if !self.deformations.is_empty() {
                    return Err(bad("deformations apply to CP resections only".into()));
                }
                let s = DsSurface::new(&self.traces).map_err(|e| bad(format!("DS: {e}")))?;
                (Arc::new(s), self.resolution)
            }
            ResectionKind::Cp => {
                no_net()?;
                let s = CpSurface::new(&self.traces, &self.deformations)
                    .map_err(|e| bad(format!("CP: {e}")))?;
                let dims = s.dims();
                (Arc::new(s), dims)
            }
        })
    }

    /// Refuses an edit of the wrong kind.
    fn require(&self, kinds: &[ResectionKind], edit: &str) -> Result<(), PlanError> {
        if kinds.contains(&self.kind) {
            Ok(())
        } else {
            Err(PlanError::resection(
                &self.name,
                format!("{edit} does not apply to a {} resection", self.kind.name()),
            ))
        }
    }

    /// Appends a trace (DS, CP).
    pub fn add_trace(&mut self, trace: Vec<[Real; 3]>) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Ds, ResectionKind::Cp], "adding a trace")?;
        self.traces.push(trace);
        Ok(())
    }

    /// Replaces (redraws) trace `index` (DS, CP).
    pub fn set_trace(&mut self, index: usize, trace: Vec<[Real; 3]>) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Ds, ResectionKind::Cp], "redrawing a trace")?;
        *self.trace_mut(index)? = trace;
        Ok(())
    }

    /// Removes trace `index` (DS, CP).
    pub fn remove_trace(&mut self, index: usize) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Ds, ResectionKind::Cp], "removing a trace")?;
        self.trace_mut(index)?;
        self.traces.remove(index);
        Ok(())
    }

    fn trace_mut(&mut self, index: usize) -> Result<&mut Vec<[Real; 3]>, PlanError> {
        let count = self.traces.len();
        self.traces.get_mut(index).ok_or_else(|| {
            PlanError::resection(
                &self.name,
                format!("trace {index} does not exist (the resection has {count})"),
            )
        })
    }

    /// Appends a deformation (CP).
    pub fn add_deformation(&mut self, d: Deformation) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Cp], "a deformation")?;
        self.deformations.push(d);
        Ok(())
    }

    /// Takes back the last deformation (CP).
    pub fn undo_deformation(&mut self) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Cp], "undoing a deformation")?;
        self.deformations
            .pop()
            .map(|_| ())
            .ok_or_else(|| PlanError::resection(&self.name, "it has no deformation to undo"))
    }

    /// Every point of the resection's definition moved by `f`: control points, or trace and
    /// deformation points.
    fn map_points(&mut self, f: impl Fn(Vec3) -> Vec3) -> Result<(), PlanError> {
        let mut next = self.clone();
        let g = |p: &mut [Real; 3]| *p = arr(f(vec3(*p)));
        next.control_points.iter_mut().for_each(g);
        next.traces.iter_mut().flatten().for_each(g);
        next.deformations.iter_mut().for_each(|d| g(&mut d.point));
        next.validate()?;
        *self = next;
        Ok(())
    }

    /// The control net (validated).
    pub fn net(&self) -> Result<ControlNet<Real>, PlanError> {
        Ok(ControlNet::new(
            self.grid[0],
            self.grid[1],
            self.control_points.clone(),
        )?)
    }

    /// Centroid of the control points, or of the trace points (the centre rotations default
    /// to).
    pub fn centre(&self) -> Vec3 {
        let pts = self
            .control_points
            .iter()
            .chain(self.traces.iter().flatten());
        let (sum, n) = pts.fold((Vec3::zeros(), 0usize), |(s, n), &p| (s + vec3(p), n + 1));
        sum / n.max(1) as Real
    }

    fn index(&self, i: usize, j: usize) -> Result<usize, PlanError> {
        let [m, n] = self.grid;
        if i < m && j < n {
            Ok(i * n + j)
        } else {
            Err(PlanError::resection(
                &self.name,
                format!("control point ({i}, {j}) is outside the {m}×{n} grid"),
            ))
        }
    }

    /// Moves P_ij to `p`.
    pub fn set_control_point(&mut self, i: usize, j: usize, p: [Real; 3]) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Bezier], "moving a control point")?;
        let k = self.index(i, j)?;
        check_point(|| format!("resection {:?}: point ({i}, {j})", self.name), p)?;
        self.control_points[k] = p;
        Ok(())
    }

    /// Replaces all control points (same grid).
    pub fn set_control_points(&mut self, points: &[[Real; 3]]) -> Result<(), PlanError> {
        self.require(&[ResectionKind::Bezier], "setting control points")?;
        let mut next = self.clone();
        next.control_points = points.to_vec();
        next.validate()?;
        *self = next;
        Ok(())
    }

    /// Moves every point of `group` by `delta` (a translation, [`Group::All`], moves any kind).
    pub fn move_group(&mut self, group: Group, delta: [Real; 3]) -> Result<(), PlanError> {
        check_point(|| format!("resection {:?}: delta", self.name), delta)?;
        if group == Group::All {
            let d = vec3(delta);
            return self.map_points(|p| p + d);
        }
        self.require(&[ResectionKind::Bezier], "moving a group of control points")?;
        let [m, n] = self.grid;
        if !(0..m * n).any(|k| group.contains(m, n, k / n, k % n)) {
            return Err(PlanError::resection(
                &self.name,
                format!("group {group:?} is empty on a {m}×{n} grid"),
            ));
        }
        let d = vec3(delta);
        let moved: Vec<[Real; 3]> = self
            .control_points
            .iter()
            .enumerate()
            .map(|(k, &p)| {
                if group.contains(m, n, k / n, k % n) {
                    arr(vec3(p) + d)
                } else {
                    p
                }
            })
            .collect();
        self.set_control_points(&moved)
    }

    /// Rotates every point by `angle_deg` about `axis` through `centre` (default: the centroid of
    /// the control points).
    pub fn rotate(
        &mut self,
        axis: [Real; 3],
        angle_deg: Real,
        centre: Option<[Real; 3]>,
    ) -> Result<(), PlanError> {
        check_point(|| format!("resection {:?}: rotation axis", self.name), axis)?;
        let a = vec3(axis);
        let norm = a.norm();
        if norm < 1e-12 || !angle_deg.is_finite() || angle_deg.abs() > MAX_ANGLE_DEG {
            return Err(PlanError::resection(
                &self.name,
                format!(
                    "rotation needs a non-zero axis and a finite angle within ±{MAX_ANGLE_DEG}°, got {axis:?}, {angle_deg}°"
                ),
            ));
        }
        let c = match centre {
            Some(c) => {
                check_point(|| format!("resection {:?}: rotation centre", self.name), c)?;
                vec3(c)
            }
            None => self.centre(),
        };
        let r = rotation(a / norm, angle_deg.to_radians());
        self.map_points(|p| c + r * (p - c))
    }
}

/// Rodrigues' rotation matrix about the unit axis `k`.
fn rotation(k: Vec3, angle: Real) -> Mat3 {
    let (s, c) = angle.sin_cos();
    let kx = Mat3::new(0.0, -k.z, k.y, k.z, 0.0, -k.x, -k.y, k.x, 0.0);
    Mat3::identity() + kx * s + kx * kx * (1.0 - c)
}
