//! `resecta bench server`: the load benchmark of issue #6 against a real server process on
//! loopback, over gRPC. It starts `resecta serve` (this binary) with a fresh data directory unless
//! `--addr` names a running server, uploads the demo phantom, and measures
//! edit → delta latency as a watching client sees it (the time from sending an edit until the
//! watch stream delivers the delta of that plan version), alone at 40×40 and 200×200 and with many
//! sessions editing at a fixed rate at once; the server's memory per idle session; the upload
//! time of a 512×512×300 u8 label map; and how soon such a session plans after its upload and
//! after a restart (`bench_ready`). `--scenarios` picks some of these. `--gpu` starts the server
//! with that compute backend; `--compare-gpu` runs the single-session latency scenario at
//! 40×40, 200×200 and 500×500 on a `--gpu off` server and then on a `--gpu required` one, and
//! reports both side by side with the backend each server reported (`GetServerInfo.compute`).

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_api::v1::{
    self as pb, CreateSessionRequest, DeleteSessionRequest, EditRequest, RawLabelMapHeader,
    UploadLabelMapRequest, WatchRequest, edit_request, upload_label_map_request, watch_response,
};
use resecta_phantom::{PhantomSpec, generate};
use resecta_server::GpuMode;
use serde::Serialize;
use tokio::sync::mpsc;
use tonic::transport::Channel;

use crate::bench_ready::Scenario;
use crate::error::CliError;
use crate::output::{print_json, progress};

#[derive(Debug, clap::Args)]
pub struct ServerArgs {
    /// A running server's gRPC address (`http://HOST:PORT`); by default the benchmark starts
    /// `resecta serve` on loopback with a temporary data directory and stops it afterwards.
    #[arg(long, conflicts_with = "compare_gpu")]
    pub addr: Option<String>,
    /// Bearer token for `--addr`.
    #[arg(long, env = "RESECTA_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Edits per single-session scenario.
    #[arg(long, default_value_t = 300)]
    pub edits: usize,
    /// Sessions editing at once in the concurrent scenario.
    #[arg(long, default_value_t = 20)]
    pub sessions: usize,
    /// Edits per second of each session in the concurrent scenario.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// Length of the concurrent scenario (seconds).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Idle sessions created to measure memory per session (needs a started server).
    #[arg(long, default_value_t = 10)]
    pub idle_sessions: usize,
    /// Uploads of the 512×512×300 label map (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub uploads: usize,
    /// Short runs (a smoke test; figures are not meaningful).
    #[arg(long)]
    pub quick: bool,
    /// The compute backend of the server the benchmark starts (`resecta serve --gpu`).
    #[arg(long, value_enum, default_value_t = GpuMode::Off)]
    pub gpu: GpuMode,
    /// Only the single-session latency at 40×40, 200×200 and 500×500, on a `--gpu off` server
    /// and then on a `--gpu required` one (WGPU_BACKEND picks the adapter), side by side; each
    /// resolution runs `--edits` edits or `--seconds`, whichever ends first.
    #[arg(long, conflicts_with = "gpu")]
    pub compare_gpu: bool,
    /// With `--compare-gpu`: the capacity ramp doubles the sessions editing at `--rate` each
    /// (40×40, `--seconds` per step, at most 5 s) from 1 up to this many, while edit → delta p99
    /// stays within 5 ms.
    #[arg(long, default_value_t = 256)]
    pub max_sessions: usize,
    /// Write latency CDF plots (PNG and SVG) here.
    #[arg(long, conflicts_with = "compare_gpu")]
    pub plot_dir: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub drag: Box<crate::bench_python::DragArgs>,
    #[command(flatten)]
    pub ready: crate::bench_ready::ReadyArgs,
}

/// Latency percentiles of one scenario (milliseconds).
#[derive(Debug, Clone, Serialize)]
pub(crate) struct Latency {
    pub(crate) scenario: String,
    resolution: [u32; 2],
    pub(crate) sessions: usize,
    pub(crate) edits: usize,
    pub(crate) p50_ms: f64,
    pub(crate) p90_ms: f64,
    pub(crate) p99_ms: f64,
    pub(crate) max_ms: f64,
    /// Edit sent → its acknowledgement (the log record durable): watchers are shown an edit
    /// before it is stored, so this can exceed the delta latency above.
    pub(crate) ack_p50_ms: f64,
    pub(crate) ack_p99_ms: f64,
    /// CPU the server process and the benchmark client used during the scenario (cores, from
    /// /proc: user + system time over wall time); absent where unreadable.
    server_cores: Option<f64>,
    pub(crate) client_cores: Option<f64>,
    /// Server CPU time per edit (ms): less sensitive than latency to other jobs on the machine.
    server_cpu_ms_per_edit: Option<f64>,
    #[serde(skip)]
    samples: Vec<f64>,
}

#[derive(Debug, Serialize)]
struct Upload {
    dims: [u32; 3],
    bytes: u64,
    /// Upload acknowledged (stored durably, summary answered).
    median_s: f64,
    runs_s: Vec<f64>,
    /// Upload start to the first volumes answer: the planning set-up (liver envelope, tumour
    /// models, distance structures) that follows the acknowledgement off the request path.
    ready_median_s: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    quick: bool,
    cpu: String,
    logical_cores: usize,
    server: &'static str,
    /// The server's compute backend (`GetServerInfo.compute`).
    compute: Compute,
    latencies: Vec<Latency>,
    /// Concurrent p99 over the single-session p99 at the same resolution (edits back to back).
    concurrent_p99_ratio: f64,
    /// Concurrent p99 over the p99 of one session editing at the same pace (`--rate`) alone:
    /// what concurrency alone adds.
    concurrent_p99_ratio_paced: f64,
    /// Server resident memory per idle session with the demo label map and one resection
    /// (bytes); absent against `--addr`.
    idle_session_bytes: Option<f64>,
    upload: Option<Upload>,
    /// Upload → first resection → volumes (`bench_ready`).
    ready: Option<crate::bench_ready::Ready>,
    /// Restart → first planning call (`bench_ready`).
    restart: Option<crate::bench_ready::Restart>,
}

pub(crate) type Client = PlanningServiceClient<Channel>;

/// A started server process, stopped (SIGKILL) on drop; with the temporary data directory it
/// owns, if any.
pub(crate) struct ServerProcess {
    child: Child,
    _dir: Option<tempfile::TempDir>,
}

impl ServerProcess {
    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    /// `kill -9`, and waits for the process to end.
    pub(crate) fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `resecta serve --gpu gpu` on a temporary data directory.
pub(crate) fn start_server(gpu: GpuMode) -> Result<(ServerProcess, String), CliError> {
    let dir = tempfile::tempdir().map_err(|e| CliError::Failed(format!("temp dir: {e}")))?;
    let path = dir.path().to_owned();
    spawn_server(&path, Some(dir), gpu)
}

/// `--gpu`'s value for `mode`.
fn gpu_flag(mode: GpuMode) -> String {
    clap::ValueEnum::to_possible_value(&mode).map_or_else(String::new, |v| v.get_name().into())
}

/// Spawns `resecta serve --gpu gpu` on `data_dir` (keeping `owned` until it stops) and returns it
/// with its gRPC address once both faces are bound.
pub(crate) fn spawn_server(
    data_dir: &std::path::Path,
    owned: Option<tempfile::TempDir>,
    gpu: GpuMode,
) -> Result<(ServerProcess, String), CliError> {
    let store = [std::ffi::OsString::from("--data-dir"), data_dir.into()];
    spawn_serve(&store, owned, gpu)
}

/// Spawns `resecta serve --gpu gpu` with `store_args` (keeping `owned` until it stops) and
/// returns it with its gRPC address once both faces are bound.
pub(crate) fn spawn_serve(
    store_args: &[std::ffi::OsString],
    owned: Option<tempfile::TempDir>,
    gpu: GpuMode,
) -> Result<(ServerProcess, String), CliError> {
    let exe = std::env::current_exe().map_err(|e| CliError::Failed(format!("own path: {e}")))?;
    let mut child = Command::new(exe)
        .args(["serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"])
        .args(["--gpu", &gpu_flag(gpu)])
        .args(store_args)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| CliError::Failed(format!("starting the server: {e}")))?;
    let stdout = child.stdout.take();
    let server = ServerProcess { child, _dir: owned };
    let mut line = String::new();
    if let Some(out) = stdout {
        std::io::BufRead::read_line(&mut std::io::BufReader::new(out), &mut line)
            .map_err(|e| CliError::Failed(format!("reading the server's addresses: {e}")))?;
    }
    if line.trim().is_empty() {
        return Err(CliError::Failed(format!(
            "resecta serve --gpu {} exited before binding (its error is above)",
            gpu_flag(gpu)
        )));
    }
    let bound: serde_json::Value = serde_json::from_str(line.trim())
        .map_err(|e| CliError::Failed(format!("server start-up line {line:?}: {e}")))?;
    let grpc = bound["grpc"]
        .as_str()
        .ok_or_else(|| CliError::Failed(format!("no gRPC address in {line:?}")))?;
    Ok((server, format!("http://{grpc}")))
}

/// A watch of session `id` from its snapshot, plain frames.
pub(crate) async fn watch(
    client: &mut Client,
    token: Option<&str>,
    id: &str,
) -> Result<tonic::Streaming<pb::WatchResponse>, CliError> {
    Ok(client
        .watch(request(
            WatchRequest {
                session_id: id.to_owned(),
                since_seq: None,
                allow_zstd: false,
                allow_quantized: false,
            },
            token,
        ))
        .await
        .map_err(failed("watch"))?
        .into_inner())
}

/// A channel to the gRPC server at `addr` (`http://HOST:PORT`).
pub(crate) async fn connect(addr: &str) -> Result<Channel, CliError> {
    Channel::from_shared(addr.to_owned())
        .map_err(|e| CliError::BadInput(format!("server address {addr:?}: {e}")))?
        .tcp_nodelay(true)
        .connect()
        .await
        .map_err(|e| CliError::Failed(format!("connecting to {addr}: {e}")))
}

/// The server at `given` (`--addr`), or one started here with backend `gpu`; its address and a
/// channel to it.
pub(crate) async fn server_and_channel(
    given: Option<&str>,
    gpu: GpuMode,
    pb: &indicatif::ProgressBar,
) -> Result<(Option<ServerProcess>, String, Channel), CliError> {
    let (server, addr) = match given {
        Some(a) => (None, a.to_owned()),
        None => {
            pb.set_message(format!("starting the server (--gpu {})", gpu_flag(gpu)));
            let (s, a) = start_server(gpu)?;
            (Some(s), a)
        }
    };
    let channel = connect(&addr).await?;
    Ok((server, addr, channel))
}

/// A new 4×4 resection named [`RESECTION`] from the tumour at `target` towards `end`.
pub(crate) fn init_edit(target: [f64; 3], end: [f64; 3]) -> edit_request::Edit {
    edit_request::Edit::InitFromEndPoint(pb::InitFromEndPoint {
        name: RESECTION.into(),
        target: Some(pb::Target {
            labels: Vec::new(),
            points: vec![v3(target)],
        }),
        end_point: Some(v3(end)),
        grid_m: 4,
        grid_n: 4,
    })
}

fn rss_bytes(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024.0)
}

pub(crate) fn failed(what: &str) -> impl Fn(tonic::Status) -> CliError + '_ {
    move |s| CliError::Failed(format!("{what}: {} ({:?})", s.message(), s.code()))
}

/// A request with the bearer token and the API version header.
pub(crate) fn request<T>(msg: T, token: Option<&str>) -> tonic::Request<T> {
    let mut r = tonic::Request::new(msg);
    let md = r.metadata_mut();
    md.insert(
        resecta_api::API_VERSION_HEADER,
        tonic::metadata::MetadataValue::from_static(resecta_api::API_VERSION_HEADER_VALUE),
    );
    if let Some(t) = token
        && let Ok(v) = format!("Bearer {t}").parse()
    {
        md.insert("authorization", v);
    }
    r
}

/// The label map to plan on, as raw little-endian bytes with its header.
pub(crate) struct LabelMap {
    pub(crate) header: RawLabelMapHeader,
    pub(crate) data: Vec<u8>,
}

pub(crate) fn demo_label_map() -> Result<LabelMap, CliError> {
    let phantom = generate(&PhantomSpec::demo()).map_err(|e| CliError::Failed(e.to_string()))?;
    let g = phantom.labels.grid();
    let d = g.direction();
    let data: Vec<u8> = phantom
        .labels
        .data()
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    Ok(LabelMap {
        header: RawLabelMapHeader {
            session_id: String::new(),
            dims: g.dims().iter().map(|&n| n as u32).collect(),
            spacing: g.spacing().to_vec(),
            origin: Vec::from(<[f64; 3]>::from(g.origin())),
            direction: (0..9).map(|k| d[(k / 3, k % 3)]).collect(),
            data_type: pb::DataType::Uint16 as i32,
            roles: None,
            total_bytes: data.len() as u64,
        },
        data,
    })
}

/// A 512×512×300 u8 label map at 0.7×0.7×1 mm: an ellipsoid liver (1) with a tumour (2).
pub(crate) fn large_label_map() -> LabelMap {
    let (nx, ny, nz) = (512usize, 512usize, 300usize);
    let mut data = vec![0u8; nx * ny * nz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let (x, y, z) = (
                    (i as f64 - 256.0) / 200.0,
                    (j as f64 - 256.0) / 150.0,
                    (k as f64 - 150.0) / 120.0,
                );
                let t = ((i as f64 - 300.0).powi(2) + (j as f64 - 256.0).powi(2)) / 900.0
                    + (k as f64 - 150.0).powi(2) / 400.0;
                data[(k * ny + j) * nx + i] = if t <= 1.0 {
                    2
                } else {
                    u8::from(x * x + y * y + z * z <= 1.0)
                };
            }
        }
    }
    LabelMap {
        header: RawLabelMapHeader {
            session_id: String::new(),
            dims: vec![nx as u32, ny as u32, nz as u32],
            spacing: vec![0.7, 0.7, 1.0],
            origin: vec![0.0; 3],
            direction: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            data_type: pb::DataType::Uint8 as i32,
            roles: None,
            total_bytes: data.len() as u64,
        },
        data,
    }
}

pub(crate) async fn upload(
    client: &mut Client,
    token: Option<&str>,
    id: &str,
    map: &LabelMap,
) -> Result<(), CliError> {
    let mut header = map.header.clone();
    header.session_id = id.to_owned();
    let chunks: Vec<UploadLabelMapRequest> = map
        .data
        .chunks(resecta_api::MAX_CHUNK_BYTES)
        .enumerate()
        .map(|(k, c)| UploadLabelMapRequest {
            header: (k == 0).then(|| upload_label_map_request::Header::Raw(header.clone())),
            data: c.to_vec(),
        })
        .collect();
    client
        .upload_label_map(request(tokio_stream::iter(chunks), token))
        .await
        .map_err(failed("label-map upload"))?;
    Ok(())
}

pub(crate) async fn create_session(
    client: &mut Client,
    token: Option<&str>,
    display_name: &str,
) -> Result<String, CliError> {
    client
        .create_session(request(
            CreateSessionRequest {
                display_name: display_name.into(),
            },
            token,
        ))
        .await
        .map_err(failed("create session"))?
        .into_inner()
        .session
        .map(|s| s.id)
        .ok_or_else(|| CliError::Failed("create session: no session in the answer".into()))
}

pub(crate) async fn edit(
    client: &mut Client,
    token: Option<&str>,
    id: &str,
    base: u64,
    op: edit_request::Edit,
) -> Result<pb::EditResponse, CliError> {
    Ok(client
        .edit(request(
            EditRequest {
                session_id: id.to_owned(),
                base_version: base,
                edit: Some(op),
            },
            token,
        ))
        .await
        .map_err(failed("edit"))?
        .into_inner())
}

pub(crate) fn v3(p: [f64; 3]) -> pb::Vec3 {
    pb::Vec3 {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

/// A planning session with the demo phantom, one resection at `resolution`, and a watcher that
/// reports the arrival time of every plan version's delta.
struct Planning {
    client: Client,
    token: Option<String>,
    id: String,
    version: u64,
    point: pb::Vec3,
    arrivals: mpsc::UnboundedReceiver<(u64, Instant)>,
}

pub(crate) const RESECTION: &str = "resection_1";

async fn planning_session(
    channel: &Channel,
    token: Option<&str>,
    map: &LabelMap,
    resolution: [u32; 2],
) -> Result<Planning, CliError> {
    let mut client = PlanningServiceClient::new(channel.clone())
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(64 << 20);
    let id = create_session(&mut client, token, "load benchmark").await?;
    upload(&mut client, token, &id, map).await?;
    // The demo patient's resection: around the large tumour, towards the left lobe.
    let init = edit(
        &mut client,
        token,
        &id,
        1,
        init_edit([40.0, -10.0, 5.0], [-20.0, -10.0, 5.0]),
    )
    .await?;
    let set = edit(
        &mut client,
        token,
        &id,
        init.plan_version,
        edit_request::Edit::SetResolution(pb::SetResolution {
            name: RESECTION.into(),
            ru: resolution[0],
            rv: resolution[1],
        }),
    )
    .await?;
    let mut stream = watch(&mut client, token, &id).await?;
    // The snapshot (in parts when large) names the control points; the benchmark moves an
    // inner one.
    let mut point = None;
    while point.is_none() {
        let part = match stream.message().await.map_err(failed("watch"))? {
            Some(pb::WatchResponse {
                event: Some(watch_response::Event::Snapshot(s)),
                ..
            }) => s,
            _ => break,
        };
        point = part
            .resections
            .iter()
            .find(|r| r.name == RESECTION)
            .and_then(|r| r.resection.as_ref())
            .and_then(|r| r.control_points.get(5).copied());
        if part.complete {
            break;
        }
    }
    let point = point
        .ok_or_else(|| CliError::Failed("watch: no snapshot with the resection first".into()))?;
    let (tx, arrivals) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok(Some(m)) = stream.message().await {
            if matches!(
                m.event,
                Some(watch_response::Event::Delta(_) | watch_response::Event::Snapshot(_))
            ) && tx.send((m.plan_version, Instant::now())).is_err()
            {
                break;
            }
        }
    });
    Ok(Planning {
        client,
        token: token.map(str::to_owned),
        id,
        version: set.plan_version,
        point,
        arrivals,
    })
}

impl Planning {
    /// Moves an inner control point by ±1 mm and waits for its delta and acknowledgement.
    async fn timed_edit(&mut self, k: usize) -> Result<Timed, CliError> {
        let mut p = self.point;
        p.z += if k.is_multiple_of(2) { 1.0 } else { 0.0 };
        let sent = Instant::now();
        let answer = edit(
            &mut self.client,
            self.token.as_deref(),
            &self.id,
            self.version,
            edit_request::Edit::SetControlPoint(pb::SetControlPoint {
                name: RESECTION.into(),
                i: 1,
                j: 1,
                point: Some(p),
            }),
        )
        .await?;
        let ack_ms = sent.elapsed().as_secs_f64() * 1e3;
        self.version = answer.plan_version;
        loop {
            let (version, at) = tokio::time::timeout(Duration::from_secs(30), self.arrivals.recv())
                .await
                .map_err(|_| CliError::Failed("no delta within 30 s of an edit".into()))?
                .ok_or_else(|| CliError::Failed("the watch stream ended".into()))?;
            if version >= self.version {
                return Ok(Timed {
                    delta_ms: at.duration_since(sent).as_secs_f64() * 1e3,
                    ack_ms,
                });
            }
        }
    }
}

/// One edit's latencies (ms).
pub(crate) struct Timed {
    /// Edit sent → its delta received by the watching client.
    pub(crate) delta_ms: f64,
    /// Edit sent → acknowledged.
    pub(crate) ack_ms: f64,
}

pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * (sorted.len() - 1) as f64).round() as usize;
    sorted[rank.min(sorted.len() - 1)]
}

pub(crate) fn latency(
    scenario: &str,
    resolution: [u32; 2],
    sessions: usize,
    timed: Vec<Timed>,
) -> Latency {
    let sorted = |f: fn(&Timed) -> f64| {
        let mut v: Vec<f64> = timed.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let samples = sorted(|t| t.delta_ms);
    let acks = sorted(|t| t.ack_ms);
    Latency {
        scenario: scenario.into(),
        resolution,
        sessions,
        edits: samples.len(),
        p50_ms: percentile(&samples, 0.50),
        p90_ms: percentile(&samples, 0.90),
        p99_ms: percentile(&samples, 0.99),
        max_ms: samples.last().copied().unwrap_or(f64::NAN),
        ack_p50_ms: percentile(&acks, 0.50),
        ack_p99_ms: percentile(&acks, 0.99),
        server_cores: None,
        server_cpu_ms_per_edit: None,
        client_cores: None,
        samples,
    }
}

/// User + system CPU seconds of a process (`self` or a pid), at Linux's 100 ticks per second.
fn cpu_seconds(pid: &str) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// CPU use of the server (`pid`) and this client from `start` to `finish`.
pub(crate) struct Load {
    pid: Option<u32>,
    server: Option<f64>,
    client: Option<f64>,
    t: Instant,
}

impl Load {
    fn server_now(pid: Option<u32>) -> Option<f64> {
        pid.and_then(|p| cpu_seconds(&p.to_string()))
    }

    pub(crate) fn start(pid: Option<u32>) -> Self {
        Self {
            pid,
            server: Self::server_now(pid),
            client: cpu_seconds("self"),
            t: Instant::now(),
        }
    }

    pub(crate) fn finish(self, l: &mut Latency) {
        let wall = self.t.elapsed().as_secs_f64();
        l.server_cores = self
            .server
            .zip(Self::server_now(self.pid))
            .map(|(a, b)| (b - a) / wall);
        l.server_cpu_ms_per_edit = l
            .server_cores
            .map(|c| c * wall * 1e3 / l.edits.max(1) as f64);
        l.client_cores = self
            .client
            .zip(cpu_seconds("self"))
            .map(|(a, b)| (b - a) / wall);
    }
}

/// One session editing back to back at `resolution`: `edits` edits after a warm-up, or fewer
/// when `budget` (from the first timed edit) runs out first (at least 3).
pub(crate) async fn single(
    channel: &Channel,
    token: Option<&str>,
    map: &LabelMap,
    resolution: [u32; 2],
    edits: usize,
    budget: Option<Duration>,
    pid: Option<u32>,
) -> Result<Latency, CliError> {
    let mut s = planning_session(channel, token, map, resolution).await?;
    for k in 0..edits.min(10) {
        s.timed_edit(k).await?; // warm-up
    }
    let load = Load::start(pid);
    let mut samples = Vec::with_capacity(edits);
    for k in 0..edits {
        if k >= 3 && budget.is_some_and(|b| load.t.elapsed() >= b) {
            break;
        }
        samples.push(s.timed_edit(k).await?);
    }
    let mut l = latency("single session", resolution, 1, samples);
    load.finish(&mut l);
    delete(channel, token, &s.id).await;
    Ok(l)
}

/// `n_sessions` sessions editing at `rate` each for `seconds`, their phases spread over a
/// period; session k on server `channels[k % channels.len()]`.
pub(crate) async fn paced(
    channels: &[Channel],
    token: Option<&str>,
    map: &LabelMap,
    rate: f64,
    n_sessions: usize,
    seconds: f64,
    pid: Option<u32>,
) -> Result<Latency, CliError> {
    let mut sessions = Vec::with_capacity(n_sessions);
    for k in 0..n_sessions {
        let channel = &channels[k % channels.len()];
        sessions.push((
            channel.clone(),
            planning_session(channel, token, map, [40, 40]).await?,
        ));
    }
    let ids: Vec<(Channel, String)> = sessions
        .iter()
        .map(|(c, s)| (c.clone(), s.id.clone()))
        .collect();
    let period = Duration::from_secs_f64(1.0 / rate.max(0.1));
    let count = (seconds * rate).ceil() as usize;
    let load = Load::start(pid);
    let tasks: Vec<_> = sessions
        .into_iter()
        .enumerate()
        .map(|(n, (_, mut s))| {
            tokio::spawn(async move {
                // Spread the sessions' phases over one period.
                tokio::time::sleep(period.mul_f64(n as f64 / n_sessions as f64)).await;
                let mut tick = tokio::time::interval(period);
                tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                let mut samples = Vec::with_capacity(count);
                for k in 0..count {
                    tick.tick().await;
                    samples.push(s.timed_edit(k).await?);
                }
                Ok::<_, CliError>(samples)
            })
        })
        .collect();
    let mut all = Vec::new();
    for t in tasks {
        all.extend(
            t.await
                .map_err(|e| CliError::Failed(format!("session task: {e}")))??,
        );
    }
    let scenario = if n_sessions == 1 {
        "single session, paced"
    } else {
        "concurrent sessions"
    };
    let mut l = latency(scenario, [40, 40], n_sessions, all);
    load.finish(&mut l);
    for (channel, id) in &ids {
        delete(channel, token, id).await;
    }
    Ok(l)
}

pub(crate) async fn delete(channel: &Channel, token: Option<&str>, id: &str) {
    let mut client = PlanningServiceClient::new(channel.clone());
    let _ = client
        .delete_session(request(
            DeleteSessionRequest {
                session_id: id.to_owned(),
            },
            token,
        ))
        .await;
}

async fn idle_memory(
    channel: &Channel,
    token: Option<&str>,
    map: &LabelMap,
    pid: u32,
    n: usize,
) -> Result<f64, CliError> {
    // One session first: thread pools and other one-time set-up are not a session's cost.
    let warm = planning_session(channel, token, map, [40, 40]).await?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let before = rss_bytes(pid).unwrap_or(f64::NAN);
    let mut ids = vec![warm.id];
    for _ in 0..n {
        let s = planning_session(channel, token, map, [40, 40]).await?;
        ids.push(s.id);
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after = rss_bytes(pid).unwrap_or(f64::NAN);
    for id in &ids {
        delete(channel, token, id).await;
    }
    Ok((after - before) / n.max(1) as f64)
}

async fn uploads(channel: &Channel, token: Option<&str>, runs: usize) -> Result<Upload, CliError> {
    let map = tokio::task::spawn_blocking(large_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))?;
    let mut client =
        PlanningServiceClient::new(channel.clone()).max_encoding_message_size(64 << 20);
    let mut times = Vec::new();
    let mut ready = Vec::new();
    for _ in 0..runs.max(1) {
        let id = create_session(&mut client, token, "upload benchmark").await?;
        let t = Instant::now();
        upload(&mut client, token, &id, &map).await?;
        times.push(t.elapsed().as_secs_f64());
        // Waits for the planning set-up, so that the next run does not share the cores with it.
        client
            .get_volumes(request(
                pb::GetVolumesRequest {
                    session_id: id.clone(),
                },
                token,
            ))
            .await
            .map_err(failed("volumes after the upload"))?;
        ready.push(t.elapsed().as_secs_f64());
        delete(channel, token, &id).await;
    }
    let median = |v: &[f64]| {
        let mut sorted = v.to_vec();
        sorted.sort_by(f64::total_cmp);
        percentile(&sorted, 0.5)
    };
    Ok(Upload {
        dims: [512, 512, 300],
        bytes: map.data.len() as u64,
        median_s: median(&times),
        ready_median_s: median(&ready),
        runs_s: times,
    })
}

/// A server's compute backend as `GetServerInfo.compute` reports it.
#[derive(Debug, Clone, Serialize)]
struct Compute {
    /// `"cpu"` or `"wgpu"`.
    backend: String,
    /// The GPU adapter's name; empty on the CPU.
    adapter: String,
    /// Surfaces evaluated in 64-bit floats.
    f64: bool,
}

async fn compute_info(channel: &Channel, token: Option<&str>) -> Result<Compute, CliError> {
    let info = PlanningServiceClient::new(channel.clone())
        .get_server_info(request(pb::GetServerInfoRequest {}, token))
        .await
        .map_err(failed("server info"))?
        .into_inner();
    let c = info.compute.unwrap_or_default();
    Ok(Compute {
        backend: c.backend,
        adapter: c.adapter,
        f64: c.f64,
    })
}

/// Resolutions of `--compare-gpu`.
const COMPARED: [[u32; 2]; 3] = [[40, 40], [200, 200], [500, 500]];

/// One server's runs in `--compare-gpu`.
#[derive(Debug, Serialize)]
struct BackendRuns {
    /// `resecta serve --gpu` value.
    gpu: String,
    compute: Compute,
    /// Single session, back to back, at each of [`COMPARED`].
    latencies: Vec<Latency>,
    capacity: Capacity,
}

/// Edit → delta p99 bound of the capacity ramp (ms).
const CAPACITY_P99_MS: f64 = 5.0;

/// Sessions per server at a fixed edit rate: the ramp's steps and the most sessions whose
/// edit → delta p99 stayed within [`CAPACITY_P99_MS`] (0: not even one).
#[derive(Debug, Serialize)]
pub(crate) struct Capacity {
    pub(crate) rate_per_s: f64,
    p99_bound_ms: f64,
    pub(crate) sessions: usize,
    pub(crate) steps: Vec<Latency>,
}

/// Doubles the sessions editing at `rate` each (spread over `channels`' servers) from 1 (one
/// per server) to `max` while p99 stays in bound.
pub(crate) async fn capacity(
    channels: &[Channel],
    token: Option<&str>,
    map: &LabelMap,
    rate: f64,
    max: usize,
    seconds: f64,
    pid: Option<u32>,
    pb: &indicatif::ProgressBar,
) -> Result<Capacity, CliError> {
    let mut steps = Vec::new();
    let mut sessions = 0;
    let mut n = channels.len();
    while n <= max {
        pb.set_message(format!("capacity: {n} sessions at {rate} edits/s"));
        let l = paced(channels, token, map, rate, n, seconds, pid).await?;
        let within = l.p99_ms <= CAPACITY_P99_MS;
        steps.push(l);
        if !within {
            break;
        }
        sessions = n;
        n *= 2;
    }
    Ok(Capacity {
        rate_per_s: rate,
        p99_bound_ms: CAPACITY_P99_MS,
        sessions,
        steps,
    })
}

/// At one resolution, the `--gpu off` server's figure over the `--gpu required` one's (above 1:
/// the GPU server is faster).
#[derive(Debug, Serialize)]
struct CpuOverGpu {
    resolution: [u32; 2],
    delta_p50: f64,
    server_cpu_ms_per_edit: Option<f64>,
}

#[derive(Debug, Serialize)]
struct CompareReport {
    quick: bool,
    cpu: String,
    logical_cores: usize,
    /// Timed edits asked for per resolution, and the time that cuts them short (seconds).
    edits: usize,
    budget_s: f64,
    backends: Vec<BackendRuns>,
    cpu_over_gpu: Vec<CpuOverGpu>,
}

/// `--compare-gpu`: the single-session scenario at [`COMPARED`] on a `--gpu off` server, then on
/// a `--gpu required` one.
async fn compare_gpu(args: &ServerArgs, pb: &indicatif::ProgressBar) -> Result<(), CliError> {
    let token = args.token.as_deref();
    let map = tokio::task::spawn_blocking(demo_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))??;
    let (edits, budget_s) = if args.quick {
        (args.edits.min(20), 1.0)
    } else {
        (args.edits, args.seconds)
    };
    let mut backends = Vec::new();
    for gpu in [GpuMode::Off, GpuMode::Required] {
        let (server, _, channel) = server_and_channel(None, gpu, pb).await?;
        let compute = compute_info(&channel, token).await?;
        let mut latencies = Vec::new();
        for r in COMPARED {
            pb.set_message(format!(
                "--gpu {}: one session, {}×{}",
                gpu_flag(gpu),
                r[0],
                r[1]
            ));
            let budget = Some(Duration::from_secs_f64(budget_s));
            let pid = server.as_ref().map(ServerProcess::pid);
            latencies.push(single(&channel, token, &map, r, edits, budget, pid).await?);
        }
        let pid = server.as_ref().map(ServerProcess::pid);
        let (max, seconds) = if args.quick {
            (args.max_sessions.min(2), 1.0)
        } else {
            (args.max_sessions, budget_s.min(5.0))
        };
        let one = std::slice::from_ref(&channel);
        let capacity = capacity(one, token, &map, args.rate, max, seconds, pid, pb).await?;
        drop(server);
        backends.push(BackendRuns {
            gpu: gpu_flag(gpu),
            compute,
            latencies,
            capacity,
        });
    }
    pb.finish_and_clear();
    let cpu_over_gpu = match &backends[..] {
        [off, gpu] => off
            .latencies
            .iter()
            .zip(&gpu.latencies)
            .map(|(c, g)| CpuOverGpu {
                resolution: c.resolution,
                delta_p50: c.p50_ms / g.p50_ms,
                server_cpu_ms_per_edit: c
                    .server_cpu_ms_per_edit
                    .zip(g.server_cpu_ms_per_edit)
                    .map(|(c, g)| c / g),
            })
            .collect(),
        _ => Vec::new(),
    };
    let report = CompareReport {
        quick: args.quick,
        cpu: cpu_name(),
        logical_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        edits,
        budget_s,
        backends,
        cpu_over_gpu,
    };
    if args.json {
        return print_json(&report);
    }
    for b in &report.backends {
        let c = &b.compute;
        let backend = format!("{} {}", c.backend, c.adapter);
        println!("--gpu {}: {} (f64: {})", b.gpu, backend.trim_end(), c.f64);
        print_latencies(&b.latencies);
        print_latencies(&b.capacity.steps);
        println!(
            "sessions at {} edits/s with p99 ≤ {} ms: {}",
            b.capacity.rate_per_s, b.capacity.p99_bound_ms, b.capacity.sessions
        );
    }
    for r in &report.cpu_over_gpu {
        println!(
            "{}×{}: cpu / gpu delta p50 {:.2}, server CPU per edit {}",
            r.resolution[0],
            r.resolution[1],
            r.delta_p50,
            r.server_cpu_ms_per_edit
                .map_or_else(|| "n/a".into(), |x| format!("{x:.2}"))
        );
    }
    println!(
        "machine: {} ({} logical cores)",
        report.cpu, report.logical_cores
    );
    Ok(())
}

pub(crate) fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("model name"))
                .map(|l| l.trim_start_matches([' ', '\t', ':']).to_owned())
        })
        .unwrap_or_else(|| "unknown".into())
}

fn plot(dir: &std::path::Path, latencies: &[Latency]) -> Result<(), CliError> {
    use resecta_plot::{Colour, Figure, Series, Style};
    let colours = [Colour::BLUE, Colour::ORANGE, Colour::GREEN, Colour::RED];
    let series = latencies
        .iter()
        .zip(colours.iter().cycle())
        .map(|(l, &colour)| {
            let n = l.samples.len().max(1) as f64;
            let points = l
                .samples
                .iter()
                .enumerate()
                .map(|(k, &ms)| (ms.max(1e-3), 100.0 * (k + 1) as f64 / n))
                .collect();
            Series::new(
                format!(
                    "{} {}×{} ({} session{})",
                    l.scenario,
                    l.resolution[0],
                    l.resolution[1],
                    l.sessions,
                    if l.sessions == 1 { "" } else { "s" }
                ),
                points,
                Style::Line { colour },
            )
        })
        .collect();
    let figure = Figure {
        title: "Edit → delta at a watching client (gRPC, loopback)".into(),
        x_label: "latency (ms)".into(),
        y_label: "edits (%)".into(),
        log_x: true,
        series,
        width: 900,
        height: 560,
    };
    crate::output::write_figure(&crate::output::files_in(dir)?, "edit_latency_cdf", &figure)?;
    Ok(())
}

pub fn run(args: &ServerArgs) -> Result<(), CliError> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::Failed(format!("runtime: {e}")))?;
    runtime.block_on(run_async(args))
}

async fn run_async(args: &ServerArgs) -> Result<(), CliError> {
    if args.drag.client == crate::bench_python::ClientKind::Python {
        return crate::bench_python::run(args).await;
    }
    let pb = progress(args.json);
    if args.compare_gpu {
        return compare_gpu(args, &pb).await;
    }
    let (server, _, channel) = server_and_channel(args.addr.as_deref(), args.gpu, &pb).await?;
    let token = args.token.as_deref();
    let compute = compute_info(&channel, token).await?;
    let map = tokio::task::spawn_blocking(demo_label_map)
        .await
        .map_err(|e| CliError::Failed(e.to_string()))??;
    let (edits, seconds) = if args.quick {
        (20, 1.0)
    } else {
        (args.edits, args.seconds)
    };

    let pid = server.as_ref().map(|s| s.child.id());
    let scenarios = &args.ready;
    let mut idle_session_bytes = None;
    let mut latencies = Vec::new();
    let (mut ratio, mut ratio_paced) = (f64::NAN, f64::NAN);
    if scenarios.runs(Scenario::Latency) {
        // First, on a fresh process: later the allocator holds memory freed by earlier
        // scenarios and new sessions reuse it, which would understate their cost.
        if let Some(s) = &server {
            pb.set_message("idle sessions");
            let n = if args.quick { 2 } else { args.idle_sessions };
            idle_session_bytes = Some(idle_memory(&channel, token, &map, s.child.id(), n).await?);
        }
        pb.set_message("single session, 40×40");
        let s40 = single(&channel, token, &map, [40, 40], edits, None, pid).await?;
        pb.set_message("single session, 200×200");
        let s200 = single(&channel, token, &map, [200, 200], edits, None, pid).await?;
        pb.set_message(format!("1 session at {}/s", args.rate));
        let one = std::slice::from_ref(&channel);
        let alone = paced(one, token, &map, args.rate, 1, seconds, pid).await?;
        pb.set_message(format!("{} sessions at {}/s", args.sessions, args.rate));
        let multi = paced(one, token, &map, args.rate, args.sessions, seconds, pid).await?;
        ratio = multi.p99_ms / s40.p99_ms;
        ratio_paced = multi.p99_ms / alone.p99_ms;
        latencies = vec![s40, s200, alone, multi];
    }
    let ready_runs = if args.quick { 1 } else { scenarios.ready_runs };
    let mut upload = None;
    if scenarios.runs(Scenario::Upload) {
        pb.set_message("512×512×300 upload");
        let runs = if args.quick { 1 } else { args.uploads };
        upload = Some(uploads(&channel, token, runs).await?);
    }
    let mut ready = None;
    if scenarios.runs(Scenario::Ready) {
        pb.set_message("512×512×300 upload → first resection");
        ready = Some(crate::bench_ready::ready(&channel, token, ready_runs).await?);
    }
    drop(server);
    let mut restart = None;
    if scenarios.runs(Scenario::Restart) {
        pb.set_message("restart → first planning call");
        let older = if args.quick { 1 } else { 3 };
        restart = Some(crate::bench_ready::restart(ready_runs, older, args.gpu).await?);
    }
    pb.finish_and_clear();

    let report = Report {
        quick: args.quick,
        cpu: cpu_name(),
        logical_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        server: if args.addr.is_some() {
            "given (--addr)"
        } else {
            "started by the benchmark (resecta serve, SQLite data dir)"
        },
        compute,
        concurrent_p99_ratio: ratio,
        concurrent_p99_ratio_paced: ratio_paced,
        latencies,
        idle_session_bytes,
        upload,
        ready,
        restart,
    };
    if let Some(dir) = &args.plot_dir
        && !report.latencies.is_empty()
    {
        plot(dir, &report.latencies)?;
    }
    if args.json {
        return print_json(&report);
    }
    if !report.latencies.is_empty() {
        print_latencies(&report.latencies);
        println!(
            "concurrent p99 / single p99 = {:.2} (back to back), {:.2} (same pace)",
            report.concurrent_p99_ratio, report.concurrent_p99_ratio_paced
        );
    }
    if let Some(b) = report.idle_session_bytes {
        println!("server memory per idle session: {:.1} MB", b / 1e6);
    }
    if let Some(u) = &report.upload {
        println!(
            "upload 512×512×300 u8 ({:.1} MB): median {:.3} s",
            u.bytes as f64 / 1e6,
            u.median_s
        );
    }
    crate::bench_ready::print(report.ready.as_ref(), report.restart.as_ref());
    println!(
        "machine: {} ({} logical cores)",
        report.cpu, report.logical_cores
    );
    Ok(())
}

fn print_latencies(latencies: &[Latency]) {
    println!(
        "{:<22} {:>9} {:>8} {:>6} {:>8} {:>8} {:>8} {:>8} {:>10} {:>10}",
        "scenario",
        "grid",
        "sessions",
        "edits",
        "p50 ms",
        "p90 ms",
        "p99 ms",
        "max ms",
        "ack p50",
        "ack p99"
    );
    for l in latencies {
        println!(
            "{:<22} {:>9} {:>8} {:>6} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>10.2} {:>10.2}",
            l.scenario,
            format!("{}×{}", l.resolution[0], l.resolution[1]),
            l.sessions,
            l.edits,
            l.p50_ms,
            l.p90_ms,
            l.p99_ms,
            l.max_ms,
            l.ack_p50_ms,
            l.ack_p99_ms
        );
    }
}
