//! `resecta plan`: evaluate a resection plan on a label map (margins, verdicts, volumes), and
//! `resecta plan init`: the initial resection for a tumour and an end point.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use clap::{Args, Subcommand};
use resecta_geom::{LabelMap, Real, RoleMap, Volume, VoxelLimit};
use resecta_io::{read_label_map, write_label_map, write_mesh};
use resecta_plan::{
    Anatomy, Plan, PlanError, PlanEvent, Planner, ResectionMetrics, RiskReport, Target,
    VolumeReport,
};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};

#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct PlanArgs {
    #[command(subcommand)]
    pub command: Option<PlanCommand>,
    /// Label map (NIfTI, NRRD, .seg.nrrd, MetaImage).
    #[arg(required = true)]
    pub labelmap: Option<PathBuf>,
    /// Plan file (`resecta-plan/1` JSON).
    #[arg(required = true)]
    pub plan: Option<PathBuf>,
    /// Write the resection surfaces (VTP with margin scalars), the resected label map, the
    /// normalised plan and the report here; with vessels also the risk map (`risk.nii.gz`:
    /// 1 functional remnant, 2 resected, 3 devascularised, 4 congested, 5 both) and the portal
    /// territories (`risk-territories.nii.gz`) on the functional liver's box.
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
    /// Future-liver-remnant warning threshold (% of the functional liver).
    #[arg(long, default_value_t = resecta_plan::DEFAULT_FLR_THRESHOLD_PCT)]
    pub flr_threshold: Real,
    /// A reference plan (`resecta-plan/1`) on the same label map: each resection's volume
    /// deviation is against the reference's resection of the same name.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Subcommand)]
pub enum PlanCommand {
    /// Print the initial plan for a tumour and an end point (thesis Algorithms 1–2).
    Init(InitArgs),
}

#[derive(Debug, Args)]
pub struct InitArgs {
    /// Label map.
    pub labelmap: PathBuf,
    /// Tumour label to resect.
    #[arg(long)]
    pub tumor_label: u16,
    /// End point x,y,z (RAS mm): the slicing plane is halfway between it and the tumour centroid.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true, required_unless_present = "plane_point")]
    pub end_point: Option<[Real; 3]>,
    /// Instead of an end point: a point x,y,z of the resection plane…
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true, requires = "plane_normal", conflicts_with = "end_point")]
    pub plane_point: Option<[Real; 3]>,
    /// …and its normal x,y,z (pointing away from the tumour).
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true, requires = "plane_point")]
    pub plane_normal: Option<[Real; 3]>,
    /// Role map JSON (default: the tumour label as tumour, every other label as parenchyma).
    #[arg(long)]
    pub roles: Option<String>,
    /// Pick the tumour component at (or within 5 mm of) this point x,y,z instead of every
    /// component of the label.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub tumor_point: Option<[Real; 3]>,
    /// Control grid m×n.
    #[arg(long, default_value = "4x4", value_parser = parse_grid)]
    pub grid: [usize; 2],
    /// Resection name.
    #[arg(long, default_value = "r1")]
    pub name: String,
    /// Safety margin (mm).
    #[arg(long, default_value_t = resecta_plan::resection::DEFAULT_MARGIN_MM)]
    pub margin: Real,
    /// Print one JSON object (the plan) on stdout; the default also prints the plan, with a
    /// summary on stderr.
    #[arg(long)]
    pub json: bool,
}

/// `x,y,z` as three finite numbers.
pub(crate) fn parse_point(s: &str) -> Result<[Real; 3], String> {
    let v: Vec<Real> = s
        .split(',')
        .map(|t| t.trim().parse::<Real>().map_err(|e| format!("{t:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
        _ => Err(format!("expected three finite numbers x,y,z, got {s:?}")),
    }
}

/// `MxN` (or `M×N`) as two numbers.
pub(crate) fn parse_grid(s: &str) -> Result<[usize; 2], String> {
    let (m, n) = s
        .split_once(['x', '×'])
        .ok_or_else(|| format!("expected MxN, got {s:?}"))?;
    let p = |t: &str| t.trim().parse::<usize>().map_err(|e| format!("{t:?}: {e}"));
    Ok([p(m)?, p(n)?])
}

pub(crate) fn plan_err(e: PlanError) -> CliError {
    match e {
        PlanError::Recon(_)
        | PlanError::Geometry(_)
        | PlanError::Margin(_)
        | PlanError::Volumetry(_) => CliError::Failed(e.to_string()),
        PlanError::Format(_)
        | PlanError::Json(_)
        | PlanError::InvalidResection { .. }
        | PlanError::UnknownResection(_)
        | PlanError::DuplicateName(_)
        | PlanError::TooManyResections(_)
        | PlanError::NonFinite { .. }
        | PlanError::InvalidArgument(_)
        | PlanError::NothingToUndo
        | PlanError::NothingToRedo
        | PlanError::HistoryFull(_)
        | PlanError::LabelAbsent(_)
        | PlanError::NotATumourLabel(_)
        | PlanError::NoTumour
        | PlanError::TumourOutsideLiver(_)
        | PlanError::NoTumourAtPoint(_)
        | PlanError::EndPointAtCentroid
        | PlanError::PlaneMissesLiver
        | PlanError::EmptyLiver
        | PlanError::Bezier(_) => CliError::BadInput(e.to_string()),
    }
}

pub(crate) fn read_labels(path: &Path) -> Result<LabelMap, CliError> {
    Ok(read_label_map(path, VoxelLimit::default())?)
}

pub fn run(args: &PlanArgs) -> Result<(), CliError> {
    match (&args.command, &args.labelmap, &args.plan) {
        (Some(PlanCommand::Init(a)), _, _) => init(a),
        (None, Some(labels), Some(plan)) => evaluate(args, labels, plan),
        _ => Err(CliError::BadInput(
            "usage: resecta plan LABELMAP PLAN.json | resecta plan init LABELMAP …".into(),
        )),
    }
}

#[derive(Debug, Serialize)]
struct ResectionReport {
    name: String,
    resected_ml: Option<Real>,
    resected_pct: Option<Real>,
    complete_cut: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    incomplete: Option<String>,
    margin_mm: Real,
    band_mm: Real,
    min_margin_mm: Option<Real>,
    /// Half a tumour voxel along the minimum's direction: the nearest voxel centre lies at most
    /// this much farther than `min_margin_mm` (the distance to the voxels as cubes).
    min_margin_uncertainty_mm: Option<Real>,
    min_margin_point: Option<[Real; 3]>,
    min_margin_uv: Option<[Real; 2]>,
    violation: bool,
    violating_area_mm2: Real,
    warning_area_mm2: Real,
    inside_area_mm2: Real,
    vertices: usize,
    metrics: ResectionMetrics,
}

#[derive(Debug, Serialize)]
struct PlanReport {
    total_ml: Real,
    remnant_ml: Option<Real>,
    remnant_pct: Option<Real>,
    resected_ml: Option<Real>,
    flr_threshold_pct: Real,
    flr_warning: Option<bool>,
    complete: bool,
    resections: Vec<ResectionReport>,
    /// Vessels cut and the remnant at risk, when the label map has portal or hepatic vessels.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    risk: Option<RiskReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    risk_unavailable: Option<String>,
    read_ms: Real,
    setup_ms: Real,
    margins_ms: Real,
    volumetry_ms: Real,
}

pub(crate) fn read_plan(path: &Path) -> Result<Plan, CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::BadInput(format!("{}: {e}", path.display())))?;
    Plan::from_json(&text).map_err(|e| CliError::BadInput(format!("{}: {e}", path.display())))
}

/// The volumes of the reference plan on the planner's anatomy (same roles).
fn reference_volumes(planner: &Planner, path: &Path) -> Result<VolumeReport, CliError> {
    planner
        .reference_volumes(read_plan(path)?)
        .map_err(|e| CliError::BadInput(format!("{}: {e}", path.display())))
}

fn evaluate(args: &PlanArgs, labels: &Path, plan_path: &Path) -> Result<(), CliError> {
    let pb = progress(args.json);
    let t0 = Instant::now();
    let plan = read_plan(plan_path)?;
    pb.set_message("reading the label map");
    let labels = read_labels(labels)?;
    let read_ms = ms(t0);
    pb.set_message("anatomy: liver envelope, surfaces, tumours");
    let t1 = Instant::now();
    let anatomy = Arc::new(Anatomy::new(&labels, &plan.roles).map_err(plan_err)?);
    let setup_ms = ms(t1);
    pb.set_message("margins");
    let t2 = Instant::now();
    let mut planner = Planner::new(anatomy, plan).map_err(plan_err)?;
    planner.flr_threshold_pct = args.flr_threshold;
    let margins_ms = ms(t2);
    pb.set_message("volumetry");
    let t3 = Instant::now();
    let mut volumes = planner.volumes().map_err(plan_err)?;
    if let Some(path) = &args.reference {
        pb.set_message("reference plan");
        volumes.compare_with(&reference_volumes(&planner, path)?);
    }
    let volumetry_ms = ms(t3);
    let report = report(
        &planner,
        volumes,
        [read_ms, setup_ms, margins_ms, volumetry_ms],
    )?;
    if let Some(dir) = &args.out_dir {
        pb.set_message("writing");
        write_outputs(&mut planner, dir, &report)?;
    }
    pb.finish_and_clear();
    if args.json {
        print_json(&report)
    } else {
        print_summary(&report);
        Ok(())
    }
}

fn report(
    planner: &Planner,
    v: VolumeReport,
    [read_ms, setup_ms, margins_ms, volumetry_ms]: [Real; 4],
) -> Result<PlanReport, CliError> {
    let volumes: BTreeMap<&str, _> = v.resections.iter().map(|r| (r.name.as_str(), r)).collect();
    let mut resections = Vec::new();
    for r in &planner.plan().resections {
        let s = planner.state(&r.name).map_err(plan_err)?;
        let vol = volumes.get(r.name.as_str());
        let verdict = &s.verdict;
        let metrics = vol.map(|x| x.metrics).ok_or_else(|| {
            CliError::Failed(format!("volumetry left out resection {:?}", r.name))
        })?;
        resections.push(ResectionReport {
            name: r.name.clone(),
            resected_ml: vol.and_then(|x| x.resected_ml),
            resected_pct: vol.and_then(|x| x.resected_pct),
            complete_cut: vol.is_some_and(|x| x.complete_cut),
            incomplete: vol.and_then(|x| x.incomplete.as_ref().map(|i| i.to_string())),
            margin_mm: r.margin_mm,
            band_mm: r.band_mm,
            min_margin_mm: verdict.min_margin_mm,
            min_margin_uncertainty_mm: verdict.margin_uncertainty_mm,
            min_margin_point: verdict.point.map(|p| resecta_plan::engine::point(&p)),
            min_margin_uv: verdict.uv,
            violation: verdict.violation,
            violating_area_mm2: verdict.violating_area_mm2,
            warning_area_mm2: verdict.warning_area_mm2,
            inside_area_mm2: verdict.inside_area_mm2,
            vertices: s.margins.distance.len(),
            metrics,
        });
    }
    Ok(PlanReport {
        total_ml: v.total_ml,
        remnant_ml: v.remnant_ml,
        remnant_pct: v.remnant_pct,
        resected_ml: v.resected_ml,
        flr_threshold_pct: v.flr_threshold_pct,
        flr_warning: v.flr_warning,
        complete: v.complete,
        resections,
        risk: v.risk,
        risk_unavailable: v.risk_unavailable,
        read_ms,
        setup_ms,
        margins_ms,
        volumetry_ms,
    })
}

fn write_outputs(planner: &mut Planner, dir: &Path, report: &PlanReport) -> Result<(), CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::Failed(format!("{}: {e}", dir.display())))?;
    let names: Vec<String> = planner
        .plan()
        .resections
        .iter()
        .map(|r| r.name.clone())
        .collect();
    for (k, name) in names.iter().enumerate() {
        let mesh = planner
            .state(name)
            .and_then(|s| s.mesh())
            .map_err(plan_err)?;
        write_mesh(dir.join(format!("resection-{k}.vtp")), &mesh)?;
    }
    let resected = planner.resected_labels().map_err(plan_err)?;
    let wide = Volume::from_vec(
        resected.grid().clone(),
        resected.data().iter().map(|&l| u16::from(l)).collect(),
    )
    .map_err(|e| CliError::Failed(e.to_string()))?;
    write_label_map(dir.join("resected.nii.gz"), &wide)?;
    // With vessels: the risk classes (resecta_plan::risk_class) and portal territories per
    // voxel of the functional liver's box.
    if let Some(m) = planner.risk_map().map_err(plan_err)? {
        let as_u16 = |v: Vec<u16>| {
            Volume::from_vec(m.grid.clone(), v).map_err(|e| CliError::Failed(e.to_string()))
        };
        write_label_map(
            dir.join("risk.nii.gz"),
            &as_u16(m.classes.iter().map(|&c| u16::from(c)).collect())?,
        )?;
        write_label_map(
            dir.join("risk-territories.nii.gz"),
            &as_u16(
                m.territories
                    .iter()
                    .map(|&t| u16::try_from(t).unwrap_or(u16::MAX))
                    .collect(),
            )?,
        )?;
    }
    let write = |file: &str, text: String| {
        std::fs::write(dir.join(file), text)
            .map_err(|e| CliError::Failed(format!("{}: {e}", dir.join(file).display())))
    };
    write("plan.json", planner.plan().to_json().map_err(plan_err)?)?;
    write(
        "report.json",
        serde_json::to_string_pretty(report).map_err(|e| CliError::Failed(e.to_string()))?,
    )
}

fn opt(v: Option<Real>, unit: &str) -> String {
    v.map_or_else(|| "—".to_owned(), |x| format!("{x:.1} {unit}"))
}

fn print_summary(r: &PlanReport) {
    println!(
        "liver {:.1} ml · remnant {} ({}) · FLR threshold {:.0} %{}",
        r.total_ml,
        opt(r.remnant_ml, "ml"),
        opt(r.remnant_pct, "%"),
        r.flr_threshold_pct,
        if r.flr_warning == Some(true) {
            " · WARNING: remnant below threshold"
        } else {
            ""
        }
    );
    if let Some(k) = &r.risk {
        println!(
            "functional remnant {:.1} ml ({:.1} %) · devascularised {:.1} ml · congested {:.1} ml · {} vessel(s) cut",
            k.functional_remnant_ml,
            k.functional_remnant_pct,
            k.devascularised_ml,
            k.congested_ml,
            k.cut_vessels.len()
        );
    }
    if let Some(why) = &r.risk_unavailable {
        println!("no risk analysis: {why}");
    }
    for s in &r.resections {
        println!(
            "{}: resected {} · min margin {} (margin {:.1} mm) · {} · violating {:.0} mm² · {}",
            s.name,
            opt(s.resected_ml, "ml"),
            opt(s.min_margin_mm, "mm"),
            s.margin_mm,
            if s.violation {
                "VIOLATION"
            } else {
                "margin kept"
            },
            s.violating_area_mm2,
            match &s.incomplete {
                None => "complete cut".to_owned(),
                Some(why) => format!("INCOMPLETE CUT: {why}"),
            }
        );
        let m = &s.metrics;
        println!(
            "  margin deviation {} · volume deviation {} · median |H| {}",
            opt(m.margin_deviation_mm, "mm"),
            opt(m.volume_deviation_pct, "%"),
            m.median_abs_mean_curvature_per_mm
                .map_or_else(|| "—".to_owned(), |h| format!("{h:.2e} mm⁻¹")),
        );
    }
}

fn init(args: &InitArgs) -> Result<(), CliError> {
    let labels = read_labels(&args.labelmap)?;
    let roles: RoleMap = match &args.roles {
        Some(s) => {
            serde_json::from_str(s).map_err(|e| CliError::BadInput(format!("--roles: {e}")))?
        }
        None => default_roles(&labels, args.tumor_label)?,
    };
    let anatomy = Arc::new(Anatomy::new(&labels, &roles).map_err(plan_err)?);
    let mut planner = Planner::new(anatomy, Plan::new(roles)).map_err(plan_err)?;
    let target = Target {
        labels: vec![args.tumor_label],
        points: args.tumor_point.into_iter().collect(),
    };
    let v = |[x, y, z]: [Real; 3]| resecta_geom::Vec3::new(x, y, z);
    let (mut resection, init) = match (args.end_point, args.plane_point, args.plane_normal) {
        (_, Some(p), Some(n)) => {
            let plane = resecta_plan::plane_from(v(p), v(n)).map_err(plan_err)?;
            planner.initial_on_plane(&args.name, &target, &plane, args.grid)
        }
        (Some(e), _, _) => planner.initial_resection(&args.name, &target, v(e), args.grid),
        _ => {
            return Err(CliError::BadInput(
                "give --end-point, or --plane-point with --plane-normal".into(),
            ));
        }
    }
    .map_err(plan_err)?;
    resection.margin_mm = args.margin;
    planner
        .edit(PlanEvent::AddResection { resection })
        .map_err(plan_err)?;
    if !args.json {
        eprintln!(
            "plane through {:?}, normal {:?}; contour extent {:.1} × {:.1} mm",
            init.plane_point, init.plane_normal, init.lengths[0], init.lengths[1]
        );
    }
    let text = planner.plan().to_json().map_err(plan_err)?;
    println!("{text}");
    Ok(())
}

/// The tumour label as tumour and every other present label as parenchyma.
fn default_roles(labels: &LabelMap, tumour: u16) -> Result<RoleMap, CliError> {
    let counts = labels.value_counts();
    if !counts.contains_key(&tumour) {
        return Err(CliError::BadInput(format!(
            "tumour label {tumour} is not present in the label map"
        )));
    }
    let others: Vec<u16> = counts
        .keys()
        .copied()
        .filter(|&l| l != 0 && l != tumour)
        .collect();
    let json = serde_json::json!({"parenchyma": others, "tumor": [tumour]});
    serde_json::from_value(json).map_err(|e| CliError::BadInput(format!("roles: {e}")))
}
