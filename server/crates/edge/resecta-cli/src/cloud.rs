//! `resecta reconstruct-points`: a closed surface from a point cloud (catheter points, scans)
//! with or without normals, by screened Poisson reconstruction (thesis ch. 9).

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use resecta_geom::Real;
use resecta_io::{read_points, write_mesh};
use resecta_recon::{CloudOptions, CloudReport, DEFAULT_CLOUD_DEPTH, reconstruct_cloud};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};
use crate::recon::{Adapter, Backend, poisson_solver, recon_err};

#[derive(Debug, Args)]
pub struct ReconstructPointsArgs {
    /// Points (.csv/.txt/.xyz: x,y,z[,nx,ny,nz]; .ply; .vtp; or any mesh file's vertices),
    /// RAS mm. Normals are used when the file has them and estimated otherwise.
    pub points: PathBuf,
    /// PSR depth: 2^d cells across the points' bounding cube × 1.1 (5 suits 100–600
    /// catheter points; dense scans want 7–8).
    #[arg(long, default_value_t = DEFAULT_CLOUD_DEPTH,
          value_parser = clap::value_parser!(u32).range(1..=10))]
    pub depth: u32,
    /// Neighbours per point for normal estimation and point areas (3..=64).
    #[arg(long, default_value_t = resecta_recon::DEFAULT_CLOUD_NEIGHBOURS)]
    pub neighbours: usize,
    /// Ignore the file's normals and estimate them.
    #[arg(long)]
    pub estimate_normals: bool,
    /// Output mesh (.vtp, .vtk, .stl, .ply, .obj), RAS.
    #[arg(long)]
    pub out: PathBuf,
    /// Where PSR's multigrid runs.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Summary {
    #[serde(flatten)]
    cloud: CloudReport,
    backend: Backend,
    #[serde(skip_serializing_if = "Option::is_none")]
    adapter: Option<Adapter>,
    triangles: usize,
    vertices: usize,
    /// Enclosed volume of the surface, ml.
    volume_ml: Real,
    area_mm2: Real,
    watertight: bool,
    /// Reading, reconstructing (normals, solve, surface) and writing, ms.
    read_ms: Real,
    reconstruct_ms: Real,
    write_ms: Real,
    time_ms: Real,
    out: PathBuf,
}

pub fn run(args: &ReconstructPointsArgs) -> Result<(), CliError> {
    let start = Instant::now();
    let pb = progress(args.json);
    pb.set_message("reading points");
    let cloud = read_points(&args.points)?;
    let read_ms = ms(start);
    let (solver, adapter) = poisson_solver(args.backend)?;
    pb.set_message("reconstructing");
    let t = Instant::now();
    let normals = if args.estimate_normals {
        None
    } else {
        cloud.normals.as_deref()
    };
    let options = CloudOptions {
        depth: args.depth,
        neighbours: args.neighbours,
    };
    let model =
        reconstruct_cloud(&cloud.positions, normals, &options, &solver).map_err(recon_err)?;
    let reconstruct_ms = ms(t);
    pb.set_message("writing mesh");
    let t = Instant::now();
    write_mesh(&args.out, &model.mesh)?;
    let write_ms = ms(t);
    pb.finish_and_clear();
    let report = model.mesh.report();
    let summary = Summary {
        cloud: model.report,
        backend: args.backend,
        adapter,
        triangles: model.mesh.triangles().len(),
        vertices: model.mesh.vertices().len(),
        volume_ml: model.mesh.signed_volume() / 1000.0,
        area_mm2: model.mesh.area(),
        watertight: report.watertight,
        read_ms,
        reconstruct_ms,
        write_ms,
        time_ms: ms(start),
        out: args.out.clone(),
    };
    if args.json {
        return print_json(&summary);
    }
    let c = &summary.cloud;
    println!(
        "{} points ({} normals{}), PSR d={} (cell {:.2} mm): {} triangles, {:.2} ml, {}, {:.0} ms → {}",
        c.points,
        match c.normals {
            resecta_recon::NormalSource::Given => "given",
            resecta_recon::NormalSource::Estimated => "estimated",
        },
        c.components
            .map(|k| format!(", {k} component{}", if k == 1 { "" } else { "s" }))
            .unwrap_or_default(),
        c.depth,
        c.cell_mm,
        summary.triangles,
        summary.volume_ml,
        if summary.watertight {
            "watertight"
        } else {
            "NOT watertight"
        },
        summary.time_ms,
        args.out.display()
    );
    Ok(())
}
