//! `resecta`: the command line face of the engine.
//!
//! Every computing subcommand takes `--json` and then prints exactly one JSON object on stdout;
//! progress and logs go to stderr. Exit codes: 0 success, 2 bad input, 1 other failure.

mod bench;
mod bench_python;
mod bench_ready;
mod bench_recon;
mod bench_replicas;
mod bench_server;
mod bezier;
mod cloud;
mod demo;
mod eam;
mod error;
mod info;
mod output;
mod phantom;
mod plan;
mod recon;
mod resectogram;
mod serve;
mod study;
mod territories;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "resecta", version, about = "Liver resection planning engine")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Describe an image, segmentation or mesh file: geometry, labels with volumes, topology.
    Info(info::Args),
    /// Generate a synthetic liver phantom with its analytic truth.
    Phantom(phantom::Args),
    /// Run the demo on the embedded default phantom: write files, read them back, check them.
    Demo(demo::Args),
    /// Surface model of some labels by Poisson reconstruction (PSR) or MCSD.
    Reconstruct(recon::ReconstructArgs),
    /// The complete patient model: PSR liver, MCSD tumours and vessels, one mesh each.
    Models(recon::ModelsArgs),
    /// A closed surface from a point cloud with or without normals (catheter points) by PSR.
    ReconstructPoints(cloud::ReconstructPointsArgs),
    /// Paper IV's sampling study: how many points, and where, a left atrium needs.
    EamStudy(eam::EamStudyArgs),
    /// Accuracy, polygons, volume and smoothness of any mesh against a label map.
    Measure(recon::MeasureArgs),
    /// The Paper I study on one label map: PSR depths × MCSD parameters, tables and Pareto plot.
    Evaluate(recon::EvaluateArgs),
    /// Evaluate a resection plan (margins, verdicts, volumes), or `plan init` a new one.
    Plan(plan::PlanArgs),
    /// Vessel centrelines and the vascular territories of the functional liver.
    Territories(territories::TerritoriesArgs),
    /// A resection unrolled to its (u, v) square as a PNG: margin classes, liver boundary,
    /// portal territories, cut vessels and the worst point.
    Resectogram(resectogram::ResectogramArgs),
    /// Bézier surfaces.
    #[command(subcommand)]
    Bezier(bezier::Command),
    /// The planning server: gRPC and HTTP faces over patient sessions (docs/server.md).
    Serve(resecta_server::ServeArgs),
    /// Studies: `study methods` compares Bézier, DS and CP resections (Paper II, in silico).
    #[command(subcommand)]
    Study(study::Command),
    /// Benchmarks, with their anchors in the same run.
    #[command(subcommand)]
    Bench(bench::Command),
}

fn main() -> ExitCode {
    quiet_vulkan_layers();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(a) => info::run(&a),
        Command::Phantom(a) => phantom::run(&a),
        Command::Demo(a) => demo::run(&a),
        Command::Reconstruct(a) => recon::reconstruct(&a),
        Command::Models(a) => recon::models(&a),
        Command::ReconstructPoints(a) => cloud::run(&a),
        Command::EamStudy(a) => eam::run(&a),
        Command::Measure(a) => recon::measure_mesh(&a),
        Command::Evaluate(a) => recon::evaluate(&a),
        Command::Plan(a) => plan::run(&a),
        Command::Territories(a) => territories::run(&a),
        Command::Resectogram(a) => resectogram::run(&a),
        Command::Bezier(c) => bezier::run(&c),
        Command::Serve(a) => serve::serve(&a),
        Command::Study(c) => study::run(&c),
        Command::Bench(c) => bench::run(&c),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("resecta: error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

/// Disables Mesa's device-select Vulkan layer unless the environment says otherwise: it only
/// orders adapters for displays, and it connects to a Wayland display while adapters are
/// enumerated, printing non-log lines on stderr where `XDG_RUNTIME_DIR` is unset.
#[allow(unsafe_code)]
fn quiet_vulkan_layers() {
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: first thing in `main`, before any thread exists that could read the environment.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}
