//! `resecta reconstruct`, `models`, `measure` and `evaluate`: surface models (Paper I).

use std::path::{Path, PathBuf};
use std::time::Instant;

use resecta_geom::{LabelMap, Real, RoleMap, TriMesh, Volume, VoxelLimit};
use resecta_gpu::{GpuContext, gpu_poisson_solver};
use resecta_io::{read_label_map, read_mesh, write_mesh};
use resecta_poisson::{OrientedPoints, PoissonSolver};
use resecta_recon::study::{self, StudyConfig};
use resecta_recon::{
    McsdParams, ModelOptions, ParenchymaMethod, Quality, mask, mcsd, measure, patient_models, psr,
};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};

/// Where the Poisson multigrid runs (points, splatting and marching cubes stay on the host).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    Cpu,
    /// The first adapter of `WGPU_BACKEND` (all backends when unset).
    Gpu,
}

/// The adapter a GPU backend ran on.
#[derive(Debug, Clone, Serialize)]
pub struct Adapter {
    pub name: String,
    pub backend: String,
    pub driver: String,
    /// A software rasteriser (lavapipe): timings are correctness runs only.
    pub software: bool,
}

/// The solver of `backend`, with the adapter for the GPU; no adapter is [`CliError::Failed`]
/// naming the backends searched.
pub fn poisson_solver(backend: Backend) -> Result<(PoissonSolver, Option<Adapter>), CliError> {
    match backend {
        Backend::Cpu => Ok((PoissonSolver::cpu(), None)),
        Backend::Gpu => {
            let ctx =
                GpuContext::new().map_err(|e| CliError::Failed(format!("--backend gpu: {e}")))?;
            let adapter = Adapter {
                name: ctx.info.name.clone(),
                backend: format!("{:?}", ctx.info.backend).to_lowercase(),
                driver: format!("{} {}", ctx.info.driver, ctx.info.driver_info),
                software: ctx.is_software(),
            };
            Ok((gpu_poisson_solver(&ctx), Some(adapter)))
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Poisson surface reconstruction from the mask's oriented points.
    Psr,
    /// Marching cubes, decimation, windowed-sinc smoothing (3D Slicer's method).
    Mcsd,
}

/// `--depth 7` or `--depth auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthArg {
    Fixed(u32),
    Auto,
}

fn parse_depth(s: &str) -> Result<DepthArg, String> {
    if s == "auto" {
        return Ok(DepthArg::Auto);
    }
    s.parse::<u32>()
        .map(DepthArg::Fixed)
        .map_err(|_| format!("depth must be an integer in 1..=10 or `auto`, got `{s}`"))
}

#[derive(Debug, clap::Args)]
pub struct ReconstructArgs {
    /// Label map (NIfTI, NRRD, .seg.nrrd, MetaImage).
    pub input: PathBuf,
    /// Labels forming the object, comma-separated.
    #[arg(long, value_delimiter = ',', required = true,
          value_parser = clap::value_parser!(u16).range(1..))]
    pub labels: Vec<u16>,
    #[arg(long, value_enum, default_value_t = Method::Psr)]
    pub method: Method,
    /// PSR depth (finest grid 2^d cells across the points' bounding cube × 1.1), or `auto` for
    /// the σ-optimal depth in 5..=8 for this mask.
    #[arg(long, value_parser = parse_depth, default_value = "7")]
    pub depth: DepthArg,
    /// MCSD smoothing factor in [0, 1] (Slicer's; 0 = off).
    #[arg(long, default_value_t = 0.5)]
    pub smoothing: Real,
    /// MCSD decimation: fraction of triangles removed, in [0, 1).
    #[arg(long, default_value_t = 0.0)]
    pub decimation: Real,
    /// Output mesh (.vtp, .vtk, .stl, .ply, .obj), RAS.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the oriented points (positions and outward normals) as PLY.
    #[arg(long)]
    pub points_out: Option<PathBuf>,
    /// Where PSR's multigrid runs.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct ReconstructSummary {
    method: Method,
    labels: Vec<u16>,
    #[serde(skip_serializing_if = "Option::is_none")]
    depth: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    smoothing: Option<Real>,
    #[serde(skip_serializing_if = "Option::is_none")]
    decimation: Option<Real>,
    /// Where PSR's multigrid ran, and on which adapter.
    backend: Backend,
    #[serde(skip_serializing_if = "Option::is_none")]
    adapter: Option<Adapter>,
    #[serde(flatten)]
    quality: Quality,
    /// Volume of the selected voxels, ml.
    mask_ml: Real,
    /// Samples (oriented points) the accuracy is measured against.
    samples: usize,
    /// File → mesh file: read, select, reconstruct, write (metrics excluded), ms.
    time_ms: Real,
    /// Reading the label map, selecting the labels (cropped mask), the reconstruction alone
    /// (mask → mesh) and writing the mesh, ms.
    read_ms: Real,
    select_ms: Real,
    reconstruct_ms: Real,
    write_ms: Real,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    depth_candidates: Vec<study::DepthCandidate>,
    out: PathBuf,
}

fn read_labels(path: &Path) -> Result<LabelMap, CliError> {
    Ok(read_label_map(path, VoxelLimit::default())?)
}

pub(crate) fn recon_err(e: resecta_recon::ReconError) -> CliError {
    use resecta_recon::ReconError as E;
    match e {
        E::NoLabels
        | E::LabelsAbsent { .. }
        | E::EmptyMask
        | E::InvalidParameter { .. }
        | E::NormalCount { .. }
        | E::BadNormal { .. }
        | E::PointCloud(_) => CliError::BadInput(e.to_string()),
        E::Poisson(ref p) if !matches!(p, resecta_poisson::PoissonError::Backend { .. }) => {
            CliError::BadInput(e.to_string())
        }
        E::Poisson(_)
        | E::Cancelled
        | E::Filter(_)
        | E::Isosurface(_)
        | E::Metrics(_)
        | E::Geometry(_) => CliError::Failed(e.to_string()),
    }
}

fn mask_ml(mask: &Volume<bool>) -> Real {
    mask.data().iter().filter(|&&b| b).count() as Real * mask.grid().voxel_volume_mm3() / 1000.0
}

/// The oriented points as a mesh without triangles, for writing.
fn points_mesh(points: &OrientedPoints) -> Result<TriMesh, CliError> {
    TriMesh::new(points.positions.clone(), Vec::new())
        .and_then(|m| m.with_normals(points.normals.clone()))
        .map_err(|e| CliError::Failed(e.to_string()))
}

pub fn reconstruct(args: &ReconstructArgs) -> Result<(), CliError> {
    if args.labels.is_empty() {
        return Err(CliError::BadInput(
            "--labels: give at least one label".into(),
        ));
    }
    let (solver, adapter) = poisson_solver(args.backend)?;
    let pb = progress(args.json);
    let start = Instant::now();
    pb.set_message("reading label map");
    let labels = read_labels(&args.input)?;
    let read_ms = ms(start);
    let select_start = Instant::now();
    let selected = mask::select_cropped(&labels, &args.labels, 1).map_err(recon_err)?;
    let select_ms = ms(select_start);
    pb.set_message(match args.method {
        Method::Psr => "Poisson reconstruction",
        Method::Mcsd => "marching cubes, decimation, smoothing",
    });
    let recon_start = Instant::now();
    let (mesh, points, depth, candidates) = match args.method {
        Method::Psr => {
            let points = psr::points(&selected).map_err(recon_err)?;
            match args.depth {
                DepthArg::Fixed(d) => {
                    let mesh = psr::surface_with(&points, d, &solver).map_err(recon_err)?;
                    (mesh, Some(points), Some(d), Vec::new())
                }
                DepthArg::Auto => {
                    let auto = study::auto_depth_with(&points, &[5, 6, 7, 8], &solver)
                        .map_err(recon_err)?;
                    (auto.mesh, Some(points), Some(auto.depth), auto.candidates)
                }
            }
        }
        Method::Mcsd => {
            let p = McsdParams {
                smoothing: args.smoothing,
                decimation: args.decimation,
            };
            (
                mcsd::reconstruct(&selected, &p).map_err(recon_err)?,
                None,
                None,
                Vec::new(),
            )
        }
    };
    let reconstruct_ms = ms(recon_start);
    pb.set_message("writing mesh");
    let write_start = Instant::now();
    write_mesh(&args.out, &mesh)?;
    let write_ms = ms(write_start);
    let time_ms = ms(start);
    pb.set_message("measuring");
    let points = match points {
        Some(p) => p,
        None => psr::points(&selected).map_err(recon_err)?,
    };
    if let Some(path) = &args.points_out {
        write_mesh(path, &points_mesh(&points)?)?;
    }
    let quality = measure(&mesh, &points.positions).map_err(recon_err)?;
    pb.finish_and_clear();
    let summary = ReconstructSummary {
        method: args.method,
        labels: args.labels.clone(),
        depth,
        smoothing: (args.method == Method::Mcsd).then_some(args.smoothing),
        decimation: (args.method == Method::Mcsd).then_some(args.decimation),
        backend: args.backend,
        adapter,
        quality,
        mask_ml: mask_ml(&selected),
        samples: points.positions.len(),
        time_ms,
        read_ms,
        select_ms,
        reconstruct_ms,
        write_ms,
        depth_candidates: candidates,
        out: args.out.clone(),
    };
    if args.json {
        return print_json(&summary);
    }
    let q = &summary.quality;
    println!(
        "{}: {} triangles, {} vertices, mean {:.3} mm, p95 {:.3} mm, {:.2} ml (mask {:.2} ml), {}, {:.0} ms → {}",
        match args.method {
            Method::Psr => format!("PSR d={}", summary.depth.unwrap_or(0)),
            Method::Mcsd => format!("MCSD s={} e={}", args.smoothing, args.decimation),
        },
        q.polys,
        q.points,
        q.mean_mm,
        q.p95_mm,
        q.volume_ml,
        summary.mask_ml,
        if q.watertight {
            "watertight"
        } else {
            "NOT watertight"
        },
        summary.time_ms,
        args.out.display()
    );
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct MeasureArgs {
    /// Mesh to measure (.vtp, .vtk, .stl, .ply, .obj), RAS.
    pub mesh: PathBuf,
    /// Label map whose oriented points are the reference.
    #[arg(long)]
    pub reference: PathBuf,
    #[arg(long, value_delimiter = ',', required = true,
          value_parser = clap::value_parser!(u16).range(1..))]
    pub labels: Vec<u16>,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct MeasureSummary {
    #[serde(flatten)]
    quality: Quality,
    mask_ml: Real,
    samples: usize,
}

pub fn measure_mesh(args: &MeasureArgs) -> Result<(), CliError> {
    if args.labels.is_empty() {
        return Err(CliError::BadInput(
            "--labels: give at least one label".into(),
        ));
    }
    let mesh = read_mesh(&args.mesh)?;
    let labels = read_labels(&args.reference)?;
    let selected = mask::select(&labels, &args.labels).map_err(recon_err)?;
    let points = psr::points(&selected).map_err(recon_err)?;
    let quality = measure(&mesh, &points.positions).map_err(recon_err)?;
    let summary = MeasureSummary {
        quality,
        mask_ml: mask_ml(&selected),
        samples: points.positions.len(),
    };
    if args.json {
        return print_json(&summary);
    }
    let q = &summary.quality;
    println!(
        "{} triangles, mean {:.3} mm, p95 {:.3} mm, max {:.3} mm, {:.2} ml (mask {:.2} ml), curvature {:.3e}, {}",
        q.polys,
        q.mean_mm,
        q.p95_mm,
        q.max_mm,
        q.volume_ml,
        summary.mask_ml,
        q.curvature,
        if q.watertight {
            "watertight"
        } else {
            "NOT watertight"
        }
    );
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct ModelsArgs {
    /// Label map.
    pub input: PathBuf,
    /// Role map as JSON, e.g. '{"parenchyma":[1],"tumor":[2],"portal":[3],"hepatic":[4]}'.
    #[arg(long)]
    pub roles: Option<String>,
    /// Folder for the meshes (created if missing).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// How the parenchyma is built (tumours and vessels always by MCSD).
    #[arg(long, value_enum, default_value_t = Method::Psr)]
    pub method: Method,
    /// PSR depth for the parenchyma.
    #[arg(long, default_value_t = 7)]
    pub depth: u32,
    /// One vessel model per face-connected component instead of one per label.
    #[arg(long)]
    pub split_components: bool,
    /// Vessel components smaller than this (mm³) get no model and are counted (tumours: always
    /// 10 mm³, the planner's rule).
    #[arg(long, default_value_t = resecta_recon::SPECK_MM3)]
    pub min_component_mm3: Real,
    /// Mesh format (file extension).
    #[arg(long, default_value = "vtp")]
    pub format: String,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct ModelEntry {
    name: String,
    role: String,
    /// The label value it was built from (parenchyma: when the role has one).
    label: Option<u16>,
    method: &'static str,
    voxels: usize,
    polys: usize,
    points: usize,
    volume_ml: Real,
    watertight: bool,
    file: PathBuf,
}

#[derive(Debug, Serialize)]
struct DroppedEntry {
    role: &'static str,
    components: usize,
    voxels: usize,
    volume_ml: Real,
}

#[derive(Debug, Serialize)]
struct ModelsSummary {
    models: Vec<ModelEntry>,
    /// Components left out as specks, per role with any.
    dropped: Vec<DroppedEntry>,
    min_component_mm3: Real,
    read_ms: Real,
    /// Label map → meshes in memory.
    reconstruct_ms: Real,
    /// The whole command, writing included.
    time_ms: Real,
}

pub fn models(args: &ModelsArgs) -> Result<(), CliError> {
    let roles: RoleMap = match &args.roles {
        Some(s) => {
            serde_json::from_str(s).map_err(|e| CliError::BadInput(format!("--roles: {e}")))?
        }
        None => RoleMap::default(),
    };
    let pb = progress(args.json);
    let start = Instant::now();
    pb.set_message("reading label map");
    let labels = read_labels(&args.input)?;
    let read_ms = ms(start);
    std::fs::create_dir_all(&args.out_dir)
        .map_err(|e| CliError::Failed(format!("{}: {e}", args.out_dir.display())))?;
    let mut built = |name: &str| {
        pb.set_message(format!("built {name}"));
        true
    };
    let options = ModelOptions {
        parenchyma: match args.method {
            Method::Psr => ParenchymaMethod::Psr { depth: args.depth },
            Method::Mcsd => ParenchymaMethod::Mcsd,
        },
        mcsd: McsdParams::default(),
        split_components: args.split_components,
        min_component_mm3: args.min_component_mm3,
    };
    let recon_start = Instant::now();
    let built = patient_models(&labels, &roles, &options, &mut built).map_err(recon_err)?;
    let reconstruct_ms = ms(recon_start);
    let mut entries = Vec::new();
    for m in &built.models {
        let file = args.out_dir.join(format!("{}.{}", m.name(), args.format));
        write_mesh(&file, &m.mesh)?;
        let report = m.mesh.report();
        entries.push(ModelEntry {
            name: m.name(),
            role: m.role.name().to_owned(),
            label: m.label,
            method: m.method,
            voxels: m.voxels,
            polys: m.mesh.triangles().len(),
            points: m.mesh.vertices().len(),
            volume_ml: m.mesh.signed_volume() / 1000.0,
            watertight: report.watertight,
            file,
        });
    }
    pb.finish_and_clear();
    let summary = ModelsSummary {
        models: entries,
        dropped: built
            .dropped
            .iter()
            .map(|d| DroppedEntry {
                role: d.role.name(),
                components: d.components,
                voxels: d.voxels,
                volume_ml: d.volume_mm3 / 1000.0,
            })
            .collect(),
        min_component_mm3: args.min_component_mm3,
        read_ms,
        reconstruct_ms,
        time_ms: ms(start),
    };
    if args.json {
        return print_json(&summary);
    }
    for e in &summary.models {
        println!(
            "{:<14} {:<5} {:>8} triangles {:>9.2} ml {} → {}",
            e.name,
            e.method,
            e.polys,
            e.volume_ml,
            if e.watertight {
                "watertight"
            } else {
                "NOT watertight"
            },
            e.file.display()
        );
    }
    for d in &summary.dropped {
        println!(
            "{}: {} component(s) below {} mm³ left out ({:.4} ml)",
            d.role, d.components, summary.min_component_mm3, d.volume_ml
        );
    }
    println!(
        "{} models in {:.0} ms",
        summary.models.len(),
        summary.time_ms
    );
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Label map.
    pub input: PathBuf,
    #[arg(long, value_delimiter = ',', required = true,
          value_parser = clap::value_parser!(u16).range(1..))]
    pub labels: Vec<u16>,
    /// Folder for study.md, study.json, pareto.png and pareto.svg.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// A reduced grid (PSR d 5–7; MCSD s ∈ {0, 45, 90} × e ∈ {0, 0.5}), for tests.
    #[arg(long)]
    pub quick: bool,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct EvaluateSummary {
    models: usize,
    p_best: Option<String>,
    c_best: Option<String>,
    c_sim: Option<String>,
    m_best: Option<String>,
    files: Vec<PathBuf>,
    time_ms: Real,
}

pub fn evaluate(args: &EvaluateArgs) -> Result<(), CliError> {
    if args.labels.is_empty() {
        return Err(CliError::BadInput(
            "--labels: give at least one label".into(),
        ));
    }
    let config = if args.quick {
        StudyConfig::quick()
    } else {
        StudyConfig::default()
    };
    let start = Instant::now();
    let labels = read_labels(&args.input)?;
    let selected = mask::select(&labels, &args.labels).map_err(recon_err)?;
    let bar = crate::output::counter(args.json, config.len() as u64, "models");
    let mut tick = |name: &str| {
        bar.set_message(name.to_owned());
        bar.inc(1);
    };
    let run = study::run(&selected, &config, &mut tick).map_err(recon_err)?;
    bar.finish_and_clear();
    let write = crate::output::files_in(&args.out_dir)?;
    let json =
        serde_json::to_string_pretty(&run).map_err(|e| CliError::Failed(format!("JSON: {e}")))?;
    let figure = resecta_plot::pareto_figure(&run.study);
    let mut files = vec![
        write("study.md", run.study.markdown().as_bytes())?,
        write("study.json", json.as_bytes())?,
    ];
    files.extend(crate::output::write_figure(&write, "pareto", &figure)?);
    let name = |i: Option<usize>| run.study.model(i).map(|m| m.record.label.clone());
    let summary = EvaluateSummary {
        models: run.study.models.len(),
        p_best: name(run.study.p_best),
        c_best: name(run.study.c_best),
        c_sim: name(run.study.c_sim),
        m_best: name(Some(run.study.m_best)),
        files,
        time_ms: ms(start),
    };
    if args.json {
        return print_json(&summary);
    }
    println!(
        "{} models; best PSR {}, best MCSD {}, MCSD most similar in smoothness {}; wrote {}",
        summary.models,
        summary.p_best.as_deref().unwrap_or("-"),
        summary.c_best.as_deref().unwrap_or("-"),
        summary.c_sim.as_deref().unwrap_or("-"),
        args.out_dir.display()
    );
    Ok(())
}
