//! `resecta bezier eval`: evaluate a Bézier surface from a control-point file, so a surface can be
//! checked from outside.

use std::path::{Path, PathBuf};
use std::time::Instant;

use resecta_bezier::{
    BezierScalar, ControlNet, MleEvaluator, Outputs, Resolution, SurfaceGrid, to_trimesh,
};
use serde::Serialize;

use crate::error::CliError;
use crate::output::print_json;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Evaluate a surface: control points (JSON array of M·N [x,y,z], index i·N + j, i along u)
    /// at RU×RV samples u_a = a/(RU−1), v_b = b/(RV−1).
    Eval(EvalArgs),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Precision {
    F32,
    F64,
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Control grid M,N (M along u).
    #[arg(long, value_parser = parse_pair)]
    pub grid: (usize, usize),
    /// JSON file with M·N control points.
    #[arg(long)]
    pub control_points: PathBuf,
    /// Samples RU,RV.
    #[arg(long, value_parser = parse_pair)]
    pub resolution: (usize, usize),
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    pub precision: Precision,
    /// `.json` for `{"resolution":[RU,RV],"points":[[x,y,z],…]}` (u outer, v inner), or a mesh
    /// extension (.vtk, .vtp, .stl, .ply, .obj) for the triangulated surface with normals.
    #[arg(long)]
    pub out: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

fn parse_pair(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected two numbers A,B, got {s:?}"))?;
    let n = |t: &str| t.trim().parse::<usize>().map_err(|e| format!("{t:?}: {e}"));
    Ok((n(a)?, n(b)?))
}

#[derive(Debug, Serialize)]
struct EvalSummary {
    out: PathBuf,
    grid: [usize; 2],
    resolution: [usize; 2],
    precision: &'static str,
    points: usize,
    bounds: [[f64; 3]; 2],
    time_ms: f64,
}

#[derive(Debug, Serialize)]
struct PointsFile<'a> {
    resolution: [usize; 2],
    points: &'a [[f64; 3]],
}

pub fn run(cmd: &Command) -> Result<(), CliError> {
    match cmd {
        Command::Eval(args) => eval(args),
    }
}

fn eval(args: &EvalArgs) -> Result<(), CliError> {
    let path = &args.control_points;
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::BadInput(format!("{}: {e}", path.display())))?;
    let points: Vec<[f64; 3]> = serde_json::from_str(&text).map_err(|e| {
        CliError::BadInput(format!(
            "{}: expected a JSON array of [x,y,z]: {e}",
            path.display()
        ))
    })?;
    let bad =
        |e: resecta_bezier::BezierError| CliError::BadInput(format!("{}: {e}", path.display()));
    let (m, n) = args.grid;
    let (ru, rv) = args.resolution;
    let resolution =
        Resolution::new(ru, rv).map_err(|e| CliError::BadInput(format!("--resolution: {e}")))?;
    let start = Instant::now();
    let bounds = match args.precision {
        Precision::F64 => {
            let net = ControlNet::new(m, n, points).map_err(bad)?;
            write_surface(
                &args.out,
                &MleEvaluator::new(net, resolution).evaluate(Outputs::Normals),
            )?
        }
        Precision::F32 => {
            let p32 = points.iter().map(|p| p.map(|c| c as f32)).collect();
            let net = ControlNet::<f32>::new(m, n, p32).map_err(bad)?;
            write_surface(
                &args.out,
                &MleEvaluator::new(net, resolution).evaluate(Outputs::Normals),
            )?
        }
    };
    let time_ms = start.elapsed().as_secs_f64() * 1000.0;
    let summary = EvalSummary {
        out: args.out.clone(),
        grid: [m, n],
        resolution: [ru, rv],
        precision: match args.precision {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        },
        points: ru * rv,
        bounds,
        time_ms,
    };
    if args.json {
        return print_json(&summary);
    }
    println!(
        "wrote {} ({}×{} samples of a {m}×{n} {} surface, {:.2} ms)",
        summary.out.display(),
        ru,
        rv,
        summary.precision,
        time_ms
    );
    Ok(())
}

/// Writes the surface (JSON points or a mesh by extension) and returns its bounds.
fn write_surface<T: BezierScalar>(
    out: &Path,
    grid: &SurfaceGrid<T>,
) -> Result<[[f64; 3]; 2], CliError> {
    let points: Vec<[f64; 3]> = grid.points().iter().map(|p| p.map(T::to_f64)).collect();
    let mut bounds = [[f64::INFINITY; 3], [f64::NEG_INFINITY; 3]];
    for p in &points {
        for c in 0..3 {
            bounds[0][c] = bounds[0][c].min(p[c]);
            bounds[1][c] = bounds[1][c].max(p[c]);
        }
    }
    if out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        let r = grid.resolution();
        let file = PointsFile {
            resolution: [r.ru(), r.rv()],
            points: &points,
        };
        let text = serde_json::to_string(&file).map_err(|e| CliError::Failed(e.to_string()))?;
        std::fs::write(out, text)
            .map_err(|e| CliError::Failed(format!("{}: {e}", out.display())))?;
    } else {
        let mesh = to_trimesh(grid).map_err(|e| CliError::Failed(e.to_string()))?;
        resecta_io::write_mesh(out, &mesh)?;
    }
    Ok(bounds)
}
