//! `resecta bench server --client python`: a drag at a fixed rate (`--rate`, 30 edits/s) on one
//! session, measured at the benchmark's own Rust client and at a watching Python client, the
//! path the Slicer module takes (`resecta_client`: a worker thread sends the edits, a watch
//! thread decodes every delta and writes it into the client's arrays). The Python side is
//! `clients/python/scripts/bench_watch.py`, run as a child process against the same session;
//! it prints one JSON object that is folded into this report.
//!
//! The patient is the demo phantom, the large-tumour phantom (`--patient large-tumour`: a bumpy
//! tumour of tens of thousands of margin-surface triangles on a 512×512×130 CT grid), or a label
//! map file (`--labelmap PATH --roles JSON`, optionally `--liver-mask PATH` whose voxels become
//! parenchyma where the label map has none). Rust and Python rounds alternate (`--rounds`), so
//! both clients see the same machine state.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use resecta_api::v1::planning_service_client::PlanningServiceClient;
use resecta_api::v1::{self as pb, edit_request, resection_surface, watch_response};
use resecta_geom::{Real, Role, RoleMap, Vec3, Volume, VoxelLimit};
use resecta_phantom::{PhantomSpec, generate};
use serde::Serialize;
use tokio::sync::mpsc;
use tonic::transport::Channel;

use crate::bench_server::{self as bs, LabelMap, Latency, Load, ServerArgs, Timed, failed, v3};
use crate::error::CliError;
use crate::output::{print_json, progress};

/// Who watches in `resecta bench server`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ClientKind {
    /// The scenarios of issue #6, watched by the benchmark's own gRPC client.
    #[default]
    Rust,
    /// A drag at `--rate` on one session, watched alternately by the benchmark's client and by
    /// the Python client (`resecta_client`, as the Slicer module uses it).
    Python,
}

/// The patient of `--client python` (unless `--labelmap` names a file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Patient {
    /// The demo phantom (300×230×64, 0.8×0.8×2.5 mm; the 25 mm tumour).
    #[default]
    Demo,
    /// `PhantomSpec::large_tumour`: a bumpy tumour (a ball with 14 overlapping bumps) on a
    /// 512×512×130 grid of 0.57×0.57×1.6 mm.
    LargeTumour,
}

/// The options of `resecta bench server` for the Python-client drag.
#[derive(Debug, Clone, clap::Args)]
pub struct DragArgs {
    /// Who watches: `rust` (the issue #6 scenarios) or `python` (a drag at `--rate`, `--edits`
    /// edits per round, watched by the Rust and the Python client in alternate rounds).
    #[arg(long, value_enum, default_value_t)]
    pub client: ClientKind,
    /// The patient of the drag.
    #[arg(long, value_enum, default_value_t)]
    pub patient: Patient,
    /// A label-map file (NIfTI, NRRD, MetaImage) to plan on instead of a phantom; its largest
    /// tumour component is the target. Needs `--roles`.
    #[arg(long, requires = "roles")]
    pub labelmap: Option<PathBuf>,
    /// Role → labels of `--labelmap`, JSON (`{"parenchyma":[3],"tumor":[2],"vessel":[1]}`).
    #[arg(long)]
    pub roles: Option<String>,
    /// A liver mask on the label map's grid: its nonzero voxels that are 0 in the label map get
    /// the first parenchyma label.
    #[arg(long, requires = "labelmap")]
    pub liver_mask: Option<PathBuf>,
    /// Rounds of the drag, alternating the Rust and the Python client.
    #[arg(long, default_value_t = 2)]
    pub rounds: usize,
    /// Control point moved: row i, column j of the 4×4 grid; it swings along the grid's normal
    /// by this many mm, one period per second.
    #[arg(long, default_value_t = 5.0)]
    pub amplitude_mm: f64,
    /// The Python interpreter (with numpy, grpcio and protobuf).
    #[arg(long, env = "RESECTA_PYTHON", default_value = "python3")]
    pub python: PathBuf,
    /// The Python driver script.
    #[arg(long, default_value = "clients/python/scripts/bench_watch.py")]
    pub python_driver: PathBuf,
}

const RESECTION: &str = "resection_1";
const POINT: (u32, u32) = (1, 1);

/// The patient as uploaded, with what the drag targets.
struct Case {
    name: String,
    map: LabelMap,
    /// A point in the target tumour and the end point of the initial resection (RAS mm).
    target: [Real; 3],
    end_point: [Real; 3],
    tumour_voxels: usize,
    /// Triangles of the target tumour's margin surface (its voxels' boundary).
    margin_triangles: usize,
}

#[derive(Debug, Serialize)]
struct PatientReport {
    name: String,
    dims: Vec<u32>,
    spacing: Vec<f64>,
    tumour_voxels: usize,
    margin_triangles: usize,
    resection_vertices: usize,
}

#[derive(Debug, Serialize)]
struct Report {
    quick: bool,
    cpu: String,
    logical_cores: usize,
    patient: PatientReport,
    rate: f64,
    rounds: usize,
    /// One row per round and client, then the rounds of each client pooled (`scenario` ends
    /// in "all rounds").
    latencies: Vec<Latency>,
    /// The Python driver's own JSON of every round (breakdown, versions), samples left out.
    python_runs: Vec<serde_json::Value>,
}

fn bad(e: impl std::fmt::Display) -> CliError {
    CliError::Failed(e.to_string())
}

fn raw_map(labels: &resecta_geom::grid::LabelMap, roles: &RoleMap) -> LabelMap {
    let g = labels.grid();
    let d = g.direction();
    let data: Vec<u8> = labels.data().iter().flat_map(|v| v.to_le_bytes()).collect();
    let role = |r: Role| roles.labels(r).iter().map(|&l| u32::from(l)).collect();
    LabelMap {
        header: pb::RawLabelMapHeader {
            session_id: String::new(),
            dims: g.dims().iter().map(|&n| n as u32).collect(),
            spacing: g.spacing().to_vec(),
            origin: Vec::from(<[f64; 3]>::from(g.origin())),
            direction: (0..9).map(|k| d[(k / 3, k % 3)]).collect(),
            data_type: pb::DataType::Uint16 as i32,
            roles: Some(pb::RoleMap {
                parenchyma: role(Role::Parenchyma),
                tumor: role(Role::Tumor),
                portal: role(Role::Portal),
                hepatic: role(Role::Hepatic),
                vessel: role(Role::Vessel),
            }),
            total_bytes: data.len() as u64,
        },
        data,
    }
}

/// The target tumour (the largest component of the tumour labels), a point in it (the voxel
/// nearest its centroid), its margin-surface triangles, and an end point 60 mm from it towards
/// the liver's centroid (the initial cut halfway).
fn case_from_labels(
    name: String,
    labels: resecta_geom::grid::LabelMap,
    roles: &RoleMap,
) -> Result<Case, CliError> {
    let g = labels.grid().clone();
    let dims = g.dims();
    let at = |v: usize| {
        g.index_to_world(Vec3::new(
            (v % dims[0]) as Real,
            (v / dims[0] % dims[1]) as Real,
            (v / (dims[0] * dims[1])) as Real,
        ))
    };
    let tumour_labels = roles.labels(Role::Tumor);
    let mask = labels.map(|l| tumour_labels.contains(&l));
    let no_tumour = || CliError::BadInput(format!("{name}: no tumour voxels"));
    let parts = resecta_recon::mask::components(&mask).map_err(|_| no_tumour())?;
    let largest = parts.first().ok_or_else(no_tumour)?;
    let pg = largest.grid();
    let part: Vec<Vec3> = (0..pg.len())
        .filter(|&v| largest.data()[v])
        .map(|v| pg.voxel_center(pg.ijk(v)))
        .collect();
    let centroid = part.iter().sum::<Vec3>() / part.len() as Real;
    let pick = part
        .iter()
        .copied()
        .min_by(|a, b| (a - centroid).norm().total_cmp(&(b - centroid).norm()))
        .unwrap_or(centroid);
    let liver_labels: Vec<u16> = [Role::Parenchyma, Role::Portal, Role::Hepatic, Role::Vessel]
        .iter()
        .flat_map(|&r| roles.labels(r).to_vec())
        .collect();
    let (mut sum, mut n) = (Vec3::zeros(), 0usize);
    for (v, l) in labels.data().iter().enumerate() {
        if liver_labels.contains(l) {
            sum += at(v);
            n += 1;
        }
    }
    let liver_centre = if n > 0 { sum / n as Real } else { centroid };
    let toward = (liver_centre - pick)
        .try_normalize(1e-9)
        .unwrap_or_else(Vec3::x);
    // The cropped component keeps the grid's index → RAS map.
    let margin = resecta_plan::anatomy::tumour_model(largest).map_err(bad)?;
    Ok(Case {
        name,
        map: raw_map(&labels, roles),
        target: pick.into(),
        end_point: (pick + toward * 60.0).into(),
        tumour_voxels: part.len(),
        margin_triangles: margin.triangles().len(),
    })
}

fn load_case(d: &DragArgs) -> Result<Case, CliError> {
    if let Some(path) = &d.labelmap {
        let roles: RoleMap = serde_json::from_str(d.roles.as_deref().unwrap_or("{}"))
            .map_err(|e| CliError::BadInput(format!("--roles: {e}")))?;
        let mut labels = resecta_io::read_label_map(path, VoxelLimit::default())
            .map_err(|e| CliError::BadInput(e.to_string()))?;
        if let Some(mask_path) = &d.liver_mask {
            let mask = resecta_io::read_label_map(mask_path, VoxelLimit::default())
                .map_err(|e| CliError::BadInput(e.to_string()))?;
            if mask.grid().dims() != labels.grid().dims() {
                return Err(CliError::BadInput(
                    "--liver-mask: not on the label map's grid".into(),
                ));
            }
            let parenchyma = *roles.labels(Role::Parenchyma).first().ok_or_else(|| {
                CliError::BadInput("--roles: no parenchyma label for --liver-mask".into())
            })?;
            let data: Vec<u16> = labels
                .data()
                .iter()
                .zip(mask.data())
                .map(|(&l, &m)| if l == 0 && m != 0 { parenchyma } else { l })
                .collect();
            labels = Volume::from_vec(labels.grid().clone(), data).map_err(bad)?;
        }
        // Never the file's name in the report: it may carry a patient identifier.
        return case_from_labels("label map (--labelmap)".into(), labels, &roles);
    }
    let spec = match d.patient {
        Patient::Demo => PhantomSpec::demo(),
        Patient::LargeTumour => PhantomSpec::large_tumour(),
    };
    let phantom = generate(&spec).map_err(bad)?;
    let mut case = case_from_labels(
        match d.patient {
            Patient::Demo => "demo phantom".into(),
            Patient::LargeTumour => "large-tumour phantom".into(),
        },
        phantom.labels,
        &spec.roles,
    )?;
    if d.patient == Patient::Demo {
        // The demo patient's resection, as the other scenarios plan it.
        case.target = [40.0, -10.0, 5.0];
        case.end_point = [-20.0, -10.0, 5.0];
    }
    Ok(case)
}

/// A planned session and a Rust watcher reporting each plan version's arrival.
struct Drag {
    client: bs::Client,
    token: Option<String>,
    id: String,
    p0: [f64; 3],
    normal: [f64; 3],
    vertices: usize,
}

async fn plan_session(
    channel: &Channel,
    token: Option<&str>,
    case: &Case,
) -> Result<Drag, CliError> {
    let mut client = PlanningServiceClient::new(channel.clone())
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(64 << 20);
    let id = bs::create_session(&mut client, token, "drag benchmark").await?;
    bs::upload(&mut client, token, &id, &case.map).await?;
    bs::edit(
        &mut client,
        token,
        &id,
        0,
        bs::init_edit(case.target, case.end_point),
    )
    .await?;
    let mut stream = bs::watch(&mut client, token, &id).await?;
    let first = stream.message().await.map_err(failed("watch"))?;
    let (cps, vertices) = match first.and_then(|m| m.event) {
        Some(watch_response::Event::Snapshot(s)) => s
            .resections
            .iter()
            .find(|r| r.name == RESECTION)
            .and_then(|r| {
                let cps = r.resection.as_ref()?.control_points.clone();
                // The RSMS header's vertex count (bytes 8..12, docs/wire/mesh-delta.md).
                let vertices = match &r.mesh {
                    Some(resection_surface::Mesh::FullMesh(m)) => m
                        .get(8..12)
                        .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize),
                    _ => 0,
                };
                Some((cps, vertices))
            }),
        _ => None,
    }
    .ok_or_else(|| CliError::Failed("watch: no snapshot with the resection first".into()))?;
    if cps.len() != 16 {
        return Err(CliError::Failed("the resection's grid is not 4×4".into()));
    }
    let p = |i: usize, j: usize| Vec3::new(cps[4 * i + j].x, cps[4 * i + j].y, cps[4 * i + j].z);
    let mean = |f: &dyn Fn(usize) -> Vec3| (0..4).map(f).sum::<Vec3>() / 4.0;
    let du = mean(&|j| p(3, j)) - mean(&|j| p(0, j));
    let dv = mean(&|i| p(i, 3)) - mean(&|i| p(i, 0));
    let normal = du.cross(&dv).try_normalize(1e-12).unwrap_or_else(Vec3::z);
    Ok(Drag {
        client,
        token: token.map(str::to_owned),
        id,
        p0: p(POINT.0 as usize, POINT.1 as usize).into(),
        normal: normal.into(),
        vertices,
    })
}

impl Drag {
    /// Position `k` of the dragged point: swinging along the normal, one period per `rate`
    /// edits (the Python driver moves it the same way).
    fn point(&self, k: usize, rate: f64, amplitude: f64) -> [f64; 3] {
        let s = amplitude * (2.0 * std::f64::consts::PI * k as f64 / rate.max(1.0)).sin();
        std::array::from_fn(|i| self.p0[i] + self.normal[i] * s)
    }

    /// `count` paced edits (after `warmup`), each timed to its delta at a Rust watcher.
    async fn rust_round(
        &mut self,
        rate: f64,
        amplitude: f64,
        warmup: usize,
        count: usize,
    ) -> Result<Vec<Timed>, CliError> {
        let token = self.token.clone();
        let mut stream = bs::watch(&mut self.client, token.as_deref(), &self.id).await?;
        stream.message().await.map_err(failed("watch"))?; // the snapshot
        let (tx, mut arrivals) = mpsc::unbounded_channel();
        let reader = tokio::spawn(async move {
            while let Ok(Some(m)) = stream.message().await {
                if matches!(m.event, Some(watch_response::Event::Delta(_)))
                    && tx.send((m.plan_version, Instant::now())).is_err()
                {
                    break;
                }
            }
        });
        let period = Duration::from_secs_f64(1.0 / rate.max(0.1));
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut out = Vec::with_capacity(count);
        for k in 0..warmup + count {
            tick.tick().await;
            let point = v3(self.point(k, rate, amplitude));
            let sent = Instant::now();
            let answer = bs::edit(
                &mut self.client,
                token.as_deref(),
                &self.id,
                0,
                edit_request::Edit::SetControlPoint(pb::SetControlPoint {
                    name: RESECTION.into(),
                    i: POINT.0,
                    j: POINT.1,
                    point: Some(point),
                }),
            )
            .await?;
            let ack_ms = sent.elapsed().as_secs_f64() * 1e3;
            let delta_ms = loop {
                let (version, at) = tokio::time::timeout(Duration::from_secs(30), arrivals.recv())
                    .await
                    .map_err(|_| CliError::Failed("no delta within 30 s of an edit".into()))?
                    .ok_or_else(|| CliError::Failed("the watch stream ended".into()))?;
                if version >= answer.plan_version {
                    break at.duration_since(sent).as_secs_f64() * 1e3;
                }
            };
            if k >= warmup {
                out.push(Timed { delta_ms, ack_ms });
            }
        }
        reader.abort();
        Ok(out)
    }
}

/// Runs the Python driver against the session; its JSON and its edits' latencies.
struct PythonRound {
    drag: DragArgs,
    rate: f64,
    token: Option<String>,
    addr: String,
    id: String,
    warmup: usize,
    count: usize,
}

fn python_round(r: &PythonRound) -> Result<(serde_json::Value, Vec<Timed>), CliError> {
    let (d, addr, id, warmup, count) = (&r.drag, &r.addr, &r.id, r.warmup, r.count);
    let mut cmd = Command::new(&d.python);
    cmd.arg(&d.python_driver)
        .args(["--addr", addr.trim_start_matches("http://")])
        .args(["--session", id, "--resection", RESECTION])
        .args(["--i", &POINT.0.to_string(), "--j", &POINT.1.to_string()])
        .args(["--rate", &r.rate.to_string()])
        .args([
            "--edits",
            &count.to_string(),
            "--warmup",
            &warmup.to_string(),
        ])
        .args(["--amplitude", &d.amplitude_mm.to_string()]);
    if let Some(t) = &r.token {
        cmd.env("RESECTA_TOKEN", t);
    }
    let out = cmd.output().map_err(|e| {
        CliError::Failed(format!(
            "running {} {}: {e}",
            d.python.display(),
            d.python_driver.display()
        ))
    })?;
    if !out.status.success() {
        return Err(CliError::Failed(format!(
            "the Python driver failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    let mut v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .map_err(|e| CliError::Failed(format!("the Python driver's JSON: {e}")))?;
    let list = |v: &serde_json::Value, key: &str| -> Vec<f64> {
        v[key]
            .as_array()
            .map(|a| a.iter().filter_map(serde_json::Value::as_f64).collect())
            .unwrap_or_default()
    };
    let (delta, ack) = (list(&v, "samples_ms"), list(&v, "ack_samples_ms"));
    if delta.len() != ack.len() || delta.is_empty() {
        return Err(CliError::Failed(
            "the Python driver's JSON has no samples".into(),
        ));
    }
    if let Some(o) = v.as_object_mut() {
        o.remove("samples_ms");
        o.remove("ack_samples_ms");
    }
    let timed = delta
        .into_iter()
        .zip(ack)
        .map(|(delta_ms, ack_ms)| Timed { delta_ms, ack_ms })
        .collect();
    Ok((v, timed))
}

fn copies(timed: &[Timed]) -> Vec<Timed> {
    timed
        .iter()
        .map(|t| Timed {
            delta_ms: t.delta_ms,
            ack_ms: t.ack_ms,
        })
        .collect()
}

fn driver_path(p: &Path) -> Result<(), CliError> {
    if p.is_file() {
        Ok(())
    } else {
        Err(CliError::BadInput(format!(
            "the Python driver {} is not there: run from the repository root or pass \
             --python-driver",
            p.display()
        )))
    }
}

pub async fn run(args: &ServerArgs) -> Result<(), CliError> {
    driver_path(&args.drag.python_driver)?;
    let pb = progress(args.json);
    pb.set_message("patient");
    let case = {
        let d = (*args.drag).clone();
        tokio::task::spawn_blocking(move || load_case(&d))
            .await
            .map_err(bad)??
    };
    let (server, addr, channel) =
        bs::server_and_channel(args.addr.as_deref(), args.gpu, &pb).await?;
    let pid = server.as_ref().map(bs::ServerProcess::pid);
    let token = args.token.as_deref();
    pb.set_message(format!("planning on the {}", case.name));
    let mut drag = plan_session(&channel, token, &case).await?;
    let (count, warmup, rounds) = if args.quick {
        (20, 5, 1)
    } else {
        (args.edits, 15, args.drag.rounds.max(1))
    };
    let amplitude = args.drag.amplitude_mm;
    let mut latencies = Vec::new();
    let mut python_runs = Vec::new();
    let (mut all_rust, mut all_python) = (Vec::new(), Vec::new());
    for r in 0..rounds {
        pb.set_message(format!("round {} of {rounds}: Rust client", r + 1));
        let load = Load::start(pid);
        let timed = drag.rust_round(args.rate, amplitude, warmup, count).await?;
        all_rust.extend(copies(&timed));
        let mut l = bs::latency(&format!("rust client, round {}", r + 1), [40, 40], 1, timed);
        load.finish(&mut l);
        latencies.push(l);

        pb.set_message(format!("round {} of {rounds}: Python client", r + 1));
        let load = Load::start(pid);
        let (json, timed) = {
            let round = PythonRound {
                drag: (*args.drag).clone(),
                rate: args.rate,
                token: args.token.clone(),
                addr: addr.clone(),
                id: drag.id.clone(),
                warmup,
                count,
            };
            tokio::task::spawn_blocking(move || python_round(&round))
                .await
                .map_err(bad)??
        };
        all_python.extend(copies(&timed));
        let mut l = bs::latency(
            &format!("python client, round {}", r + 1),
            [40, 40],
            1,
            timed,
        );
        load.finish(&mut l);
        l.client_cores = json["client_cores"].as_f64();
        latencies.push(l);
        python_runs.push(json);
    }
    if rounds > 1 {
        latencies.push(bs::latency(
            "rust client, all rounds",
            [40, 40],
            1,
            all_rust,
        ));
        latencies.push(bs::latency(
            "python client, all rounds",
            [40, 40],
            1,
            all_python,
        ));
    }
    pb.finish_and_clear();
    drop(server);
    let h = &case.map.header;
    let report = Report {
        quick: args.quick,
        cpu: bs::cpu_name(),
        logical_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        patient: PatientReport {
            name: case.name.clone(),
            dims: h.dims.clone(),
            spacing: h.spacing.clone(),
            tumour_voxels: case.tumour_voxels,
            margin_triangles: case.margin_triangles,
            resection_vertices: drag.vertices,
        },
        rate: args.rate,
        rounds,
        latencies,
        python_runs,
    };
    if args.json {
        return print_json(&report);
    }
    println!(
        "{} ({} tumour voxels, {} margin-surface triangles), {} edits/s, {} vertices",
        report.patient.name,
        report.patient.tumour_voxels,
        report.patient.margin_triangles,
        report.rate,
        report.patient.resection_vertices
    );
    println!(
        "{:<28} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8} {:>12}",
        "client", "edits", "p50 ms", "p90 ms", "p99 ms", "max ms", "ack p50", "client cores"
    );
    for l in &report.latencies {
        println!(
            "{:<28} {:>6} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>12.3}",
            l.scenario,
            l.edits,
            l.p50_ms,
            l.p90_ms,
            l.p99_ms,
            l.max_ms,
            l.ack_p50_ms,
            l.client_cores.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
