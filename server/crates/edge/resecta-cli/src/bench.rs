//! `resecta bench`: benchmark harness (timing loops only; the algorithms live in their crates).

use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use resecta_bezier::{ControlNet, Method, Outputs, P3, Prepared, Resolution, write_ceiling};
use resecta_gpu::{GpuContext, GpuPrepared, GpuScalar};
use serde::Serialize;

use crate::error::CliError;
use crate::output::print_json;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Bézier evaluation (Paper III, Figs. 8.5–8.7): BRF/MAT/MLE × f32/f64 × control grids ×
    /// resolutions × threads × backends, with the memory-write ceiling.
    Bezier(BezierArgs),
    /// The planning server under load (issue #6): edit → delta latency at watching clients alone
    /// and with many sessions at once, memory per idle session, and a 512×512×300 upload.
    Server(crate::bench_server::ServerArgs),
    /// Replicas (issue #25): two replicas on one PostgreSQL store beside one server on SQLite,
    /// edit latency, sessions per server at a fixed edit rate, and fail-over after `kill -9`.
    Replicas(crate::bench_replicas::ReplicasArgs),
    /// Poisson reconstruction (issue #21): PSR of a phantom liver at several depths on the CPU
    /// and the GPU, times, iterations and the CPU–GPU surface and volume differences.
    Recon(crate::bench_recon::ReconArgs),
}

#[derive(Debug, clap::Args)]
pub struct BezierArgs {
    /// A small subset with short timing windows (a smoke test; figures are not meaningful).
    #[arg(long)]
    pub quick: bool,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Clone, Serialize)]
struct Row {
    method: &'static str,
    precision: &'static str,
    grid: [usize; 2],
    resolution: [usize; 2],
    /// CPU threads (rayon pool size); `null` for the wgpu backend, where the device decides.
    threads: Option<usize>,
    backend: &'static str,
    evals_per_s: f64,
    runs: u64,
    write_ceiling_evals_per_s: f64,
    fraction_of_write_ceiling: f64,
}

#[derive(Debug, Serialize)]
struct Ceiling {
    precision: &'static str,
    resolution: [usize; 2],
    threads: usize,
    write_ceiling_evals_per_s: f64,
}

#[derive(Debug, Serialize)]
struct Speedup {
    precision: &'static str,
    grid: [usize; 2],
    resolution: [usize; 2],
    threads: usize,
    mle_over_brf: f64,
    mle_over_mat: f64,
}

#[derive(Debug, Serialize)]
pub(crate) struct Machine {
    pub(crate) cpu: String,
    pub(crate) logical_cores: usize,
}

#[derive(Debug, Serialize)]
struct Device {
    name: String,
    backend: String,
    driver: String,
    f64: bool,
}

#[derive(Debug, Serialize)]
struct Report {
    quick: bool,
    machine: Machine,
    /// The wgpu adapter, or `null` when none was found (wgpu rows are then absent).
    wgpu: Option<Device>,
    results: Vec<Row>,
    write_ceilings: Vec<Ceiling>,
    speedups: Vec<Speedup>,
}

/// The sweep: full, or the quick smoke-test subset.
struct Plan {
    grids: Vec<usize>,
    resolutions: Vec<usize>,
    threads: Vec<usize>,
    window: Duration,
    min_runs: u64,
}

impl Plan {
    fn new(quick: bool) -> Self {
        let cores = std::thread::available_parallelism().map_or(1, usize::from);
        let threads: Vec<usize> = [1, 2].into_iter().filter(|&t| t <= cores.max(2)).collect();
        if quick {
            Self {
                grids: vec![4, 12],
                resolutions: vec![64],
                threads: vec![1],
                window: Duration::from_millis(5),
                min_runs: 1,
            }
        } else {
            Self {
                grids: vec![4, 8, 12],
                resolutions: vec![256, 512, 1000],
                threads,
                window: Duration::from_millis(400),
                min_runs: 2,
            }
        }
    }
}

pub fn run(cmd: &Command) -> Result<(), CliError> {
    match cmd {
        Command::Bezier(args) => bezier(args),
        Command::Server(args) => crate::bench_server::run(args),
        Command::Replicas(args) => crate::bench_replicas::run(args),
        Command::Recon(args) => crate::bench_recon::run(args),
    }
}

fn bezier(args: &BezierArgs) -> Result<(), CliError> {
    let plan = Plan::new(args.quick);
    let total = 2 * plan.resolutions.len() * plan.threads.len() * (1 + 3 * plan.grids.len());
    let pb = if args.json || !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        ProgressBar::hidden()
    } else {
        let pb = ProgressBar::new(total as u64);
        if let Ok(s) = ProgressStyle::with_template("{bar:40} {pos}/{len} {msg}") {
            pb.set_style(s);
        }
        pb
    };
    pb.set_message("looking for a wgpu adapter");
    let gpu = GpuContext::try_new();
    let mut results = Vec::new();
    let mut write_ceilings = Vec::new();
    sweep::<f64>(&plan, gpu.as_ref(), &pb, &mut results, &mut write_ceilings)?;
    sweep::<f32>(&plan, gpu.as_ref(), &pb, &mut results, &mut write_ceilings)?;
    pb.finish_and_clear();
    let report = Report {
        quick: args.quick,
        machine: machine(),
        wgpu: gpu.map(|g| Device {
            name: g.info.name.clone(),
            backend: format!("{:?}", g.info.backend).to_lowercase(),
            driver: format!("{} {}", g.info.driver, g.info.driver_info)
                .trim()
                .to_owned(),
            f64: g.caps.f64,
        }),
        speedups: speedups(&results),
        results,
        write_ceilings,
    };
    if args.json {
        return print_json(&report);
    }
    print_table(&report);
    Ok(())
}

fn sweep<T: GpuScalar>(
    plan: &Plan,
    gpu: Option<&GpuContext>,
    pb: &ProgressBar,
    rows: &mut Vec<Row>,
    ceilings: &mut Vec<Ceiling>,
) -> Result<(), CliError> {
    let failed = |e: resecta_bezier::BezierError| CliError::Failed(e.to_string());
    for &res in &plan.resolutions {
        let resolution = Resolution::new(res, res).map_err(failed)?;
        for &threads in &plan.threads {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| CliError::Failed(format!("thread pool: {e}")))?;
            pb.set_message(format!("{} write ceiling {res}² {threads}t", T::NAME));
            let mut buf = vec![[T::ZERO; 3]; resolution.len()];
            let ceiling = pool.install(|| rate(plan, || write_ceiling(&mut buf, T::ONE)).0);
            pb.inc(1);
            ceilings.push(Ceiling {
                precision: T::NAME,
                resolution: [res, res],
                threads,
                write_ceiling_evals_per_s: ceiling,
            });
            for &g in &plan.grids {
                for method in Method::ALL {
                    pb.set_message(format!(
                        "{} {} {g}×{g} {res}² {threads}t",
                        method.name(),
                        T::NAME
                    ));
                    let net = bench_net::<T>(g).map_err(failed)?;
                    let mut prepared =
                        Prepared::new(method, net, resolution, Outputs::Points).map_err(failed)?;
                    let mut err = None;
                    let (evals_per_s, runs) = pool.install(|| {
                        rate(plan, || {
                            if let Err(e) = prepared.run() {
                                err = Some(e);
                            }
                        })
                    });
                    if let Some(e) = err {
                        return Err(failed(e));
                    }
                    pb.inc(1);
                    rows.push(Row {
                        method: method.name(),
                        precision: T::NAME,
                        grid: [g, g],
                        resolution: [res, res],
                        threads: Some(threads),
                        backend: "cpu",
                        evals_per_s,
                        runs,
                        write_ceiling_evals_per_s: ceiling,
                        fraction_of_write_ceiling: evals_per_s / ceiling,
                    });
                }
            }
        }
        if let Some(ctx) = gpu.filter(|c| T::supported(c)) {
            let ceiling = ceilings
                .iter()
                .filter(|c| c.precision == T::NAME && c.resolution == [res, res])
                .map(|c| c.write_ceiling_evals_per_s)
                .fold(0.0, f64::max);
            for &g in &plan.grids {
                pb.set_message(format!("mle {} {g}×{g} {res}² wgpu", T::NAME));
                let net = bench_net::<T>(g).map_err(failed)?;
                let gpu_failed = |e: resecta_gpu::GpuError| CliError::Failed(e.to_string());
                let mut prepared = GpuPrepared::new(ctx, net, resolution).map_err(gpu_failed)?;
                let mut err = None;
                let (evals_per_s, runs) = rate(plan, || {
                    if let Err(e) = prepared.run() {
                        err = Some(e);
                    }
                });
                if let Some(e) = err {
                    return Err(gpu_failed(e));
                }
                rows.push(Row {
                    method: Method::Mle.name(),
                    precision: T::NAME,
                    grid: [g, g],
                    resolution: [res, res],
                    threads: None,
                    backend: "wgpu",
                    evals_per_s,
                    runs,
                    write_ceiling_evals_per_s: ceiling,
                    fraction_of_write_ceiling: evals_per_s / ceiling,
                });
            }
        }
    }
    Ok(())
}

/// Runs `f` repeatedly for the plan's window (and at least `min_runs` times): (runs/s, runs).
fn rate(plan: &Plan, mut f: impl FnMut()) -> (f64, u64) {
    f(); // warm-up
    let start = Instant::now();
    let mut runs = 0u64;
    while runs < plan.min_runs || start.elapsed() < plan.window {
        f();
        runs += 1;
    }
    (runs as f64 / start.elapsed().as_secs_f64(), runs)
}

/// A deterministic non-planar control net of g×g points over a 100 mm square.
fn bench_net<T: resecta_bezier::BezierScalar>(
    g: usize,
) -> Result<ControlNet<T>, resecta_bezier::BezierError> {
    let step = 100.0 / (g - 1) as f64;
    let points: Vec<P3<T>> = (0..g * g)
        .map(|k| {
            let (i, j) = ((k / g) as f64, (k % g) as f64);
            let z = 10.0 * ((i * 0.7).sin() + (j * 1.3).cos());
            [T::from_f64(i * step), T::from_f64(j * step), T::from_f64(z)]
        })
        .collect();
    ControlNet::new(g, g, points)
}

fn speedups(rows: &[Row]) -> Vec<Speedup> {
    let find = |r: &Row, m: &str| {
        rows.iter().find(|o| {
            o.method == m
                && o.precision == r.precision
                && o.grid == r.grid
                && o.resolution == r.resolution
                && o.threads == r.threads
                && o.backend == r.backend
        })
    };
    rows.iter()
        .filter(|r| r.method == "mle" && r.backend == "cpu")
        .filter_map(|r| {
            Some(Speedup {
                precision: r.precision,
                grid: r.grid,
                resolution: r.resolution,
                threads: r.threads?,
                mle_over_brf: r.evals_per_s / find(r, "brf")?.evals_per_s,
                mle_over_mat: r.evals_per_s / find(r, "mat")?.evals_per_s,
            })
        })
        .collect()
}

pub(crate) fn machine() -> Machine {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_owned())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_owned());
    Machine {
        cpu,
        logical_cores: std::thread::available_parallelism().map_or(1, usize::from),
    }
}

fn print_table(r: &Report) {
    println!(
        "{} ({} logical cores){}",
        r.machine.cpu,
        r.machine.logical_cores,
        if r.quick { ", quick" } else { "" }
    );
    println!(
        "{:<7}{:<5}{:>7}{:>11}{:>4} {:<8}{:>14}{:>10}",
        "method", "prec", "grid", "res", "thr", "backend", "evals/s", "ceiling"
    );
    for row in &r.results {
        println!(
            "{:<7}{:<5}{:>7}{:>11}{:>4} {:<8}{:>14.1}{:>9.1}%",
            row.method,
            row.precision,
            format!("{}×{}", row.grid[0], row.grid[1]),
            format!("{}²", row.resolution[0]),
            row.threads.map_or("-".to_owned(), |t| t.to_string()),
            row.backend,
            row.evals_per_s,
            100.0 * row.fraction_of_write_ceiling
        );
    }
    println!("speedups (MLE over BRF / MAT):");
    for s in &r.speedups {
        println!(
            "  {} {}×{} {}² {}t: {:>7.1}× BRF, {:>5.2}× MAT",
            s.precision,
            s.grid[0],
            s.grid[1],
            s.resolution[0],
            s.threads,
            s.mle_over_brf,
            s.mle_over_mat
        );
    }
}
