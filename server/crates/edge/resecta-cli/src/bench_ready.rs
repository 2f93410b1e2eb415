//! `resecta bench server --scenarios ready,restart`: how soon a 512×512×300 session plans.
//!
//! - **ready**: a 512×512×300 u8 label map is uploaded, and the first resection (an initial
//!   resection from the tumour and an end point, Alg. 1–2: its surface, margins and verdict) is
//!   asked for as soon as the upload is acknowledged; then the volumes. Times are reported from
//!   the acknowledgement and from the start of the upload.
//! - **restart**: a data directory holds that session (with one resection) and a few older
//!   sessions; the server is killed (SIGKILL) and spawned again, and the first planning call
//!   on the large session (an edit, or in other runs a volumes request) is timed from the
//!   spawn to its answer.

use std::time::{Duration, Instant};

use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_api::v1::{self as pb, edit_request};
use serde::Serialize;
use tonic::transport::Channel;

use crate::bench_server::{
    Client, LabelMap, connect, create_session, delete, demo_label_map, edit, failed, init_edit,
    large_label_map, percentile, request, spawn_server, upload,
};
use crate::error::CliError;

/// The parts of `resecta bench server` to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Scenario {
    /// Edit → delta latency (one session, 20 sessions) and the memory of an idle session.
    Latency,
    /// Upload of a 512×512×300 label map → acknowledged.
    Upload,
    /// Upload → first resection and → volumes.
    Ready,
    /// Server restart → first planning call on a restored 512×512×300 session.
    Restart,
}

#[derive(Debug, Clone, clap::Args)]
pub struct ReadyArgs {
    /// Scenarios to run, comma-separated (default: all).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_values_t = [Scenario::Latency, Scenario::Upload, Scenario::Ready, Scenario::Restart]
    )]
    pub scenarios: Vec<Scenario>,
    /// Runs of each readiness scenario (`ready`, and `restart` per first call; medians
    /// reported).
    #[arg(long, default_value_t = 3)]
    pub ready_runs: usize,
}

impl ReadyArgs {
    pub fn runs(&self, s: Scenario) -> bool {
        self.scenarios.contains(&s)
    }
}

/// Median, spread and every run (seconds).
#[derive(Debug, Serialize)]
pub struct Figure {
    pub median_s: f64,
    pub min_s: f64,
    pub max_s: f64,
    pub runs_s: Vec<f64>,
}

impl Figure {
    fn of(runs: Vec<f64>) -> Self {
        let mut sorted = runs.clone();
        sorted.sort_by(f64::total_cmp);
        Self {
            median_s: percentile(&sorted, 0.5),
            min_s: sorted.first().copied().unwrap_or(f64::NAN),
            max_s: sorted.last().copied().unwrap_or(f64::NAN),
            runs_s: runs,
        }
    }
}

/// Upload of a 512×512×300 u8 label map → first resection → volumes.
#[derive(Debug, Serialize)]
pub struct Ready {
    pub dims: [u32; 3],
    /// Upload start → acknowledged.
    pub ack: Figure,
    /// Acknowledgement → the first resection's answer (initial resection, 4×4, surface,
    /// margins and verdict computed).
    pub first_resection_from_ack: Figure,
    /// Upload start → the first resection's answer.
    pub first_resection_from_start: Figure,
    /// Upload start → the first volumes answer (asked after the first resection).
    pub volumes_from_start: Figure,
}

/// Restart with a 512×512×300 session (one resection) and older sessions in the data directory.
#[derive(Debug, Serialize)]
pub struct Restart {
    /// Sessions in the data directory besides the large one (demo phantom, one resection each,
    /// used before it).
    pub older_sessions: usize,
    /// Server spawned → start-up line (both faces bound).
    pub bound: Figure,
    /// Server spawned → first call, an edit (one control point moved) on the large session,
    /// answered.
    pub first_edit: Figure,
    /// Then → its volumes answered (from the spawn).
    pub volumes_after_edit: Figure,
    /// Server spawned → first call, the volumes of the large session, answered (other runs).
    pub first_volumes: Figure,
}

const RESECTION: &str = "resection_1";

/// Tumour centre of [`large_label_map`] (RAS mm) and an end point towards the liver's centre.
const TUMOUR: [f64; 3] = [210.0, 179.2, 150.0];
const END_POINT: [f64; 3] = [120.0, 179.2, 150.0];

fn client(channel: &Channel) -> Client {
    PlanningServiceClient::new(channel.clone())
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(64 << 20)
}

/// The first resection's answer must carry the resection and its verdict.
fn check_first(answer: &pb::EditResponse) -> Result<(), CliError> {
    match answer.resections.first() {
        Some(r) if r.resection.is_some() && r.verdict.is_some() => Ok(()),
        _ => Err(CliError::Failed(
            "the first resection's answer has no resection or verdict".into(),
        )),
    }
}

async fn volumes(client: &mut Client, token: Option<&str>, id: &str) -> Result<(), CliError> {
    let v = client
        .get_volumes(request(
            pb::GetVolumesRequest {
                session_id: id.to_owned(),
            },
            token,
        ))
        .await
        .map_err(failed("volumes"))?
        .into_inner();
    if v.volumes.is_none() {
        return Err(CliError::Failed("a volumes answer without volumes".into()));
    }
    Ok(())
}

/// The `ready` scenario against a running server.
pub async fn ready(channel: &Channel, token: Option<&str>, runs: usize) -> Result<Ready, CliError> {
    let map = tokio::task::spawn_blocking(large_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))?;
    let mut client = client(channel);
    let (mut ack, mut from_ack, mut from_start, mut vols) = (vec![], vec![], vec![], vec![]);
    for _ in 0..runs.max(1) {
        let id = create_session(&mut client, token, "readiness benchmark").await?;
        let t0 = Instant::now();
        upload(&mut client, token, &id, &map).await?;
        let acked = Instant::now();
        let answer = edit(&mut client, token, &id, 1, init_edit(TUMOUR, END_POINT)).await?;
        let answered = Instant::now();
        check_first(&answer)?;
        volumes(&mut client, token, &id).await?;
        vols.push(t0.elapsed().as_secs_f64());
        ack.push(acked.duration_since(t0).as_secs_f64());
        from_ack.push(answered.duration_since(acked).as_secs_f64());
        from_start.push(answered.duration_since(t0).as_secs_f64());
        delete(channel, token, &id).await;
        // The server settles (volumes scheduled after the edit, freed memory) between runs.
        tokio::time::sleep(Duration::from_secs(2)).await;
    }
    Ok(Ready {
        dims: [512, 512, 300],
        ack: Figure::of(ack),
        first_resection_from_ack: Figure::of(from_ack),
        first_resection_from_start: Figure::of(from_start),
        volumes_from_start: Figure::of(vols),
    })
}

/// A session on `map` with one initial resection; returns its id and the resection's inner
/// control point (1, 1).
async fn planned_session(
    client: &mut Client,
    map: &LabelMap,
    name: &str,
    target: [f64; 3],
    end: [f64; 3],
) -> Result<(String, pb::Vec3), CliError> {
    let id = create_session(client, None, name).await?;
    upload(client, None, &id, map).await?;
    let answer = edit(client, None, &id, 1, init_edit(target, end)).await?;
    check_first(&answer)?;
    let point = answer
        .resections
        .first()
        .and_then(|r| r.resection.as_ref())
        .and_then(|r| r.control_points.get(5).copied())
        .ok_or_else(|| CliError::Failed("the initial resection has no control points".into()))?;
    volumes(client, None, &id).await?;
    Ok((id, point))
}

/// The `restart` scenario: its own server processes on a temporary data directory.
pub async fn restart(
    runs: usize,
    older: usize,
    gpu: resecta_server::GpuMode,
) -> Result<Restart, CliError> {
    let dir = tempfile::tempdir().map_err(|e| CliError::Failed(format!("temp dir: {e}")))?;
    let large = tokio::task::spawn_blocking(large_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))?;
    let demo = tokio::task::spawn_blocking(demo_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))??;
    let (id, point) = {
        let (server, addr) = spawn_server(dir.path(), None, gpu)?;
        let mut c = client(&connect(&addr).await?);
        for k in 0..older {
            // The demo patient's resection around its large tumour.
            planned_session(
                &mut c,
                &demo,
                &format!("older {k}"),
                [40.0, -10.0, 5.0],
                [-20.0, -10.0, 5.0],
            )
            .await?;
        }
        let planned =
            planned_session(&mut c, &large, "restart benchmark", TUMOUR, END_POINT).await?;
        drop(server);
        planned
    };
    let (mut bound, mut first_edit, mut after_edit, mut first_volumes) =
        (vec![], vec![], vec![], vec![]);
    for run in 0..2 * runs.max(1) {
        let t0 = Instant::now();
        let (server, addr) = spawn_server(dir.path(), None, gpu)?;
        bound.push(t0.elapsed().as_secs_f64());
        let mut c = client(&connect(&addr).await?);
        if run % 2 == 0 {
            let mut p = point;
            p.z += if run % 4 == 0 { 1.0 } else { -1.0 };
            let op = edit_request::Edit::SetControlPoint(pb::SetControlPoint {
                name: RESECTION.into(),
                i: 1,
                j: 1,
                point: Some(p),
            });
            let answer = edit(&mut c, None, &id, 0, op).await?;
            first_edit.push(t0.elapsed().as_secs_f64());
            check_first(&answer)?;
            volumes(&mut c, None, &id).await?;
            after_edit.push(t0.elapsed().as_secs_f64());
        } else {
            volumes(&mut c, None, &id).await?;
            first_volumes.push(t0.elapsed().as_secs_f64());
        }
        // Killed like a crash; every acknowledged edit is on disk.
        drop(server);
    }
    Ok(Restart {
        older_sessions: older,
        bound: Figure::of(bound),
        first_edit: Figure::of(first_edit),
        volumes_after_edit: Figure::of(after_edit),
        first_volumes: Figure::of(first_volumes),
    })
}

/// Prints the figures of a readiness run.
pub fn print(ready: Option<&Ready>, restart: Option<&Restart>) {
    let line = |what: &str, f: &Figure| {
        println!(
            "{what:<44} median {:.3} s (min {:.3}, max {:.3}, {} runs)",
            f.median_s,
            f.min_s,
            f.max_s,
            f.runs_s.len()
        );
    };
    if let Some(r) = ready {
        line("upload 512×512×300 → acknowledged", &r.ack);
        line(
            "acknowledged → first resection",
            &r.first_resection_from_ack,
        );
        line(
            "upload start → first resection",
            &r.first_resection_from_start,
        );
        line("upload start → volumes", &r.volumes_from_start);
    }
    if let Some(r) = restart {
        line("restart: spawn → bound", &r.bound);
        line("restart: spawn → first edit answered", &r.first_edit);
        line(
            "restart: spawn → volumes after that edit",
            &r.volumes_after_edit,
        );
        line("restart: spawn → first call GetVolumes", &r.first_volumes);
    }
}
