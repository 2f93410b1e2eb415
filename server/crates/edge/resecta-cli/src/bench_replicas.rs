//! `resecta bench replicas` (issue #25): two replicas of `resecta serve` on one PostgreSQL
//! store beside one server on SQLite, in one run, on loopback: edit → acknowledged and edit →
//! delta latency of one session at 40×40, sessions per server at a fixed edit rate (the
//! capacity ramp of `bench server`, sessions spread over the replicas), and fail-over: the time
//! from `kill -9` of the replica holding a session to the first edit the other replica answers
//! for it (the lease has to expire, then the survivor restores the session from the log).

use std::ffi::OsString;
use std::time::{Duration, Instant};

use resecta_api::v1::{self as pb, edit_request};
use resecta_server::GpuMode;
use resecta_store::{PostgresStore, SessionStore, StoreOptions};
use serde::Serialize;
use tonic::transport::Channel;

use crate::bench_server::{
    Capacity, Latency, ServerProcess, capacity, connect, delete, demo_label_map, edit, init_edit,
    request, single, spawn_serve, start_server,
};
use crate::error::CliError;
use crate::output::{print_json, progress};

#[derive(Debug, clap::Args)]
pub struct ReplicasArgs {
    /// A PostgreSQL database the benchmark may empty and use (`postgres://USER@HOST:PORT/DB`);
    /// scripts/pg_cluster.sh starts a throwaway server.
    #[arg(long, env = "RESECTA_BENCH_PG", hide_env_values = true)]
    pub pg: String,
    /// Edits of the single-session scenario.
    #[arg(long, default_value_t = 300)]
    pub edits: usize,
    /// Edits per second of each session in the capacity ramp.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// Length of each capacity step (seconds).
    #[arg(long, default_value_t = 4.0)]
    pub seconds: f64,
    /// Most sessions of the capacity ramp (all servers together).
    #[arg(long, default_value_t = 64)]
    pub max_sessions: usize,
    /// Fail-overs measured.
    #[arg(long, default_value_t = 5)]
    pub failovers: usize,
    /// The replicas' lease (ms) [default: the server's, 3000].
    #[arg(long)]
    pub lease_ms: Option<u64>,
    /// Write the capacity plot (`replicas_capacity.svg`/`.png`) here.
    #[arg(long)]
    pub plot_dir: Option<std::path::PathBuf>,
    /// Short runs (a smoke test; figures are not meaningful).
    #[arg(long)]
    pub quick: bool,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Setup {
    setup: &'static str,
    single: Latency,
    capacity: Capacity,
}

#[derive(Debug, Serialize)]
struct Failover {
    lease_ms: u64,
    /// `kill -9` of the holder → the first edit the survivor acknowledged (ms), per run.
    runs_ms: Vec<f64>,
    median_ms: f64,
    max_ms: f64,
    /// Every acknowledged edit was found on the survivor, in every run.
    no_acknowledged_edit_lost: bool,
}

#[derive(Debug, Serialize)]
struct Report {
    setups: Vec<Setup>,
    failover: Failover,
}

pub fn run(args: &ReplicasArgs) -> Result<(), CliError> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::Failed(format!("runtime: {e}")))?;
    runtime.block_on(run_async(args))
}

/// Empties the benchmark's database (sessions of an earlier run would count against quotas).
async fn empty_database(url: &str) -> Result<(), CliError> {
    let url = url.to_owned();
    tokio::task::spawn_blocking(move || {
        let store = PostgresStore::open(&url, None, StoreOptions::default())
            .map_err(|e| CliError::Failed(format!("benchmark database: {e}")))?;
        for s in store
            .sessions()
            .map_err(|e| CliError::Failed(e.to_string()))?
        {
            store
                .delete_session(&s.id)
                .map_err(|e| CliError::Failed(e.to_string()))?;
        }
        Ok(())
    })
    .await
    .map_err(|e| CliError::Failed(e.to_string()))?
}

/// A replica named `name` on the benchmark's database.
fn replica(args: &ReplicasArgs, name: &str) -> Result<(ServerProcess, String), CliError> {
    let mut flags: Vec<OsString> = vec![
        "--store".into(),
        args.pg.clone().into(),
        "--replica-id".into(),
        name.into(),
    ];
    if let Some(ms) = args.lease_ms {
        flags.extend(["--lease-ms".into(), ms.to_string().into()]);
    }
    spawn_serve(&flags, None, GpuMode::Off)
}

async fn run_async(args: &ReplicasArgs) -> Result<(), CliError> {
    let pb = progress(args.json);
    empty_database(&args.pg).await?;
    let map = tokio::task::spawn_blocking(demo_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))??;
    let (edits, seconds, max, failovers) = if args.quick {
        (20, 1.0, 4, 1)
    } else {
        (args.edits, args.seconds, args.max_sessions, args.failovers)
    };
    let mut setups = Vec::new();
    {
        pb.set_message("1 server on SQLite");
        let (server, addr) = start_server(GpuMode::Off)?;
        let channel = connect(&addr).await?;
        let one = std::slice::from_ref(&channel);
        let single = single(&channel, None, &map, [40, 40], edits, None, None).await?;
        let capacity = capacity(one, None, &map, args.rate, max, seconds, None, &pb).await?;
        setups.push(Setup {
            setup: "1 server, SQLite",
            single,
            capacity,
        });
        drop(server);
    }
    {
        pb.set_message("2 replicas on PostgreSQL");
        let (a, a_addr) = replica(args, "bench-a")?;
        let (b, b_addr) = replica(args, "bench-b")?;
        let channels = [connect(&a_addr).await?, connect(&b_addr).await?];
        let single = single(&channels[0], None, &map, [40, 40], edits, None, None).await?;
        let capacity = capacity(&channels, None, &map, args.rate, max, seconds, None, &pb).await?;
        setups.push(Setup {
            setup: "2 replicas, PostgreSQL",
            single,
            capacity,
        });
        drop((a, b));
    }
    let failover = failover(args, &map, failovers, &pb).await?;
    pb.finish_and_clear();
    let report = Report { setups, failover };
    if let Some(dir) = &args.plot_dir {
        crate::output::write_figure(
            &crate::output::files_in(dir)?,
            "replicas_capacity",
            &capacity_figure(&report.setups),
        )?;
    }
    if args.json {
        return print_json(&report);
    }
    for s in &report.setups {
        println!(
            "{:<24} ack p50 {:>6.2} ms  ack p99 {:>6.2} ms  delta p99 {:>6.2} ms  sessions at {} edits/s: {}",
            s.setup,
            s.single.ack_p50_ms,
            s.single.ack_p99_ms,
            s.single.p99_ms,
            s.capacity.rate_per_s,
            s.capacity.sessions
        );
    }
    let f = &report.failover;
    println!(
        "fail-over (lease {} ms): median {:.0} ms, max {:.0} ms over {} runs; no acknowledged edit lost: {}",
        f.lease_ms,
        f.median_ms,
        f.max_ms,
        f.runs_ms.len(),
        f.no_acknowledged_edit_lost
    );
    Ok(())
}

/// Edits moving an inner control point; the version each acknowledged.
async fn drag(
    client: &mut crate::bench_server::Client,
    id: &str,
    base: u64,
    k: usize,
) -> Result<u64, tonic::Status> {
    let op = edit_request::Edit::SetControlPoint(pb::SetControlPoint {
        name: crate::bench_server::RESECTION.into(),
        i: 1,
        j: 1,
        point: Some(pb::Vec3 {
            x: 30.0 - 0.1 * k as f64,
            y: -10.0,
            z: 5.0,
        }),
    });
    client
        .edit(request(
            pb::EditRequest {
                session_id: id.to_owned(),
                base_version: base,
                edit: Some(op),
            },
            None,
        ))
        .await
        .map(|r| r.into_inner().plan_version)
}

async fn failover(
    args: &ReplicasArgs,
    map: &crate::bench_server::LabelMap,
    runs: usize,
    pb: &indicatif::ProgressBar,
) -> Result<Failover, CliError> {
    let mut runs_ms = Vec::with_capacity(runs);
    let mut intact = true;
    for run in 0..runs {
        pb.set_message(format!("fail-over {}/{runs}", run + 1));
        let (mut a, a_addr) = replica(args, &format!("failover-a{run}"))?;
        let (_b, b_addr) = replica(args, &format!("failover-b{run}"))?;
        let (a_channel, b_channel) = (connect(&a_addr).await?, connect(&b_addr).await?);
        let mut on_a = client(&a_channel);
        let id = crate::bench_server::create_session(&mut on_a, None, "fail-over").await?;
        crate::bench_server::upload(&mut on_a, None, &id, map).await?;
        let init = init_edit([40.0, -10.0, 5.0], [-20.0, -10.0, 5.0]);
        let mut acked = edit(&mut on_a, None, &id, 1, init).await?.plan_version;
        // Edits at 30 per second on A, then A dies between two of them.
        for k in 0..10 {
            acked = drag(&mut on_a, &id, acked, k)
                .await
                .map_err(crate::bench_server::failed("edit on the holder"))?;
            tokio::time::sleep(Duration::from_millis(33)).await;
        }
        a.kill();
        let killed = Instant::now();
        let mut on_b = client(&b_channel);
        let answered = loop {
            match drag(&mut on_b, &id, 0, 99).await {
                Ok(v) => break v,
                Err(s) if killed.elapsed() < Duration::from_secs(60) => {
                    if s.code() != tonic::Code::Unavailable {
                        return Err(CliError::Failed(format!(
                            "fail-over: the survivor answered {:?}: {}",
                            s.code(),
                            s.message()
                        )));
                    }
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
                Err(s) => return Err(crate::bench_server::failed("fail-over")(s)),
            }
        };
        runs_ms.push(killed.elapsed().as_secs_f64() * 1e3);
        intact &= answered == acked + 1;
        delete(&b_channel, None, &id).await;
    }
    let mut sorted = runs_ms.clone();
    sorted.sort_by(f64::total_cmp);
    Ok(Failover {
        lease_ms: args.lease_ms.unwrap_or(3000),
        median_ms: crate::bench_server::percentile(&sorted, 0.5),
        max_ms: sorted.last().copied().unwrap_or(f64::NAN),
        runs_ms,
        no_acknowledged_edit_lost: intact,
    })
}

/// p99 of edit → delta and of edit → acknowledged against the sessions editing at once, per
/// set-up, with the 5 ms bound.
fn capacity_figure(setups: &[Setup]) -> resecta_plot::Figure {
    use resecta_plot::{Colour, Figure, MarkerShape, Series, Style};
    let mut series = Vec::new();
    let colours = [Colour::BLUE, Colour::ORANGE];
    let mut most = 1.0_f64;
    for (s, &colour) in setups.iter().zip(&colours) {
        let steps = &s.capacity.steps;
        most = steps.iter().fold(most, |m, l| m.max(l.sessions as f64));
        let at = |f: fn(&Latency) -> f64| steps.iter().map(|l| (l.sessions as f64, f(l))).collect();
        series.push(Series::new(
            format!("{}: edit → delta p99", s.setup),
            at(|l| l.p99_ms),
            Style::Line { colour },
        ));
        series.push(Series::new(
            format!("{}: edit → acknowledged p99", s.setup),
            at(|l| l.ack_p99_ms),
            Style::Markers {
                shape: MarkerShape::Circle,
                colour,
            },
        ));
    }
    series.push(Series::new(
        "5 ms",
        vec![(1.0, 5.0), (most, 5.0)],
        Style::Line {
            colour: Colour::GREY,
        },
    ));
    Figure {
        title: format!(
            "Sessions editing at {} edits/s each (40×40, loopback)",
            setups.first().map_or(30.0, |s| s.capacity.rate_per_s)
        ),
        x_label: "sessions editing at once (all servers)".into(),
        y_label: "p99 latency (ms)".into(),
        log_x: true,
        series,
        width: 900,
        height: 560,
    }
}

fn client(channel: &Channel) -> crate::bench_server::Client {
    crate::bench_server::Client::new(channel.clone()).max_decoding_message_size(1 << 30)
}
