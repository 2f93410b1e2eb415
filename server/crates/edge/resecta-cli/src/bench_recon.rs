//! `resecta bench recon`: Poisson reconstruction of a phantom liver (issue #21) at each depth on
//! the CPU and/or the GPU multigrid. The oriented points are computed once (host); per backend
//! and depth the row times splatting, the multigrid, the iso-value and marching cubes, with the
//! V-cycles and final relative residual; with both backends each depth also reports the
//! CPU–GPU difference of the surfaces (symmetric vertex-to-surface max, mm) and volumes (%).
//! A depth a backend cannot run (memory budget, device binding limit) is reported, not fatal.
//! One d = 4 solve per backend first compiles the device's pipelines (not timed).
//! On a software adapter (lavapipe) the GPU figures are correctness runs only.

use std::time::Instant;

use resecta_geom::{Real, RoleMap, TriMesh};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, generate};
use resecta_poisson::{PoissonParams, PoissonSolver};
use resecta_recon::{SurfaceDiff, mask, psr};
use serde::Serialize;

use crate::bench::{Machine, machine};
use crate::error::CliError;
use crate::output::print_json;
use crate::recon::{Adapter, Backend, poisson_solver, recon_err};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backends {
    Cpu,
    Gpu,
    Both,
}

#[derive(Debug, clap::Args)]
pub struct ReconArgs {
    #[arg(long, value_enum, default_value_t = Backends::Both)]
    pub backend: Backends,
    /// PSR depths (finest grid 2^d cells across the liver's bounding cube × 1.1).
    #[arg(long, value_delimiter = ',', default_values_t = [7u32, 8, 9])]
    pub depths: Vec<u32>,
    /// Voxels of the phantom's label map along x, y, z (0.75 × 0.75 × 1 mm each).
    #[arg(long, value_delimiter = ',', default_values_t = [512usize, 512, 300])]
    pub dims: Vec<usize>,
    /// Host memory allowed per solve, GiB (a dense d = 9 hierarchy needs about 2.5).
    #[arg(long, default_value_t = 8)]
    pub max_gib: u64,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Row {
    backend: Backend,
    depth: u32,
    /// Set when this depth could not run on this backend; the figures are then absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    run: Option<Run>,
}

#[derive(Debug, Serialize)]
struct Run {
    splat_s: Real,
    /// The multigrid: full multigrid and V-cycles to the tolerance (device upload and
    /// read-back included on the GPU).
    solve_s: Real,
    iso_s: Real,
    extract_s: Real,
    /// Points → mesh: splatting, solve, iso-value and marching cubes.
    total_s: Real,
    cycles: u32,
    residual: Real,
    triangles: usize,
    volume_ml: Real,
    watertight: bool,
}

#[derive(Debug, Serialize)]
struct Diff {
    depth: u32,
    #[serde(flatten)]
    diff: SurfaceDiff,
}

#[derive(Debug, Serialize)]
struct Report {
    machine: Machine,
    #[serde(skip_serializing_if = "Option::is_none")]
    adapter: Option<Adapter>,
    dims: [usize; 3],
    spacing_mm: [Real; 3],
    mask_voxels: usize,
    points: usize,
    points_s: Real,
    tolerance: Real,
    rows: Vec<Row>,
    /// CPU–GPU differences per depth where both ran.
    cpu_vs_gpu: Vec<Diff>,
}

const SPACING: [Real; 3] = [0.75, 0.75, 1.0];

/// A liver of about 1.4 l (right and left lobe, two obliquely rotated ellipsoids, 200 × 130 ×
/// 120 mm) centred on a grid of `dims` voxels, shrunk along an axis where the grid is smaller
/// than 240 mm.
fn phantom_spec(dims: [usize; 3]) -> PhantomSpec {
    let s: [Real; 3] = std::array::from_fn(|a| (dims[a] as Real * SPACING[a] / 240.0).min(1.0));
    let at = |v: [Real; 3]| std::array::from_fn(|a| v[a] * s[a]);
    PhantomSpec {
        grid: GridSpec::centred(dims, SPACING, [0.0; 3], Orientation::default()),
        liver: vec![
            EllipsoidSpec {
                center: at([-25.0, 0.0, 0.0]),
                radii: at([75.0, 65.0, 60.0]),
                rotation: Orientation::EulerDeg([5.0, -4.0, 18.0]),
            },
            EllipsoidSpec {
                center: at([45.0, 15.0, 15.0]),
                radii: at([55.0, 40.0, 35.0]),
                rotation: Orientation::EulerDeg([-6.0, 8.0, -12.0]),
            },
        ],
        tumors: vec![],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: Some(600_000_000),
        truth_tolerance_mm: 0.05,
    }
}

fn secs(t: Instant) -> Real {
    t.elapsed().as_secs_f64()
}

/// One reconstruction at `params`: the row's figures and the mesh.
fn run_one(
    points: &resecta_poisson::OrientedPoints,
    params: &PoissonParams,
    solver: &PoissonSolver,
) -> Result<(Run, TriMesh), resecta_recon::ReconError> {
    let t = Instant::now();
    let field = psr::field(points, params, solver)?;
    let te = Instant::now();
    let mesh = psr::field_surface(&field, solver)?;
    let r = &field.report;
    let run = Run {
        splat_s: r.splat_s,
        solve_s: r.solve_s,
        iso_s: r.iso_s,
        extract_s: secs(te),
        total_s: secs(t),
        cycles: r.cycles,
        residual: r.residuals.last().copied().unwrap_or(0.0),
        triangles: mesh.triangles().len(),
        volume_ml: mesh.signed_volume() / 1000.0,
        watertight: mesh.report().watertight,
    };
    Ok((run, mesh))
}

pub fn run(args: &ReconArgs) -> Result<(), CliError> {
    let dims: [usize; 3] = args.dims.as_slice().try_into().map_err(|_| {
        CliError::BadInput("--dims: give three voxel counts, e.g. 512,512,300".into())
    })?;
    if dims.iter().any(|&d| d < 8) {
        return Err(CliError::BadInput(
            "--dims: at least 8 voxels per axis".into(),
        ));
    }
    let mut backends = Vec::new();
    let mut adapter = None;
    if args.backend != Backends::Gpu {
        backends.push((Backend::Cpu, PoissonSolver::cpu()));
    }
    if args.backend != Backends::Cpu {
        let (solver, a) = poisson_solver(Backend::Gpu)?;
        adapter = a;
        backends.push((Backend::Gpu, solver));
    }
    let phantom = generate(&phantom_spec(dims)).map_err(|e| CliError::Failed(e.to_string()))?;
    let liver = mask::select(&phantom.labels, &[1]).map_err(recon_err)?;
    drop(phantom);
    let mask_voxels = liver.data().iter().filter(|&&b| b).count();
    let t = Instant::now();
    let points = psr::points(&liver).map_err(recon_err)?;
    let points_s = secs(t);
    drop(liver);
    let base = PoissonParams {
        max_bytes: args.max_gib << 30,
        ..PoissonParams::default()
    };
    // Warm-up: one d = 4 solve per backend compiles the device's pipelines before any timing.
    for (_, solver) in &backends {
        let warm = PoissonParams {
            depth: 4,
            ..base.clone()
        };
        psr::field(&points, &warm, solver).map_err(recon_err)?;
    }
    let mut rows = Vec::new();
    let mut diffs = Vec::new();
    for &depth in &args.depths {
        let params = PoissonParams {
            depth,
            ..base.clone()
        };
        let mut meshes = Vec::new();
        for (backend, solver) in &backends {
            if !args.json {
                eprintln!("d={depth} on {backend:?}…");
            }
            let row = match run_one(&points, &params, solver) {
                Ok((run, mesh)) => {
                    meshes.push(mesh);
                    Row {
                        backend: *backend,
                        depth,
                        error: None,
                        run: Some(run),
                    }
                }
                Err(e) => Row {
                    backend: *backend,
                    depth,
                    error: Some(e.to_string()),
                    run: None,
                },
            };
            rows.push(row);
        }
        if let [cpu, gpu] = meshes.as_slice()
            && backends.len() == 2
        {
            let diff = psr::surface_diff(cpu, gpu).map_err(recon_err)?;
            diffs.push(Diff { depth, diff });
        }
    }
    let report = Report {
        machine: machine(),
        adapter,
        dims,
        spacing_mm: SPACING,
        mask_voxels,
        points: points.len(),
        points_s,
        tolerance: base.tolerance,
        rows,
        cpu_vs_gpu: diffs,
    };
    if args.json {
        return print_json(&report);
    }
    print_report(&report);
    Ok(())
}

fn print_report(r: &Report) {
    println!(
        "{} ({} logical cores){}; phantom {:?} voxels, {} oriented points ({:.2} s)",
        r.machine.cpu,
        r.machine.logical_cores,
        r.adapter.as_ref().map_or(String::new(), |a| format!(
            "; GPU {} ({}){}",
            a.name,
            a.backend,
            if a.software {
                ", software: correctness run"
            } else {
                ""
            }
        )),
        r.dims,
        r.points,
        r.points_s
    );
    println!("backend depth  solve_s  total_s cycles residual  triangles  volume_ml");
    for row in &r.rows {
        match (&row.run, &row.error) {
            (Some(x), _) => println!(
                "{:<7} {:>5} {:>8.3} {:>8.3} {:>6} {:>8.2e} {:>10} {:>10.3}",
                format!("{:?}", row.backend).to_lowercase(),
                row.depth,
                x.solve_s,
                x.total_s,
                x.cycles,
                x.residual,
                x.triangles,
                x.volume_ml
            ),
            (None, e) => println!(
                "{:<7} {:>5} not run: {}",
                format!("{:?}", row.backend).to_lowercase(),
                row.depth,
                e.as_deref().unwrap_or("")
            ),
        }
    }
    for d in &r.cpu_vs_gpu {
        println!(
            "d={}: CPU vs GPU surface max {:.2e} mm, volume {:.2e} %",
            d.depth, d.diff.max_mm, d.diff.volume_pct
        );
    }
}
