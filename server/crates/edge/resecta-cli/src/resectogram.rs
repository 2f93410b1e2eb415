//! `resecta resectogram`: a resection of a plan unrolled to its (u, v) square, as a PNG.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use clap::Args;
use resecta_plan::{Anatomy, CutVessel, Planner};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};
use crate::plan::{parse_grid, plan_err, read_labels, read_plan};

#[derive(Debug, Args)]
pub struct ResectogramArgs {
    /// Label map (NIfTI, NRRD, .seg.nrrd, MetaImage).
    pub labelmap: PathBuf,
    /// Plan file (`resecta-plan/1` JSON).
    pub plan: PathBuf,
    /// The PNG to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The resection (default: the plan's first).
    #[arg(long)]
    pub resection: Option<String>,
    /// Resectogram size in samples, W×H.
    #[arg(long, default_value = "200x200", value_parser = parse_grid)]
    pub size: [usize; 2],
    /// Screen pixels per sample in the PNG (1–8).
    #[arg(long, default_value_t = 2)]
    pub scale: usize,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Report {
    resection: String,
    png: String,
    width: usize,
    height: usize,
    png_width: usize,
    png_height: usize,
    /// Samples per margin class: outside, safe, warning, violation.
    class_counts: [usize; 4],
    /// Share of the (u, v) square inside the liver.
    inside_fraction: f64,
    /// Distinct portal territories on the surface inside the liver.
    territories: usize,
    cut_vessels: Vec<CutVessel>,
    worst_uv: Option<[f64; 2]>,
    min_margin_mm: Option<f64>,
    margin_mm: f64,
    setup_ms: f64,
    resectogram_ms: f64,
}

pub fn run(args: &ResectogramArgs) -> Result<(), CliError> {
    let pb = progress(args.json);
    if !(1..=8).contains(&args.scale) {
        return Err(CliError::BadInput(format!(
            "--scale {}: must be 1..=8",
            args.scale
        )));
    }
    let plan = read_plan(&args.plan)?;
    let name = match &args.resection {
        Some(n) => n.clone(),
        None => plan
            .resections
            .first()
            .map(|r| r.name.clone())
            .ok_or_else(|| CliError::BadInput(format!("{}: no resection", args.plan.display())))?,
    };
    pb.set_message("reading the label map");
    let t0 = Instant::now();
    let labels = read_labels(&args.labelmap)?;
    pb.set_message("anatomy and vessel trees");
    let anatomy = Arc::new(Anatomy::new(&labels, &plan.roles).map_err(plan_err)?);
    let planner = Planner::new(anatomy, plan).map_err(plan_err)?;
    let setup_ms = ms(t0);
    pb.set_message("resectogram");
    let t1 = Instant::now();
    let [w, h] = args.size;
    let g = planner.resectogram(&name, w, h).map_err(plan_err)?;
    let resectogram_ms = ms(t1);
    let (pw, ph, rgba) = g.to_rgba(args.scale);
    let png = resecta_plot::rgba_png(pw, ph, &rgba).map_err(|e| CliError::Failed(e.to_string()))?;
    std::fs::write(&args.out, png)
        .map_err(|e| CliError::Failed(format!("{}: {e}", args.out.display())))?;
    pb.finish_and_clear();
    let mut class_counts = [0usize; 4];
    for &c in &g.classes {
        class_counts[usize::from(c).min(3)] += 1;
    }
    let mut t: Vec<u32> = g.territories.iter().copied().filter(|&t| t > 0).collect();
    t.sort_unstable();
    t.dedup();
    let report = Report {
        resection: g.resection.clone(),
        png: args.out.display().to_string(),
        width: w,
        height: h,
        png_width: pw,
        png_height: ph,
        inside_fraction: (g.classes.len() - class_counts[0]) as f64 / g.classes.len() as f64,
        class_counts,
        territories: t.len(),
        cut_vessels: g.cut_vessels,
        worst_uv: g.worst_uv,
        min_margin_mm: g.min_margin_mm,
        margin_mm: g.margin_mm,
        setup_ms,
        resectogram_ms,
    };
    if args.json {
        print_json(&report)
    } else {
        println!(
            "{}: {}×{} → {} · {:.0} % inside the liver · {} territories · {} vessel(s) cut · min margin {}",
            report.resection,
            w,
            h,
            report.png,
            100.0 * report.inside_fraction,
            report.territories,
            report.cut_vessels.len(),
            report
                .min_margin_mm
                .map_or("—".to_owned(), |m| format!("{m:.1} mm"))
        );
        Ok(())
    }
}
