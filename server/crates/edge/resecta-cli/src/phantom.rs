//! `resecta phantom`: a synthetic liver with its analytic truth.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use resecta_geom::Role;
use resecta_phantom::{Phantom, PhantomSpec, generate};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{print_json, progress};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// Liver-sized: two tumours, portal and hepatic vessels, oblique 0.8×0.8×2.5 mm grid.
    Demo,
    /// Coarse and fast, for tests.
    Small,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder to write the label map and `truth.json` into (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// A built-in phantom (ignored with --spec).
    #[arg(long, value_enum, default_value_t = Preset::Demo)]
    pub preset: Preset,
    /// A phantom spec as JSON (the `spec` object of a `truth.json` is one).
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Label map file name; its extension picks the format (.nii.gz, .nrrd, .seg.nrrd, .mha, ...).
    #[arg(long, default_value = "phantom.nii.gz")]
    pub name: String,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct RoleSummary {
    analytic_ml: f64,
    error_bound_ml: f64,
    voxelised_ml: f64,
}

#[derive(Debug, Serialize)]
struct Summary {
    labels_file: PathBuf,
    truth_file: PathBuf,
    dims: [usize; 3],
    spacing: [f64; 3],
    liver_ml: f64,
    roles: BTreeMap<Role, RoleSummary>,
    time_ms: f64,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let spec = match &args.spec {
        Some(path) => read_spec(path)?,
        None => match args.preset {
            Preset::Demo => PhantomSpec::demo(),
            Preset::Small => PhantomSpec::small(),
        },
    };
    let pb = progress(args.json);
    pb.set_message("generating phantom");
    let start = Instant::now();
    let phantom = generate(&spec).map_err(|e| CliError::BadInput(format!("phantom spec: {e}")))?;
    pb.set_message("writing files");
    let (labels_file, truth_file) = write_phantom(&args.out, &args.name, &phantom)?;
    let summary = summarise(&phantom, labels_file, truth_file, start);
    pb.finish_and_clear();
    if args.json {
        return print_json(&summary);
    }
    println!(
        "wrote {} and {}",
        summary.labels_file.display(),
        summary.truth_file.display()
    );
    println!("  liver {:.2} ml", summary.liver_ml);
    for (role, r) in &summary.roles {
        println!(
            "  {role:<10} analytic {:>9.3} ml (±{:.3})  voxelised {:>9.3} ml",
            r.analytic_ml, r.error_bound_ml, r.voxelised_ml
        );
    }
    Ok(())
}

fn read_spec(path: &Path) -> Result<PhantomSpec, CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::BadInput(format!("{}: {e}", path.display())))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| CliError::BadInput(format!("{}: not JSON: {e}", path.display())))?;
    // Accept a bare spec or a truth.json holding one.
    let spec = value.get("spec").cloned().unwrap_or(value);
    serde_json::from_value(spec)
        .map_err(|e| CliError::BadInput(format!("{}: bad phantom spec: {e}", path.display())))
}

/// Writes the label map (format by `name`'s extension) and `truth.json` into `dir`.
pub fn write_phantom(
    dir: &Path,
    name: &str,
    phantom: &Phantom,
) -> Result<(PathBuf, PathBuf), CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::Failed(format!("{}: cannot create folder: {e}", dir.display())))?;
    let labels_file = dir.join(name);
    resecta_io::write_label_map(&labels_file, &phantom.labels)?;
    let truth_file = dir.join("truth.json");
    let json = serde_json::to_string_pretty(&phantom.truth)
        .map_err(|e| CliError::Failed(format!("truth JSON: {e}")))?;
    std::fs::write(&truth_file, json)
        .map_err(|e| CliError::Failed(format!("{}: {e}", truth_file.display())))?;
    Ok((labels_file, truth_file))
}

fn summarise(
    phantom: &Phantom,
    labels_file: PathBuf,
    truth_file: PathBuf,
    start: Instant,
) -> Summary {
    let t = &phantom.truth;
    let grid = phantom.labels.grid();
    let roles = t
        .roles
        .iter()
        .map(|(&role, m)| {
            let voxelised_mm3 = t.voxelised_mm3(role);
            let r = RoleSummary {
                analytic_ml: m.volume_mm3 / 1000.0,
                error_bound_ml: m.error_bound_mm3 / 1000.0,
                voxelised_ml: voxelised_mm3 / 1000.0,
            };
            (role, r)
        })
        .collect();
    Summary {
        labels_file,
        truth_file,
        dims: grid.dims(),
        spacing: grid.spacing(),
        liver_ml: t.liver.volume_mm3 / 1000.0,
        roles,
        time_ms: start.elapsed().as_secs_f64() * 1000.0,
    }
}
