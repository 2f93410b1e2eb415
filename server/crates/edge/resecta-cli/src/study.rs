//! `resecta study methods`: Paper II's comparison of Bézier, DS and CP resections (thesis
//! Sec. 7.4–7.5, Table 7.2) **in silico**: a scripted user gives every method the same 16
//! inputs for each liver, tumour and margin, and the plans are measured with Sec. 7.4's metrics
//! (`resecta_plan::resection_metrics`, volumetry). It is not the surgeons' study: no person, no
//! planning time, no expert reference plan (the Bézier plan of the same case stands in for it).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use clap::{Args, Subcommand};
use resecta_geom::{LabelMap, Real, RoleMap, Vec3, Volume, VoxelLimit};
use resecta_io::read_label_map;
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::{
    Anatomy, Deformation, Plan, PlanError, PlanEvent, Planner, Resection, Target,
    VIOLATION_DEVIATION_MM, volume_deviation_pct,
};
use resecta_plot::{Colour, Figure, MarkerShape, Series, Style};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Paper II's comparison of Bézier, DS and CP resections with a scripted user (in silico).
    Methods(MethodsArgs),
}

#[derive(Debug, Args)]
pub struct MethodsArgs {
    /// Label maps whose tumour components are the targets; none: the built-in phantoms.
    pub labelmaps: Vec<PathBuf>,
    /// Folder for methods.md, methods.json, methods.svg and methods.png.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Safety margins (mm): every case runs once per margin.
    #[arg(long, value_delimiter = ',', default_value = "5,10")]
    pub margins: Vec<Real>,
    /// A liver mask (non-zero = liver) per label map, in the same order, for label maps without
    /// a liver label (the MSD hepatic-vessel cases): its voxels become parenchyma wherever the
    /// label map has no label.
    #[arg(long)]
    pub liver_mask: Vec<PathBuf>,
    /// Tumour label of the label maps; every other label is parenchyma (as `plan init` infers).
    #[arg(long, default_value_t = 2)]
    pub tumor_label: u16,
    /// Run the built-in phantoms too when label maps are given.
    #[arg(long)]
    pub with_phantoms: bool,
    /// Where the inner 2×2 inputs go: through the tumour's silhouette on P0 (`tumour`), or
    /// equally spaced with the outer ones (`regular`).
    #[arg(long, value_enum, default_value_t = Layout::Tumour)]
    pub layout: Layout,
    /// Rounds of margin feedback after the placement (round 0): while a plan's margin deviation
    /// is below −0.01 mm the scripted user pulls back the lifted inputs near the minimum; 0 =
    /// placement only.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(0..=50))]
    pub feedback_rounds: u32,
    /// Only the first phantom (for tests).
    #[arg(long)]
    pub quick: bool,
    /// Also write every case's plan (`resecta-plan/1`, the three resections) here, to look at
    /// or re-evaluate with `resecta plan`.
    #[arg(long)]
    pub plans_dir: Option<PathBuf>,
    /// The machine's name, written into methods.md.
    #[arg(long)]
    pub machine: Option<String>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Where the scripted user puts the inner 2×2 of the 4×4 inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// At ±a from the tumour's projection p0 on P0, a half the margin shell's radius seen along
    /// d (at most half the outer rows' offset).
    Tumour,
    /// Equally spaced: ±1/3 of the outer rows' offset.
    Regular,
}

pub fn run(c: &Command) -> Result<(), CliError> {
    match c {
        Command::Methods(a) => methods(a),
    }
}

/// Inputs every method gets per case (the thesis' 4×4 Bézier net).
const INPUTS: usize = 16;
/// The layout: 4×4 points.
const SIDE: usize = 4;
/// Points of the CP ring.
const RING_POINTS: usize = 12;
/// Sphere tracing stops this close (mm) to the margin shell.
const PUSH_TOLERANCE_MM: Real = 1e-3;
const PUSH_STEPS: usize = 400;
/// Tumours whose centroid is this close (mm) to the liver's give no direction.
const MIN_DIRECTION_MM: Real = 1.0;
/// Outer rows and slices lie at least this far (mm; 1.5 voxel spacings if more) beyond the liver.
const MIN_BEYOND_MM: Real = 5.0;
/// Targets whose bounding box is longer than this (mm) are flagged as not tumour-like.
const SPRAWLING_TARGET_MM: Real = 100.0;

/// The three methods, in the order of the tables.
const METHODS: [&str; 3] = ["bezier", "ds", "cp"];

fn method_title(m: &str) -> &'static str {
    match m {
        "bezier" => "Bézier",
        "ds" => "DS",
        _ => "CP",
    }
}

/// The thesis' Table 7.2 as printed (5 surgeons × 8 resections = 40 per method; curvature in
/// the unit the thesis prints, m⁻¹), and the violation counts of Sec. 7.5.
#[derive(Debug, Clone, Copy, Serialize)]
struct ThesisRow {
    method: &'static str,
    /// min, 25 %, 50 %, 75 %, max.
    margin_deviation_mm: [Real; 5],
    volume_deviation_pct: [Real; 5],
    median_mean_curvature_per_m_as_printed: [Real; 5],
    time_s: [Real; 5],
    violations: usize,
    n: usize,
}

const THESIS: [ThesisRow; 3] = [
    ThesisRow {
        method: "bezier",
        margin_deviation_mm: [-3.25, 0.13, 0.42, 1.47, 6.05],
        volume_deviation_pct: [-10.15, -1.83, -0.40, 1.17, 3.77],
        median_mean_curvature_per_m_as_printed: [0.00, 0.01, 0.01, 0.02, 0.02],
        time_s: [53.0, 126.5, 174.0, 244.0, 801.0],
        violations: 1,
        n: 40,
    },
    ThesisRow {
        method: "ds",
        margin_deviation_mm: [-7.98, -3.51, -1.49, 0.12, 8.53],
        volume_deviation_pct: [-7.07, -3.31, -1.39, 0.32, 6.69],
        median_mean_curvature_per_m_as_printed: [0.01, 0.01, 0.02, 0.02, 0.04],
        time_s: [44.0, 116.75, 179.0, 345.0, 757.0],
        violations: 28,
        n: 40,
    },
    ThesisRow {
        method: "cp",
        margin_deviation_mm: [-9.84, -7.65, -4.75, -1.04, 5.46],
        volume_deviation_pct: [-8.97, -4.93, -2.40, -0.56, 3.21],
        median_mean_curvature_per_m_as_printed: [0.01, 0.03, 0.03, 0.04, 0.11],
        time_s: [42.0, 129.75, 180.5, 250.5, 748.0],
        violations: 31,
        n: 40,
    },
];

/// One method's plan of one case.
#[derive(Debug, Clone, Serialize)]
struct MethodRecord {
    method: &'static str,
    inputs: usize,
    /// Inputs the scripted user moved off P0 (pushed towards the tumour).
    pushed_inputs: usize,
    /// The resection could not be built (the error), else `None`.
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    complete_cut: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    incomplete: Option<String>,
    resected_ml: Option<Real>,
    min_margin_mm: Option<Real>,
    margin_deviation_mm: Option<Real>,
    /// Against the Bézier plan of the same case.
    volume_deviation_pct: Option<Real>,
    median_abs_mean_curvature_per_mm: Option<Real>,
    /// Margin deviation below −0.01 mm.
    violation: bool,
    /// The margin feedback that led to this plan (after-feedback records only).
    #[serde(skip_serializing_if = "Option::is_none")]
    feedback: Option<Feedback>,
}

/// The scripted user's margin feedback on one plan.
#[derive(Debug, Clone, Default, Serialize)]
struct Feedback {
    /// Feedback rounds in which inputs were moved.
    rounds: usize,
    /// Inputs moved over those rounds (an input moved in two rounds counts twice).
    edits: usize,
    /// Why the user stopped.
    stop: String,
    /// The plan at round 0 (placement) and after each round: the planner's verdict.
    history: Vec<RoundRecord>,
}

/// The plan after one round (round 0: the placement).
#[derive(Debug, Clone, Serialize)]
struct RoundRecord {
    round: usize,
    /// Inputs moved in this round (round 0: the inputs the placement pushed).
    inputs_moved: usize,
    /// The largest pull-back of an input in this round (mm; 0 at round 0).
    largest_pull_mm: Real,
    /// The planner's verdict: minimum margin − m, and where the minimum is.
    margin_deviation_mm: Option<Real>,
    min_point: Option<[Real; 3]>,
}

/// One case: a liver, one target tumour, one margin.
#[derive(Debug, Clone, Serialize)]
struct CaseRecord {
    source: String,
    tumour: usize,
    label: u16,
    tumour_ml: Real,
    /// Largest side of the target's bounding box (mm): a tumour-like target is compact.
    target_extent_mm: Real,
    margin_mm: Real,
    /// Unit vector from the liver's centroid to the tumour's.
    direction: [Real; 3],
    /// A point of P0 (its normal is `direction`).
    plane_point: [Real; 3],
    /// CP deformations whose layout point lay beyond the cutting plane, moved to its edge.
    cp_deformations_moved_onto_plane: usize,
    liver_ml: Real,
    /// Round 0: the placement alone (volume deviation against the Bézier placement).
    placement: Vec<MethodRecord>,
    /// After margin feedback (volume deviation against the Bézier plan after feedback).
    methods: Vec<MethodRecord>,
}

/// A source that gave no cases, and why.
#[derive(Debug, Clone, Serialize)]
struct Skipped {
    source: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    tumour: Option<usize>,
    reason: String,
}

/// min, 25 %, 50 %, 75 %, max (R's default quantiles, type 7) and how many values.
#[derive(Debug, Clone, Copy, Serialize)]
struct Quantiles {
    n: usize,
    min: Real,
    q25: Real,
    median: Real,
    q75: Real,
    max: Real,
}

fn quantiles(values: &[Real]) -> Option<Quantiles> {
    let mut v: Vec<Real> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(Real::total_cmp);
    let q = |p: Real| {
        let h = (v.len() - 1) as Real * p;
        let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
        v[lo] + (h - lo as Real) * (v[hi] - v[lo])
    };
    Some(Quantiles {
        n: v.len(),
        min: v[0],
        q25: q(0.25),
        median: q(0.5),
        q75: q(0.75),
        max: v[v.len() - 1],
    })
}

#[derive(Debug, Clone, Serialize)]
struct MethodSummary {
    method: &'static str,
    /// Cases (plans) of this method.
    n: usize,
    inputs: usize,
    complete_cuts: usize,
    /// Plans whose margin deviation is below −0.01 mm.
    violations: usize,
    margin_deviation_mm: Option<Quantiles>,
    volume_deviation_pct: Option<Quantiles>,
    median_abs_mean_curvature_per_mm: Option<Quantiles>,
    /// Feedback rounds and edits (inputs moved) per plan; `None` for the placement.
    #[serde(skip_serializing_if = "Option::is_none")]
    feedback_rounds: Option<Quantiles>,
    #[serde(skip_serializing_if = "Option::is_none")]
    feedback_edits: Option<Quantiles>,
}

#[derive(Debug, Serialize)]
struct Report {
    study: &'static str,
    in_silico: bool,
    scripted_user: &'static str,
    margins_mm: Vec<Real>,
    inputs_per_method: usize,
    sources: Vec<String>,
    cases: usize,
    /// The most feedback rounds per plan (0: placement only).
    feedback_rounds: u32,
    /// After feedback: all cases, the phantoms alone, the label maps alone.
    summary: Vec<MethodSummary>,
    summary_phantoms: Vec<MethodSummary>,
    summary_labelmaps: Vec<MethodSummary>,
    /// Placement only (round 0): all cases, the phantoms alone, the label maps alone.
    summary_placement: Vec<MethodSummary>,
    summary_placement_phantoms: Vec<MethodSummary>,
    summary_placement_labelmaps: Vec<MethodSummary>,
    records: Vec<CaseRecord>,
    skipped: Vec<Skipped>,
    thesis_table_7_2: [ThesisRow; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    machine: Option<String>,
    command: String,
    time_ms: Real,
    files: Vec<PathBuf>,
}

const SCRIPTED_USER: &str = "For each case (liver, one tumour target, margin m): d = unit vector \
from the liver's centroid to the tumour's; P0 = the plane of normal d at distance m from the \
tumour's farthest voxel boundary along -d. Inputs: a 4x4 layout on P0 symmetric about the \
tumour's projection p0, outer rows beyond the liver contour, inner rows at +-a (a = half the \
margin shell's radius seen along d; --layout regular: equally spaced). Bezier: the layout on \
the initial grid's axes as control points; DS: 4 traces of 4 points on 4 axis-aligned slices \
(normal most perpendicular to d), outer slices beyond the liver; CP: a 12-point ring where P0 \
meets the liver surface plus 4 deformations at the inner layout points, radius 2a. Inner inputs \
are pushed towards the tumour (along d; DS: within the slice) until their distance to the \
tumour equals m, unless the ray misses the margin shell before the tumour centroid's depth. \
Feedback (up to --feedback-rounds rounds after this placement, round 0): while the planner's \
minimum margin is below m - 0.01 mm, every lifted input (one the placement pushed) moves back \
along its push direction by the violation (m - minimum) times w, w = 1 for the still-lifted \
input(s) nearest the minimum's point (distance across d) and a cosine falloff over the inner \
input spacing for the others (0 beyond); never past P0. Volume deviation is against the Bezier \
plan of the same case at the same stage (placement, after feedback).";

fn plan_err(e: PlanError) -> CliError {
    CliError::Failed(e.to_string())
}

fn arr(v: Vec3) -> [Real; 3] {
    [v.x, v.y, v.z]
}

fn vec3(p: [Real; 3]) -> Vec3 {
    Vec3::new(p[0], p[1], p[2])
}

/// A source of cases: a name, its label map and role map.
struct Source {
    name: String,
    phantom: bool,
    labels: LabelMap,
    roles: RoleMap,
}

/// The built-in phantoms: ellipsoid livers (one a union of two lobes) with spherical tumours at
/// several positions and radii, on oblique anisotropic grids.
fn phantom_specs() -> Vec<(&'static str, PhantomSpec)> {
    let spec = |dims, spacing, centre, tilt, liver, tumors| PhantomSpec {
        grid: GridSpec::centred(dims, spacing, centre, Orientation::EulerDeg(tilt)),
        liver,
        tumors,
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    };
    let ell = |center, radii, rot| EllipsoidSpec {
        center,
        radii,
        rotation: Orientation::EulerDeg(rot),
    };
    let ball = |center, radius| SphereSpec { center, radius };
    vec![
        (
            "phantom-ellipsoid-a",
            spec(
                [134, 107, 56],
                [1.5, 1.5, 2.5],
                [0.0, 0.0, 0.0],
                [5.0, -4.0, 8.0],
                vec![ell([0.0, 0.0, 0.0], [80.0, 60.0, 50.0], [0.0, 0.0, 0.0])],
                vec![
                    ball([40.0, 10.0, 5.0], 15.0),
                    ball([-20.0, 35.0, 15.0], 8.0),
                ],
            ),
        ),
        (
            "phantom-ellipsoid-b",
            spec(
                [200, 170, 47],
                [1.0, 1.0, 3.0],
                [0.0, 0.0, 0.0],
                [-8.0, 5.0, 3.0],
                vec![ell([0.0, 0.0, 0.0], [80.0, 60.0, 50.0], [0.0, 0.0, 20.0])],
                vec![
                    ball([-45.0, -10.0, 10.0], 10.0),
                    ball([20.0, 25.0, -5.0], 20.0),
                ],
            ),
        ),
        (
            "phantom-two-lobes",
            spec(
                [160, 110, 65],
                [1.2, 1.2, 2.0],
                [12.0, 8.0, 0.0],
                [3.0, 7.0, -5.0],
                vec![
                    ell([-15.0, 0.0, 0.0], [70.0, 55.0, 45.0], [0.0, 0.0, 0.0]),
                    ell([55.0, 15.0, 5.0], [45.0, 40.0, 35.0], [0.0, 10.0, -15.0]),
                ],
                vec![
                    ball([62.0, 15.0, 5.0], 12.0),
                    ball([-40.0, -20.0, -10.0], 16.0),
                ],
            ),
        ),
        (
            "phantom-large-tumour",
            spec(
                [175, 140, 70],
                [1.0, 1.0, 2.0],
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 12.0],
                vec![ell([0.0, 0.0, 0.0], [75.0, 58.0, 48.0], [10.0, 0.0, 0.0])],
                vec![ball([-30.0, 0.0, 8.0], 25.0)],
            ),
        ),
    ]
}

fn phantom_sources(quick: bool) -> Result<Vec<Source>, CliError> {
    let specs = phantom_specs();
    let take = if quick { 1 } else { specs.len() };
    specs
        .into_iter()
        .take(take)
        .map(|(name, spec)| {
            let p = generate(&spec).map_err(|e| CliError::Failed(format!("{name}: {e}")))?;
            Ok(Source {
                name: name.to_owned(),
                phantom: true,
                labels: p.labels,
                roles: RoleMap::default(),
            })
        })
        .collect()
}

/// The label map, with a liver mask's voxels as a new parenchyma label where it has none.
fn labelmap_source(
    path: &Path,
    mask: Option<&PathBuf>,
    tumour: u16,
) -> Result<Result<Source, String>, CliError> {
    let mut labels = read_label_map(path, VoxelLimit::default())?;
    let mut liver_label = None;
    if let Some(mask_path) = mask {
        let mask = read_label_map(mask_path, VoxelLimit::default())?;
        let (a, b) = (labels.grid(), mask.grid());
        let close = (a.affine() - b.affine()).abs().max() < 1e-3;
        if a.dims() != b.dims() || !close {
            return Err(CliError::BadInput(format!(
                "{}: its grid differs from {}'s",
                mask_path.display(),
                path.display()
            )));
        }
        let liver = labels.value_counts().keys().copied().max().unwrap_or(0) + 1;
        liver_label = Some(liver);
        let data = labels
            .data()
            .iter()
            .zip(mask.data())
            .map(|(&l, &m)| if l == 0 && m != 0 { liver } else { l })
            .collect();
        labels = Volume::from_vec(labels.grid().clone(), data)
            .map_err(|e| CliError::Failed(e.to_string()))?;
    }
    let counts = labels.value_counts();
    if !counts.contains_key(&tumour) {
        return Ok(Err(format!("tumour label {tumour} is not present")));
    }
    // As `plan init` infers it: the tumour label as tumour, every other label as parenchyma;
    // with a liver mask, the mask's label as parenchyma and the others as vessels (so that
    // vessels outside the liver do not count as liver).
    let others: Vec<u16> = counts
        .keys()
        .copied()
        .filter(|&l| l != 0 && l != tumour && Some(l) != liver_label)
        .collect();
    let json = match liver_label {
        None => serde_json::json!({"parenchyma": others, "tumor": [tumour]}),
        Some(liver) => {
            serde_json::json!({"parenchyma": [liver], "tumor": [tumour], "portal": others})
        }
    };
    let roles =
        serde_json::from_value(json).map_err(|e| CliError::BadInput(format!("roles: {e}")))?;
    Ok(Ok(Source {
        name: source_name(path),
        phantom: false,
        labels,
        roles,
    }))
}

fn source_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into(),
    )
}

/// Distance to the tumour's margin surface along a ray: how far `q` moves along the unit
/// `dir` until its distance to the tumour is `margin` (sphere tracing, never past the first
/// contact), or 0 when the ray does not reach the margin shell within `cap` mm.
fn push(distance: &dyn Fn(&Vec3) -> Real, q: Vec3, dir: Vec3, margin: Real, cap: Real) -> Real {
    let mut t = 0.0;
    for _ in 0..PUSH_STEPS {
        let gap = distance(&(q + dir * t)) - margin;
        if !gap.is_finite() {
            return 0.0;
        }
        if gap <= PUSH_TOLERANCE_MM {
            return t;
        }
        t += gap;
        if t > cap {
            return 0.0;
        }
    }
    0.0
}

/// `count` points spread evenly by arc length over the closed loops, as one trace per loop that
/// got points (closed by repeating its first point; at least 3 points each).
fn ring_traces(loops: &[Vec<Vec3>], count: usize) -> Vec<Vec<[Real; 3]>> {
    let seg_len = |l: &[Vec3]| -> Vec<Real> {
        (0..l.len())
            .map(|i| (l[(i + 1) % l.len()] - l[i]).norm())
            .collect()
    };
    let lengths: Vec<Vec<Real>> = loops.iter().map(|l| seg_len(l)).collect();
    let total: Real = lengths.iter().flatten().sum();
    if total <= 0.0 {
        return Vec::new();
    }
    let step = total / count as Real;
    let mut traces = Vec::new();
    let mut start = 0.0;
    let mut k = 0;
    for (l, segs) in loops.iter().zip(&lengths) {
        let len: Real = segs.iter().sum();
        let mut pts = Vec::new();
        while k < count {
            let s = (k as Real + 0.5) * step - start;
            if s >= len {
                break;
            }
            // Walk to the segment holding arc length s.
            let mut acc = 0.0;
            for (i, &sl) in segs.iter().enumerate() {
                if acc + sl >= s || i + 1 == segs.len() {
                    let f = if sl > 0.0 {
                        ((s - acc) / sl).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    pts.push(arr(l[i] + (l[(i + 1) % l.len()] - l[i]) * f));
                    break;
                }
                acc += sl;
            }
            k += 1;
        }
        start += len;
        if !pts.is_empty() {
            let first = pts[0];
            pts.push(first);
            while pts.len() < 3 {
                pts.push(first);
            }
            traces.push(pts);
        }
    }
    traces
}

/// Mean of the liver envelope's voxel centres.
fn liver_centroid(anatomy: &Anatomy) -> Option<Vec3> {
    let env = anatomy.envelope();
    let g = env.grid();
    let (sum, n) = env
        .data()
        .iter()
        .enumerate()
        .filter(|(_, b)| **b)
        .fold((Vec3::zeros(), 0usize), |(s, n), (k, _)| {
            (s + g.voxel_center(g.ijk(k)), n + 1)
        });
    (n > 0).then(|| sum / n as Real)
}

/// Where a lifted input lives in its resection.
#[derive(Debug, Clone, Copy)]
enum Slot {
    /// Bézier control point `i·n + j`.
    Control(usize),
    /// DS trace `i`, point `j`, kept on its slice (coordinate `axis` = `at`).
    Trace {
        i: usize,
        j: usize,
        axis: usize,
        at: Real,
    },
    /// CP deformation `k`; its offset is `sign` × the lift.
    Deformation { k: usize, sign: Real },
}

/// An input the placement pushed off P0: its point on P0, its push direction and how far it
/// is lifted now.
#[derive(Debug, Clone, Copy)]
struct Lifted {
    slot: Slot,
    base: Vec3,
    dir: Vec3,
    lift: Real,
}

impl Lifted {
    /// Writes the input's current position into the resection.
    fn apply(&self, r: &mut Resection) {
        let p = self.base + self.dir * self.lift;
        match self.slot {
            Slot::Control(x) => r.control_points[x] = arr(p),
            Slot::Trace { i, j, axis, at } => {
                let mut p = p;
                p[axis] = at;
                r.traces[i][j] = arr(p);
            }
            Slot::Deformation { k, sign } => r.deformations[k].offset_mm = sign * self.lift,
        }
    }
}

/// One feedback round: every still-lifted input moves back along its push direction by
/// `violation` × w, w = 1 for the still-lifted input(s) nearest `at` (distance across `d`),
/// else a cosine falloff over `spacing` beyond the nearest one's distance (0 past it); never
/// past P0. Returns how many inputs moved and the largest pull-back.
fn pull_back(
    lifted: &mut [Lifted],
    d: Vec3,
    at: Vec3,
    violation: Real,
    spacing: Real,
) -> (usize, Real) {
    let across = |l: &Lifted| {
        let x = at - l.base;
        (x - d * x.dot(&d)).norm()
    };
    let nearest = lifted
        .iter()
        .filter(|l| l.lift > PUSH_TOLERANCE_MM)
        .map(across)
        .fold(Real::INFINITY, Real::min);
    if !nearest.is_finite() {
        return (0, 0.0);
    }
    let (mut moved, mut largest) = (0, 0.0);
    for l in lifted.iter_mut() {
        let x = ((across(l) - nearest) / spacing.max(1e-6)).max(0.0);
        let w = if x >= 1.0 {
            0.0
        } else {
            0.5 * (1.0 + (std::f64::consts::PI * x).cos())
        };
        let lift = (l.lift - w * violation).max(0.0);
        let pull = l.lift - lift;
        if pull > PUSH_TOLERANCE_MM {
            moved += 1;
            largest = Real::max(largest, pull);
            l.lift = lift;
        }
    }
    (moved, largest)
}

struct Inputs {
    bezier: Resection,
    ds: Resection,
    cp: Resection,
    pushed: [usize; 3],
    /// Per method: the inputs the placement lifted, and the inner input spacing (mm).
    lifted: [Vec<Lifted>; 3],
    spacing: [Real; 3],
    /// CP deformations moved onto the cutting plane's extent.
    cp_clamped: usize,
    plane_point: Vec3,
}

/// The scripted user's inputs for one case (see [`SCRIPTED_USER`]).
fn script(
    planner: &mut Planner,
    anatomy: &Anatomy,
    k: usize,
    target: &Target,
    liver_c: Vec3,
    margin: Real,
    layout_kind: Layout,
) -> Result<(Inputs, Vec3), String> {
    let t = &anatomy.tumours()[k];
    let c = t.centroid;
    let to = c - liver_c;
    if to.norm() < MIN_DIRECTION_MM {
        return Err("the tumour's centroid is at the liver's: no direction".into());
    }
    let d = to.normalize();
    let near = t
        .mesh
        .vertices()
        .iter()
        .map(|v| v.dot(&d))
        .fold(Real::INFINITY, Real::min);
    let h0 = near - margin;
    let p0 = c - d * (c.dot(&d) - h0);
    let cap = c.dot(&d) - h0;
    let plane = resecta_plan::plane_from(p0, -d).map_err(|e| e.to_string())?;
    let (mut bezier, init) = planner
        .initial_on_plane("bezier", target, &plane, [SIDE, SIDE])
        .map_err(|e| e.to_string())?;
    let model = anatomy.target(&[k]).map_err(|e| e.to_string())?;
    let distance = |p: &Vec3| model.field.nearest(p).distance;
    let spacing = anatomy.envelope().grid().spacing();
    let beyond = (1.5 * spacing.iter().copied().fold(0.0, Real::max)).max(MIN_BEYOND_MM);
    // The inner offset: half the margin shell's radius seen along d (tumour layout), so the
    // inner inputs fall on the shell's near side.
    let lateral = t
        .mesh
        .vertices()
        .iter()
        .map(|v| {
            let x = v - c;
            (x - d * x.dot(&d)).norm()
        })
        .fold(0.0, Real::max);
    let inner = |half: Real| match layout_kind {
        Layout::Tumour => ((lateral + margin) / 2.0).min(half / 2.0),
        Layout::Regular => half / 3.0,
    };
    // The rows of the layout along an in-plane unit axis, symmetric about the tumour's
    // projection p0: the outer ones `beyond` past the liver contour on P0, the inner ones ±inner.
    let rows = |axis: Vec3| -> [Real; SIDE] {
        let half = init
            .contour
            .iter()
            .flat_map(|l| l.points.iter())
            .map(|p| (p - p0).dot(&axis).abs())
            .fold(0.0, Real::max)
            + beyond;
        let a = inner(half);
        [-half, -a, a, half]
    };

    // Bézier: the 4×4 layout on the initial grid's axes E1, E2, each point pushed along d.
    let [e1, e2] = init.axes.map(vec3);
    let (r1, r2) = (rows(e1), rows(e2));
    let layout: Vec<Vec3> = (0..SIDE * SIDE)
        .map(|x| p0 + e1 * r1[x / SIDE] + e2 * r2[x % SIDE])
        .collect();
    // Only the inner 2×2 move: the outer ring lies beyond the liver and keeps the cut complete.
    let is_inner = |i: usize| (1..SIDE - 1).contains(&i);
    let pushes: Vec<Real> = layout
        .iter()
        .enumerate()
        .map(|(x, &q)| {
            if is_inner(x / SIDE) && is_inner(x % SIDE) {
                push(&distance, q, d, margin, cap)
            } else {
                0.0
            }
        })
        .collect();
    bezier.control_points = layout
        .iter()
        .zip(&pushes)
        .map(|(&q, &s)| arr(q + d * s))
        .collect();
    bezier.margin_mm = margin;
    let moved = |p: &[Real]| p.iter().filter(|&&s| s > PUSH_TOLERANCE_MM).count();
    let bezier_lifted: Vec<Lifted> = layout
        .iter()
        .zip(&pushes)
        .enumerate()
        .filter(|(_, (_, s))| **s > PUSH_TOLERANCE_MM)
        .map(|(x, (&base, &lift))| Lifted {
            slot: Slot::Control(x),
            base,
            dir: d,
            lift,
        })
        .collect();

    // DS: 4 traces of 4 points on the slices whose normal is most perpendicular to d.
    let axis = (0..3)
        .min_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
        .unwrap_or(2);
    let mut e = Vec3::zeros();
    e[axis] = 1.0;
    let (lo, hi) = anatomy.liver_bounds().ok_or("empty liver")?;
    // In P0: û moves along the slice axis, w lies in every slice.
    let u = (e - d * d[axis]).normalize();
    let w = d.cross(&e).normalize();
    let rw = rows(w);
    // Slice positions: the outer ones beyond the liver's extent, the inner ones ±inner from p0
    // in P0 (so the inner traces cross the tumour's silhouette as the Bézier inner rows do).
    let half = ((p0[axis] - lo[axis]).max(hi[axis] - p0[axis]) + beyond) / u[axis];
    let a = inner(half);
    let slices = [-half, -a, a, half].map(|x| p0[axis] + x * u[axis]);
    let in_slice = {
        let mut s = d;
        s[axis] = 0.0;
        s.normalize()
    };
    let cap_slice = cap / in_slice.dot(&d).max(1e-6);
    let mut ds_pushes = Vec::with_capacity(INPUTS);
    let mut ds_lifted = Vec::new();
    let traces: Vec<Vec<[Real; 3]>> = slices
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let base = p0 + u * ((s - p0[axis]) / u[axis]);
            rw.iter()
                .enumerate()
                .map(|(j, &x)| {
                    let q = base + w * x;
                    let t = if is_inner(i) && is_inner(j) {
                        push(&distance, q, in_slice, margin, cap_slice)
                    } else {
                        0.0
                    };
                    let mut p = q + in_slice * t;
                    ds_pushes.push((p - q).norm());
                    if t > PUSH_TOLERANCE_MM {
                        ds_lifted.push(Lifted {
                            slot: Slot::Trace { i, j, axis, at: s },
                            base: q,
                            dir: in_slice,
                            lift: t,
                        });
                    }
                    // Exactly on the slice.
                    p[axis] = s;
                    arr(p)
                })
                .collect()
        })
        .collect();
    let mut ds = Resection::ds("ds", traces);
    ds.margin_mm = margin;
    ds.target = target.clone();

    // CP: the ring where P0 meets the liver surface, and the 4 inner pushes as deformations.
    let loops: Vec<Vec<Vec3>> = init
        .contour
        .iter()
        .filter(|l| l.points.len() >= 2)
        .map(|l| l.points.clone())
        .collect();
    let ring = ring_traces(&loops, RING_POINTS);
    let plane = resecta_traces::CpSurface::new(&ring, &[]).map_err(|e| format!("CP ring: {e}"))?;
    let sign = plane.normal().dot(&d).signum();
    // A deformation is clicked on the cutting plane: an inner point beyond its extent (a tumour
    // at the edge of the liver's cross-section) moves to the plane's nearest edge.
    let on_plane = |p: Vec3| -> (Vec3, bool) {
        let [nu, nv] = plane.dims();
        let o = plane.vertex(0, 0);
        let h = plane.quad_mm();
        let (eu, ev) = ((plane.vertex(1, 0) - o) / h, (plane.vertex(0, 1) - o) / h);
        let (a, b) = ((p - o).dot(&eu) / h, (p - o).dot(&ev) / h);
        let (ca, cb) = (
            a.clamp(0.0, (nu - 1) as Real),
            b.clamp(0.0, (nv - 1) as Real),
        );
        let moved = (ca - a).abs() > 1e-9 || (cb - b).abs() > 1e-9;
        (
            o + eu * (ca * h) + ev * (cb * h) + plane.normal() * (p - o).dot(&plane.normal()),
            moved,
        )
    };
    let mut clamped = 0;
    // The spacing of the inner inputs (mean of the two axes).
    let radius = ((r1[2] - r1[1]) + (r2[2] - r2[1])) / 2.0;
    let inner: Vec<usize> = (0..SIDE * SIDE)
        .filter(|&x| (1..SIDE - 1).contains(&(x / SIDE)) && (1..SIDE - 1).contains(&(x % SIDE)))
        .collect();
    let deformations = inner
        .iter()
        .map(|&x| {
            let (point, moved) = on_plane(layout[x]);
            clamped += usize::from(moved);
            Deformation {
                point: arr(point),
                offset_mm: sign * pushes[x],
                radius_mm: radius,
            }
        })
        .collect();
    let cp_pushed = moved(&inner.iter().map(|&x| pushes[x]).collect::<Vec<_>>());
    let cp_lifted: Vec<Lifted> = inner
        .iter()
        .enumerate()
        .filter(|&(_, &x)| pushes[x] > PUSH_TOLERANCE_MM)
        .map(|(k, &x)| Lifted {
            slot: Slot::Deformation { k, sign },
            base: layout[x],
            dir: d,
            lift: pushes[x],
        })
        .collect();
    let mut cp = Resection::cp("cp", ring, deformations);
    cp.margin_mm = margin;
    cp.target = target.clone();
    Ok((
        Inputs {
            bezier,
            ds,
            cp,
            pushed: [moved(&pushes), moved(&ds_pushes), cp_pushed],
            lifted: [bezier_lifted, ds_lifted, cp_lifted],
            // DS: the inner slices lie ±a from p0 in P0, the inner points ±rw[2] along them.
            spacing: [radius, (2.0 * a + (rw[2] - rw[1])) / 2.0, radius],
            cp_clamped: clamped,
            plane_point: p0,
        },
        d,
    ))
}

/// The target of tumour `k` alone: its label and a point on it.
fn target_of(anatomy: &Anatomy, k: usize) -> Result<Target, String> {
    let t = &anatomy.tumours()[k];
    let p = t
        .mesh
        .vertices()
        .iter()
        .min_by(|a, b| {
            (*a - t.centroid)
                .norm()
                .total_cmp(&(*b - t.centroid).norm())
        })
        .ok_or("tumour without a surface")?;
    let target = Target {
        labels: vec![t.label],
        points: vec![arr(*p)],
    };
    match anatomy.select(&target) {
        Ok(sel) if sel == [k] => Ok(target),
        Ok(sel) => Err(format!("a point on tumour {k} also picks tumours {sel:?}")),
        Err(e) => Err(e.to_string()),
    }
}

#[allow(clippy::too_many_arguments)]
fn run_case(
    anatomy: &Arc<Anatomy>,
    roles: &RoleMap,
    source: &str,
    k: usize,
    liver_c: Vec3,
    margin: Real,
    layout: Layout,
    feedback_rounds: usize,
    plans_dir: Option<&Path>,
) -> Result<CaseRecord, String> {
    let target = target_of(anatomy, k)?;
    let mut planner =
        Planner::new(Arc::clone(anatomy), Plan::new(roles.clone())).map_err(|e| e.to_string())?;
    let (mut inputs, d) = script(&mut planner, anatomy, k, &target, liver_c, margin, layout)?;
    inputs.bezier.target = target.clone();
    let mut errors: [Option<String>; 3] = [None, None, None];
    let mut resections = [inputs.bezier, inputs.ds, inputs.cp];
    for (m, r) in resections.iter().enumerate() {
        if let Err(e) = planner.edit(PlanEvent::AddResection {
            resection: r.clone(),
        }) {
            errors[m] = Some(e.to_string());
        }
    }
    if let Some(e) = &errors[0] {
        return Err(format!("the Bézier plan failed: {e}"));
    }
    let write_plan = |planner: &Planner, suffix: &str| -> Result<(), String> {
        if let Some(dir) = plans_dir {
            let file = dir.join(format!("{source}-tumour{k}-m{margin}{suffix}.json"));
            let text = planner.plan().to_json().map_err(|e| e.to_string())?;
            std::fs::write(&file, text).map_err(|e| format!("{}: {e}", file.display()))?;
        }
        Ok(())
    };
    write_plan(&planner, "")?;
    let measure = |planner: &mut Planner,
                   feedback: &[Option<Feedback>; 3]|
     -> Result<(Vec<MethodRecord>, Real), String> {
        let report = planner.volumes().map_err(|e| e.to_string())?;
        let find = |name: &str| report.resections.iter().find(|r| r.name == name);
        let reference = find("bezier").and_then(|r| r.resected_ml);
        let records = METHODS
            .iter()
            .enumerate()
            .map(|(m, &name)| {
                let v = find(name);
                let state = planner.state(name).ok();
                let dev = v.and_then(|v| v.metrics.margin_deviation_mm);
                MethodRecord {
                    method: name,
                    inputs: INPUTS,
                    pushed_inputs: inputs.pushed[m],
                    error: errors[m].clone(),
                    complete_cut: v.is_some_and(|v| v.complete_cut),
                    incomplete: v.and_then(|v| v.incomplete.as_ref().map(ToString::to_string)),
                    resected_ml: v.and_then(|v| v.resected_ml),
                    min_margin_mm: state.and_then(|s| s.verdict.min_margin_mm),
                    margin_deviation_mm: dev,
                    volume_deviation_pct: volume_deviation_pct(
                        v.and_then(|v| v.resected_ml),
                        reference,
                    ),
                    median_abs_mean_curvature_per_mm: v
                        .and_then(|v| v.metrics.median_abs_mean_curvature_per_mm),
                    violation: dev.is_some_and(|x| x < VIOLATION_DEVIATION_MM),
                    feedback: feedback[m].clone(),
                }
            })
            .collect();
        Ok((records, report.total_ml))
    };
    let (placement, liver_ml) = measure(&mut planner, &[None, None, None])?;

    // Margin feedback: the user reads the live verdict and pulls back the lifted inputs near
    // its minimum, round by round.
    let mut feedback: [Option<Feedback>; 3] = [None, None, None];
    for (m, &name) in METHODS.iter().enumerate() {
        if errors[m].is_some() {
            continue;
        }
        let mut fb = Feedback::default();
        let (mut moved, mut largest) = (inputs.pushed[m], 0.0);
        loop {
            let verdict = &planner.state(name).map_err(|e| e.to_string())?.verdict;
            let dev = verdict.min_margin_mm.map(|x| x - margin);
            let point = verdict.point;
            fb.history.push(RoundRecord {
                round: fb.rounds,
                inputs_moved: moved,
                largest_pull_mm: largest,
                margin_deviation_mm: dev,
                min_point: point.map(arr),
            });
            let (Some(dev), Some(point)) = (dev, point) else {
                fb.stop = "no surface inside the liver".into();
                break;
            };
            if dev >= VIOLATION_DEVIATION_MM {
                fb.stop = if fb.rounds == 0 {
                    "margin met at placement".into()
                } else {
                    "margin met".into()
                };
                break;
            }
            if fb.rounds >= feedback_rounds {
                fb.stop = "round limit".into();
                break;
            }
            let before = inputs.lifted[m].clone();
            (moved, largest) = pull_back(&mut inputs.lifted[m], d, point, -dev, inputs.spacing[m]);
            if moved == 0 {
                fb.stop = "no lifted input left to pull back".into();
                break;
            }
            let previous = resections[m].clone();
            for l in &inputs.lifted[m] {
                l.apply(&mut resections[m]);
            }
            planner
                .edit(PlanEvent::DeleteResection { name: name.into() })
                .map_err(|e| e.to_string())?;
            if let Err(e) = planner.edit(PlanEvent::AddResection {
                resection: resections[m].clone(),
            }) {
                // Keep the last plan that could be built.
                resections[m] = previous;
                inputs.lifted[m] = before;
                planner
                    .edit(PlanEvent::AddResection {
                        resection: resections[m].clone(),
                    })
                    .map_err(|e| e.to_string())?;
                fb.stop = format!("the pulled-back inputs give no surface: {e}");
                break;
            }
            fb.rounds += 1;
            fb.edits += moved;
        }
        feedback[m] = Some(fb);
    }
    let methods = if feedback.iter().flatten().any(|f| f.rounds > 0) {
        write_plan(&planner, "-feedback")?;
        measure(&mut planner, &feedback)?.0
    } else {
        placement
            .iter()
            .zip(&feedback)
            .map(|(r, f)| MethodRecord {
                feedback: f.clone(),
                ..r.clone()
            })
            .collect()
    };
    let t = &anatomy.tumours()[k];
    let (lo, hi) = t.mesh.vertices().iter().fold(
        (
            Vec3::repeat(Real::INFINITY),
            Vec3::repeat(Real::NEG_INFINITY),
        ),
        |(a, b), v| (a.inf(v), b.sup(v)),
    );
    Ok(CaseRecord {
        target_extent_mm: (hi - lo).max(),
        source: source.to_owned(),
        tumour: k,
        label: t.label,
        tumour_ml: t.volume_mm3 / 1000.0,
        margin_mm: margin,
        direction: arr(d),
        plane_point: arr(inputs.plane_point),
        cp_deformations_moved_onto_plane: inputs.cp_clamped,
        liver_ml,
        placement,
        methods,
    })
}

fn summarise(records: &[&CaseRecord], placement: bool) -> Vec<MethodSummary> {
    METHODS
        .iter()
        .enumerate()
        .map(|(m, &name)| {
            let rows: Vec<&MethodRecord> = records
                .iter()
                .map(|r| {
                    if placement {
                        &r.placement[m]
                    } else {
                        &r.methods[m]
                    }
                })
                .collect();
            let col = |f: &dyn Fn(&MethodRecord) -> Option<Real>| -> Vec<Real> {
                rows.iter().filter_map(|r| f(r)).collect()
            };
            MethodSummary {
                method: name,
                n: rows.len(),
                inputs: INPUTS,
                complete_cuts: rows.iter().filter(|r| r.complete_cut).count(),
                violations: rows.iter().filter(|r| r.violation).count(),
                margin_deviation_mm: quantiles(&col(&|r| r.margin_deviation_mm)),
                volume_deviation_pct: quantiles(&col(&|r| r.volume_deviation_pct)),
                median_abs_mean_curvature_per_mm: quantiles(&col(&|r| {
                    r.median_abs_mean_curvature_per_mm
                })),
                feedback_rounds: if placement {
                    None
                } else {
                    quantiles(&col(&|r| r.feedback.as_ref().map(|f| f.rounds as Real)))
                },
                feedback_edits: if placement {
                    None
                } else {
                    quantiles(&col(&|r| r.feedback.as_ref().map(|f| f.edits as Real)))
                },
            }
        })
        .collect()
}

pub fn methods(args: &MethodsArgs) -> Result<(), CliError> {
    let start = Instant::now();
    if args.margins.is_empty() || args.margins.iter().any(|&m| !(m > 0.0 && m <= 100.0)) {
        return Err(CliError::BadInput(
            "--margins: give margins in (0, 100] mm".into(),
        ));
    }
    if !args.liver_mask.is_empty() && args.liver_mask.len() != args.labelmaps.len() {
        return Err(CliError::BadInput(format!(
            "--liver-mask: {} masks for {} label maps (give one per label map, in order)",
            args.liver_mask.len(),
            args.labelmaps.len()
        )));
    }
    if let Some(dir) = &args.plans_dir {
        std::fs::create_dir_all(dir)
            .map_err(|e| CliError::Failed(format!("{}: {e}", dir.display())))?;
    }
    let pb = progress(args.json);
    pb.set_message("phantoms");
    let mut sources = Vec::new();
    if args.labelmaps.is_empty() || args.with_phantoms {
        sources.extend(phantom_sources(args.quick)?);
    }
    let mut skipped = Vec::new();
    for (i, path) in args.labelmaps.iter().enumerate() {
        pb.set_message(format!("reading {}", path.display()));
        match labelmap_source(path, args.liver_mask.get(i), args.tumor_label)? {
            Ok(s) => sources.push(s),
            Err(reason) => skipped.push(Skipped {
                source: source_name(path),
                tumour: None,
                reason,
            }),
        }
    }
    let mut records = Vec::new();
    let names: Vec<String> = sources
        .iter()
        .map(|s| s.name.clone())
        .chain(skipped.iter().map(|s| s.source.clone()))
        .collect();
    let mut phantom_names = Vec::new();
    for src in sources {
        if src.phantom {
            phantom_names.push(src.name.clone());
        }
        pb.set_message(format!("{}: anatomy", src.name));
        let anatomy = match Anatomy::new(&src.labels, &src.roles) {
            Ok(a) => Arc::new(a),
            Err(e) => {
                skipped.push(Skipped {
                    source: src.name.clone(),
                    tumour: None,
                    reason: e.to_string(),
                });
                continue;
            }
        };
        let liver_c = liver_centroid(&anatomy).ok_or_else(|| plan_err(PlanError::EmptyLiver))?;
        for k in 0..anatomy.tumours().len() {
            for &m in &args.margins {
                pb.set_message(format!("{}: tumour {k}, margin {m} mm", src.name));
                match run_case(
                    &anatomy,
                    &src.roles,
                    &src.name,
                    k,
                    liver_c,
                    m,
                    args.layout,
                    args.feedback_rounds as usize,
                    args.plans_dir.as_deref(),
                ) {
                    Ok(r) => records.push(r),
                    Err(reason) => skipped.push(Skipped {
                        source: src.name.clone(),
                        tumour: Some(k),
                        reason: format!("margin {m} mm: {reason}"),
                    }),
                }
            }
        }
    }
    pb.set_message("writing");
    let all: Vec<&CaseRecord> = records.iter().collect();
    let (ph, lm): (Vec<&CaseRecord>, Vec<&CaseRecord>) =
        all.iter().partition(|r| phantom_names.contains(&r.source));
    let mut report = Report {
        study: "methods",
        in_silico: true,
        scripted_user: SCRIPTED_USER,
        margins_mm: args.margins.clone(),
        inputs_per_method: INPUTS,
        sources: names,
        cases: records.len(),
        feedback_rounds: args.feedback_rounds,
        summary: summarise(&all, false),
        summary_phantoms: summarise(&ph, false),
        summary_labelmaps: summarise(&lm, false),
        summary_placement: summarise(&all, true),
        summary_placement_phantoms: summarise(&ph, true),
        summary_placement_labelmaps: summarise(&lm, true),
        records: Vec::new(),
        skipped,
        thesis_table_7_2: THESIS,
        machine: args.machine.clone(),
        command: command_line(),
        time_ms: 0.0,
        files: Vec::new(),
    };
    report.records = records;
    let write = crate::output::files_in(&args.out_dir)?;
    let figure = figure(&report);
    report.files = vec![
        args.out_dir.join("methods.md"),
        args.out_dir.join("methods.json"),
        args.out_dir.join("methods.svg"),
        args.out_dir.join("methods.png"),
    ];
    report.time_ms = ms(start);
    write("methods.md", markdown(&report).as_bytes())?;
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| CliError::Failed(format!("JSON: {e}")))?;
    write("methods.json", format!("{json}\n").as_bytes())?;
    write(
        "methods.svg",
        figure
            .to_svg()
            .map_err(|e| CliError::Failed(e.to_string()))?
            .as_bytes(),
    )?;
    write(
        "methods.png",
        &figure
            .to_png()
            .map_err(|e| CliError::Failed(e.to_string()))?,
    )?;
    pb.finish_and_clear();
    if args.json {
        return print_json(&report);
    }
    for (stage, s) in report
        .summary_placement
        .iter()
        .map(|s| ("round 0", s))
        .chain(report.summary.iter().map(|s| ("feedback", s)))
    {
        println!(
            "{stage:8} {:6} n {:3} · margin deviation median {} mm · volume deviation median {} % · median |H| {}·10⁻³ mm⁻¹ · violations {}/{} · complete {}/{}",
            method_title(s.method),
            s.n,
            fmt_q(s.margin_deviation_mm, |q| q.median, 2),
            fmt_q(s.volume_deviation_pct, |q| q.median, 2),
            fmt_q(s.median_abs_mean_curvature_per_mm, |q| q.median * 1e3, 3),
            s.violations,
            s.n,
            s.complete_cuts,
            s.n
        );
    }
    if !report.skipped.is_empty() {
        println!("{} case(s) skipped (see methods.md)", report.skipped.len());
    }
    println!(
        "{} cases in {:.0} s; wrote {}",
        report.cases,
        report.time_ms / 1e3,
        args.out_dir.display()
    );
    Ok(())
}

fn command_line() -> String {
    let quote = |a: String| {
        if !a.is_empty()
            && a.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_./,=:+".contains(c))
        {
            a
        } else {
            format!("'{}'", a.replace('\'', "'\\''"))
        }
    };
    let args: Vec<String> = std::env::args().skip(1).map(quote).collect();
    format!("resecta {}", args.join(" "))
}

fn fmt_q(q: Option<Quantiles>, f: impl Fn(&Quantiles) -> Real, digits: usize) -> String {
    q.map_or_else(|| "—".to_owned(), |q| format!("{:.digits$}", f(&q)))
}

fn med_iqr(q: Option<Quantiles>, scale: Real, digits: usize) -> String {
    q.map_or_else(
        || "—".to_owned(),
        |q| {
            format!(
                "{:.digits$} [{:.digits$}, {:.digits$}]",
                q.median * scale,
                q.q25 * scale,
                q.q75 * scale
            )
        },
    )
}

fn summary_table(out: &mut String, rows: &[MethodSummary]) {
    let feedback = rows.iter().any(|s| s.feedback_edits.is_some());
    out.push_str(
        "| method | plans | margin deviation (mm), median [25 %, 75 %] | volume deviation (%) | median \\|H\\| (10⁻³ mm⁻¹) | violations | complete cuts | inputs |",
    );
    out.push_str(if feedback {
        " feedback rounds, median [max] | feedback edits (inputs moved), median [max] |\n|---|---|---|---|---|---|---|---|---|---|\n"
    } else {
        "\n|---|---|---|---|---|---|---|---|\n"
    });
    let med_max = |q: Option<Quantiles>| {
        q.map_or_else(|| "—".to_owned(), |q| format!("{} [{}]", q.median, q.max))
    };
    for s in rows {
        let extra = if feedback {
            format!(
                " {} | {} |",
                med_max(s.feedback_rounds),
                med_max(s.feedback_edits)
            )
        } else {
            String::new()
        };
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} / {} | {} / {} | {} |{extra}\n",
            method_title(s.method),
            s.n,
            med_iqr(s.margin_deviation_mm, 1.0, 2),
            med_iqr(s.volume_deviation_pct, 1.0, 2),
            med_iqr(s.median_abs_mean_curvature_per_mm, 1e3, 2),
            s.violations,
            s.n,
            s.complete_cuts,
            s.n,
            s.inputs
        ));
    }
}

fn opt(v: Option<Real>, digits: usize) -> String {
    v.map_or_else(|| "—".to_owned(), |x| format!("{x:.digits$}"))
}

fn markdown(r: &Report) -> String {
    let mut o = String::new();
    o.push_str("# Methods comparison (thesis Sec. 7.4–7.5, Table 7.2) — in silico\n\n");
    o.push_str(
        "**This is an in-silico comparison with a scripted user, not the surgeons' study.** The \
thesis had 5 surgeons plan 8 resections each on 5 patients with Bézier, DS and CP, against an \
expert's reference plans, and timed them. Here one deterministic rule gives every method the \
same 16 inputs per case; there is no person, no planning time and no expert reference (the \
Bézier plan of the same case is the reference volume, so its volume deviation is 0 by \
construction). What it measures is what each method's *surface* does with the same intent: \
where it falls short of the margin, how much it resects, how curved it is — first as placed \
(round 0), then after a few rounds of *margin feedback*: resecta shows the live margin for every \
method, so the scripted user reads the planner's verdict and pulls back the inputs near the \
violation, the same rule for all three methods. (The thesis' DS and CP had no margin feedback, \
Table 7.1, one reason their margins were worse; its Bézier method had it.) Edits — inputs moved \
during feedback — stand in for the thesis' planning time.\n\n",
    );
    o.push_str("## The scripted user\n\nFor each case — a liver, one tumour component as the target, a margin m:\n\n");
    o.push_str(
        "- **Direction** d: the unit vector from the liver envelope's centroid (mean voxel centre) \
to the tumour's (mean voxel centre); the resected side holds the tumour.\n\
- **Target plane P0**: normal d, at distance m from the tumour's farthest point along −d (its \
voxels taken as cubes, which is what margins are measured to), i.e. touching the margin shell \
from the liver's side.\n\
- **Layout** (the same for every method): a 4×4 tensor layout on P0, symmetric about p0, the \
tumour's projection on P0. The outer rows and columns lie beyond the liver contour on P0 (its \
farthest point from p0 along each axis + 1.5 voxel spacings, at least 5 mm), so that the cut is \
complete; the inner 2×2 lie at ±a from p0, a = half the margin shell's radius seen along d \
(the tumour's largest distance from its axis + m, halved), so that they fall on the shell's \
near side. (`--layout regular` puts the inner rows at ±1/3 of the outer ones instead, an \
equally spaced layout: see *Why not an equally spaced layout* below.)\n\
- **Push**: an inner input q moves along the push direction towards the tumour until its \
distance to the tumour equals m (sphere tracing on the exact distance, so never past the first \
contact, to 10⁻³ mm); a point whose ray does not reach the margin shell before the depth of the \
tumour's centroid stays on P0. The outer ring is never pushed (it lies outside the liver). The \
intent is a bowl hugging the tumour at the margin.\n\
- **Bézier** (16 inputs): the layout on the axes E1, E2 of the initial grid of Algorithms 1–2 \
on P0 (`Planner::initial_on_plane`), the 16 (pushed) points as the 4×4 control points.\n\
- **DS** (16 inputs): 4 traces of 4 points on 4 parallel axis-aligned slices, the orientation \
whose normal is most perpendicular to d; the outer slices beyond the liver's extent along that \
axis (+1.5 voxel spacings, at least 5 mm), the inner ones through p0 ± a (in P0); each trace on \
the line where P0 meets its slice, its points at the layout's offsets along that line, the \
inner ones pushed along d's component within the slice.\n\
- **CP** (16 inputs): a ring of 12 points evenly by arc length on the liver contour where P0 \
meets the parenchyma surface (one closed trace per contour loop that gets points), and 4 \
deformations at the 4 inner points of the Bézier layout, each with that point's push as its \
offset (towards the tumour) and the inner spacing 2a as its radius (an inner point beyond the \
fitted plane's extent moves onto its edge, counted per case).\n\
- **Feedback** (rounds 1 … K, `--feedback-rounds K`, default 5; 0 = placement only): the \
planner's verdict gives the minimum tumour distance over the surface inside the liver and its \
point. While it is below m − 0.01 mm, every *lifted* input (one the placement pushed: Bézier \
control points, DS trace points, CP deformation offsets) moves back along its push direction \
by the violation v = m − minimum times w: w = 1 for the still-lifted input(s) nearest the \
minimum's point (distance measured across d, from the input's point on P0), and for the others \
w = ½(1 + cos(π·(r − r_nearest)/s)), 0 beyond s, s the inner input spacing (2a; DS: the mean \
of its inner slice and point spacings). No input goes past P0. A round's edits are the inputs \
that moved (by more than 10⁻³ mm); the user stops when the margin is met, after K rounds, or \
when no lifted input is left.\n\
- **Measured** per plan (`resecta_plan::resection_metrics`, Sec. 7.4): margin deviation (the \
minimum tumour distance over the surface inside the liver − m; a violation below −0.01 mm), \
volume deviation against the Bézier plan of the same case, median |H| (Eq. 7.10) over the \
samples inside the liver in mm⁻¹, whether the cut is complete, and the inputs; after feedback \
also the rounds and edits.\n\n\
*What the placement implies.* P0 touches the margin shell under the tumour, and the inner inputs \
sit on the shell's near side above P0; any surface through or near them passes above P0 between \
them, i.e. inside the shell right under the tumour. So every method falls short of the margin at \
round 0; how far is what differs: a Bézier surface only approaches its control points (the \
inner 2×2 weigh (3/8)² each, 0.56 together, at the centre), DS interpolates its traces, CP adds \
a cosine bump of full height at each deformation.\n\n\
*What the feedback implies.* Pulling back by the violation is a proportional correction: where \
the surface moves less than its inputs (Bézier at the centre: 0.56 of the pull), each round \
removes only part of the shortfall, so the deviation shrinks geometrically towards 0 but need \
not cross −0.01 mm within K rounds; the violation count is then a matter of hundredths of a \
millimetre and the median deviation says more.\n\n\
*Why not an equally spaced layout.* With the 4×4 inputs equally spaced over the liver's cross-\
section (the thesis' initial grid), the inner inputs sit a third of the way out from the \
centre, 20–50 mm from the tumour's axis: on the phantoms none of them reaches the margin shell \
(0 of 16 inputs moved in every case of `--quick --layout regular`), so all three methods plan \
P0 itself and the comparison is empty.\n\n",
    );
    if r.sources.iter().any(|n| n.starts_with("phantom-")) {
        o.push_str("**Phantoms** (`resecta-phantom`, built in; labels 1 liver, 2 tumour):\n\n");
        for (name, spec) in phantom_specs() {
            if !r.sources.iter().any(|n| n == name) {
                continue;
            }
            let g = &spec.grid;
            o.push_str(&format!(
                "- {name}: {} liver ellipsoid(s) (semi-axes {}), tumours {}; grid {}×{}×{} at {}×{}×{} mm, turned {:?}\n",
                spec.liver.len(),
                spec.liver
                    .iter()
                    .map(|e| format!("{:?}", e.radii))
                    .collect::<Vec<_>>()
                    .join(", "),
                spec.tumors
                    .iter()
                    .map(|t| format!("r {} mm at {:?}", t.radius, t.center))
                    .collect::<Vec<_>>()
                    .join(", "),
                g.dims[0], g.dims[1], g.dims[2], g.spacing[0], g.spacing[1], g.spacing[2],
                g.direction
            ));
        }
        o.push('\n');
    }
    o.push_str(&format!(
        "Margins: {} mm. Sources: {}. Cases (plans per method): **{}**.\n\n",
        r.margins_mm
            .iter()
            .map(|m| format!("{m}"))
            .collect::<Vec<_>>()
            .join(", "),
        r.sources.join(", "),
        r.cases
    ));
    o.push_str("## Results (Table 7.2's columns)\n\n");
    let both =
        r.summary_phantoms.iter().any(|s| s.n > 0) && r.summary_labelmaps.iter().any(|s| s.n > 0);
    let tables =
        |o: &mut String, all: &[MethodSummary], ph: &[MethodSummary], lm: &[MethodSummary]| {
            o.push_str("All cases:\n\n");
            summary_table(o, all);
            if both {
                o.push_str("\nPhantoms only:\n\n");
                summary_table(o, ph);
                o.push_str("\nLabel maps only:\n\n");
                summary_table(o, lm);
            }
        };
    o.push_str(
        "### Placement only (round 0)\n\nThe scripted placement, no feedback; volume deviation \
against the Bézier placement of the same case.\n\n",
    );
    tables(
        &mut o,
        &r.summary_placement,
        &r.summary_placement_phantoms,
        &r.summary_placement_labelmaps,
    );
    o.push_str(&format!(
        "\n### After feedback (at most {} round(s))\n\nThe same plans after the user's margin \
feedback; volume deviation against the Bézier plan of the same case *after feedback*. Edits are \
inputs moved over the feedback rounds (the placement's 16 inputs not counted) — our proxy for \
the thesis' planning time.\n\n",
        r.feedback_rounds
    ));
    tables(
        &mut o,
        &r.summary,
        &r.summary_phantoms,
        &r.summary_labelmaps,
    );
    o.push_str(
        "\n## The thesis' Table 7.2, for context\n\n5 surgeons × 8 resections = 40 plans per \
method on 5 Oslo-CoMet patients, against an expert's reference plans; figures as printed, \
violations from Sec. 7.5's text. The thesis prints curvature in m⁻¹; 0.01 m⁻¹ would be a radius \
of 100 m, while 0.01 mm⁻¹ is a radius of 100 mm, the order of what we measure — we read the \
printed values as most likely mm⁻¹ but show them as printed.\n\n\
| method | margin deviation (mm), median [25 %, 75 %] | volume deviation (%) | median mean curv. (as printed, \"1/m\") | violations | time (s), median |\n|---|---|---|---|---|---|\n",
    );
    for t in &r.thesis_table_7_2 {
        let f = |v: [Real; 5]| format!("{:.2} [{:.2}, {:.2}]", v[2], v[1], v[3]);
        o.push_str(&format!(
            "| {} | {} | {} | {} | {} / {} | {:.1} |\n",
            method_title(t.method),
            f(t.margin_deviation_mm),
            f(t.volume_deviation_pct),
            f(t.median_mean_curvature_per_m_as_printed),
            t.violations,
            t.n,
            t.time_s[2]
        ));
    }
    o.push_str("\n## Every case\n\nRound 0 = the placement; the other columns are the plan after feedback. Every round's verdict is in `methods.json` (`records[].methods[].feedback.history`).\n\n| source | tumour | tumour (ml) | m (mm) | method | pushed | round 0: margin dev. (mm) | round 0: volume dev. (%) | rounds | edits | stopped | complete | resected (ml, % of liver) | margin dev. (mm) | volume dev. (%) | median \\|H\\| (10⁻³ mm⁻¹) | violation |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for c in &r.records {
        for (m, p) in c.methods.iter().zip(&c.placement) {
            let fb = m.feedback.as_ref();
            o.push_str(&format!(
                "| {} | {} | {:.1} | {} | {} | {} / {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                c.source,
                c.tumour,
                c.tumour_ml,
                c.margin_mm,
                method_title(m.method),
                m.pushed_inputs,
                m.inputs,
                opt(p.margin_deviation_mm, 2),
                opt(p.volume_deviation_pct, 2),
                fb.map_or_else(|| "—".to_owned(), |f| f.rounds.to_string()),
                fb.map_or_else(|| "—".to_owned(), |f| f.edits.to_string()),
                fb.map_or("—", |f| f.stop.as_str()),
                match (&m.error, &m.incomplete, m.complete_cut) {
                    (Some(e), _, _) => format!("error: {e}"),
                    (_, _, true) => "yes".to_owned(),
                    (_, Some(why), _) => format!("no: {why}"),
                    _ => "no".to_owned(),
                },
                m.resected_ml.map_or_else(
                    || "—".to_owned(),
                    |v| format!("{v:.1} ({:.1} %)", 100.0 * v / c.liver_ml)
                ),
                opt(m.margin_deviation_mm, 2),
                opt(m.volume_deviation_pct, 2),
                opt(m.median_abs_mean_curvature_per_mm.map(|h| h * 1e3), 3),
                if m.violation { "**yes**" } else { "no" }
            ));
        }
    }
    let sprawling: Vec<&CaseRecord> = r
        .records
        .iter()
        .filter(|c| c.target_extent_mm > SPRAWLING_TARGET_MM && c.margin_mm == r.margins_mm[0])
        .collect();
    if !sprawling.is_empty() {
        o.push_str(&format!(
            "\n## Targets that are not tumour-like\n\nThese targets span more than {SPRAWLING_TARGET_MM} mm (largest side of their bounding box): a \
single component that size is not a tumour to resect with a margin (in the MSD hepatic-vessel \
label maps label 2 is one connected tree through the whole liver, most of it outside the \
predicted liver mask — it looks like vessels, not tumours; the test data's README already says \
the labels are unverified). Their rows measure the methods' geometry on a sprawling target, not \
a tumour resection, and are kept apart from the phantoms' above.\n\n"
        ));
        for c in sprawling {
            o.push_str(&format!(
                "- {}, tumour {}: {:.1} ml spanning {:.0} mm\n",
                c.source, c.tumour, c.tumour_ml, c.target_extent_mm
            ));
        }
    }
    if !r.skipped.is_empty() {
        o.push_str("\n## Skipped\n\n");
        for s in &r.skipped {
            o.push_str(&format!(
                "- {}{}: {}\n",
                s.source,
                s.tumour
                    .map_or_else(String::new, |k| format!(", tumour {k}")),
                s.reason
            ));
        }
    }
    o.push_str(
        "\n## Caveats\n\n\
- *Volumetry of non-uniform Bézier nets.* `resecta-volumetry` used to sample a cut uniformly \
in its parameters at a spacing from its iso-curve lengths, so that a net with close inner rows \
(this layout on a large liver) could be reported as a *leak* (MSD 002, m = 10 mm, before \
commit fc0337c); it now samples by the surface's speed and that plan cuts completely. Plans the \
planner reports incomplete are counted as such (no volume).\n\
- *CP's plane* is the ring's PCA plane with extents 4·√eᵢ: on a concave cross-section it may not \
reach every part of the liver, and the cut ends inside it (as CP does in commercial tools).\n\
- Volume deviation is only defined where both the plan and its Bézier reference cut completely.\n",
    );
    o.push_str(
        "\n## Figure\n\n![margin deviation against curvature](methods.png)\n\n\
`methods.svg`/`methods.png`: one marker per plan after feedback — x the median |H| inside the \
liver, y the margin deviation; the red line is the violation threshold (−0.01 mm).\n\n## Reproduce\n\n",
    );
    if let Some(m) = &r.machine {
        o.push_str(&format!("Machine: {m}. "));
    }
    o.push_str(&format!(
        "Run time {:.0} s.\n\n```sh\n{}\n```\n",
        r.time_ms / 1e3,
        r.command
    ));
    o
}

fn figure(r: &Report) -> Figure {
    let styles = [
        (MarkerShape::Circle, Colour::BLUE),
        (MarkerShape::Triangle, Colour::ORANGE),
        (MarkerShape::Square, Colour::GREEN),
    ];
    let mut series: Vec<Series> = METHODS
        .iter()
        .zip(styles)
        .enumerate()
        .map(|(m, (&name, (shape, colour)))| {
            let points = r
                .records
                .iter()
                .filter_map(|c| {
                    let x = &c.methods[m];
                    Some((
                        x.median_abs_mean_curvature_per_mm? * 1e3,
                        x.margin_deviation_mm?,
                    ))
                })
                .filter(|(a, b)| a.is_finite() && b.is_finite())
                .collect();
            Series::new(method_title(name), points, Style::Markers { shape, colour })
        })
        .collect();
    let xmax = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.0))
        .fold(0.0, Real::max);
    series.push(Series::new(
        "violation (−0.01 mm)",
        vec![
            (0.0, VIOLATION_DEVIATION_MM),
            (xmax.max(1e-3), VIOLATION_DEVIATION_MM),
        ],
        Style::Line {
            colour: Colour::RED,
        },
    ));
    Figure {
        title: format!(
            "Bézier, DS and CP, scripted user after ≤ {} feedback rounds (in silico, {} plans each)",
            r.feedback_rounds, r.cases
        ),
        x_label: "median |H| inside the liver (10⁻³ mm⁻¹)".into(),
        y_label: "margin deviation (mm)".into(),
        log_x: false,
        series,
        width: 1000,
        height: 700,
    }
}
