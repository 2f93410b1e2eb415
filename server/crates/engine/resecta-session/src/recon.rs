//! Reconstruction: the surface models of a session's label map, built off the runtime with
//! progress events, then stored and shown to watchers; and the closed surface of a point cloud,
//! which needs no session.

use std::sync::Arc;

use resecta_delta::{EncodeOptions, SurfaceFrame, encode_mesh};
use resecta_geom::{Real, Role, Vec3};
use resecta_recon::{
    CloudOptions, McsdParams, ModelOptions, ParenchymaMethod, PoissonError, PoissonSolver,
    ReconError, SPECK_MM3, patient_models, patient_models_with, reconstruct_cloud,
};
use tokio::sync::mpsc;

use crate::api::{
    CloudSurface, DECIMATION, DEFAULT_CLOUD_DEPTH, DEFAULT_CLOUD_NEIGHBOURS, DroppedComponents,
    MAX_CLOUD_NEIGHBOURS, MIN_CLOUD_NEIGHBOURS, ModelInfo, PSR_DEPTHS, PointCloud, ReconMethod,
    ReconOptions, ReconstructEvent, SMOOTHING, Surface, SurfaceKind,
};
use crate::budget::{Charge, Use, cloud_bytes, reconstruction_bytes};
use crate::error::{Missing, Quota, Result, SessionError};
use crate::log;
use crate::pools::{self, Priority};
use crate::service::Service;
use crate::state::{Model, Session, models_bytes, no_label_map};
use crate::support::{blocking, internal};

fn surface_kind(role: Role) -> SurfaceKind {
    match role {
        Role::Parenchyma => SurfaceKind::Parenchyma,
        Role::Tumor => SurfaceKind::Tumor,
        Role::Portal => SurfaceKind::Portal,
        Role::Hepatic => SurfaceKind::Hepatic,
        Role::Vessel => SurfaceKind::Vessel,
    }
}

/// The model options of `options` (`default_depth`: the PSR depth when it names none), or
/// [`SessionError::Invalid`] naming the field out of range.
fn model_options(options: &ReconOptions, default_depth: u32) -> Result<ModelOptions> {
    let depth = options.psr_depth.unwrap_or(default_depth);
    if !PSR_DEPTHS.contains(&depth) {
        return Err(SessionError::Invalid(format!(
            "psr_depth {depth} is outside {}..={}",
            PSR_DEPTHS.start(),
            PSR_DEPTHS.end()
        )));
    }
    let defaults = McsdParams::default();
    let smoothing = options.smoothing.unwrap_or(defaults.smoothing);
    if !SMOOTHING.contains(&smoothing) {
        return Err(SessionError::Invalid(format!(
            "smoothing {smoothing} is outside [0, 1]"
        )));
    }
    let decimation = options.decimation.unwrap_or(defaults.decimation);
    if !DECIMATION.contains(&decimation) {
        return Err(SessionError::Invalid(format!(
            "decimation {decimation} is outside [0, 1)"
        )));
    }
    let parenchyma = match options.method {
        ReconMethod::Psr => ParenchymaMethod::Psr { depth },
        ReconMethod::Mcsd => ParenchymaMethod::Mcsd,
    };
    let model_options = ModelOptions {
        parenchyma,
        mcsd: McsdParams {
            smoothing,
            decimation,
        },
        split_components: options.split_components,
        min_component_mm3: options.min_component_mm3.unwrap_or(SPECK_MM3),
    };
    model_options
        .check()
        .map_err(|e| SessionError::Invalid(e.to_string()))?;
    Ok(model_options)
}

/// A failed reconstruction as the operation's error: cancelled, or a precondition the label
/// map does not meet.
fn recon_error(e: ReconError) -> SessionError {
    match e {
        ReconError::Cancelled => SessionError::Cancelled,
        e @ (ReconError::NormalCount { .. }
        | ReconError::BadNormal { .. }
        | ReconError::PointCloud(_)) => SessionError::Invalid(format!("point cloud: {e}")),
        e @ (ReconError::NoLabels
        | ReconError::LabelsAbsent { .. }
        | ReconError::EmptyMask
        | ReconError::InvalidParameter { .. }
        | ReconError::Poisson(_)
        | ReconError::Filter(_)
        | ReconError::Isosurface(_)
        | ReconError::Metrics(_)
        | ReconError::Geometry(_)) => {
            SessionError::Precondition(Missing::Other, format!("reconstruction: {e}"))
        }
    }
}

/// The options of a point cloud's reconstruction, or [`SessionError::Invalid`] naming the
/// quantity out of range and the limit (`max_points`, `max_depth`: the server's
/// `max_cloud_points` and `max_cloud_depth`).
fn cloud_options(cloud: &PointCloud, max_points: usize, max_depth: u32) -> Result<CloudOptions> {
    let n = cloud.positions.len();
    if n > max_points {
        return Err(SessionError::Invalid(format!(
            "the cloud has {n} points, more than max_cloud_points ({max_points})"
        )));
    }
    if let Some(normals) = &cloud.normals
        && normals.len() != n
    {
        return Err(SessionError::Invalid(format!(
            "{} normals given for {n} points",
            normals.len()
        )));
    }
    let depth = cloud.depth.unwrap_or(DEFAULT_CLOUD_DEPTH);
    if !(1..=max_depth).contains(&depth) {
        return Err(SessionError::Invalid(format!(
            "depth {depth} is outside 1..={max_depth} (max_cloud_depth)"
        )));
    }
    let neighbours = cloud.neighbours.unwrap_or(DEFAULT_CLOUD_NEIGHBOURS);
    if !(MIN_CLOUD_NEIGHBOURS..=MAX_CLOUD_NEIGHBOURS).contains(&neighbours) {
        return Err(SessionError::Invalid(format!(
            "neighbours {neighbours} is outside {MIN_CLOUD_NEIGHBOURS}..={MAX_CLOUD_NEIGHBOURS}"
        )));
    }
    Ok(CloudOptions { depth, neighbours })
}

/// The server's mesh encoding (`server`) less what the client does not decode.
fn cloud_encoding(
    server: &EncodeOptions,
    allow_zstd: bool,
    allow_quantized: bool,
) -> EncodeOptions {
    EncodeOptions {
        quantise: server.quantise.filter(|_| allow_quantized),
        zstd_level: server.zstd_level.filter(|_| allow_zstd),
    }
}

/// A failed point-cloud reconstruction as the operation's error: the cloud cannot give a
/// surface (invalid), or its grid does not fit the solver's memory limit.
fn cloud_error(e: ReconError) -> SessionError {
    // Point-cloud errors name themselves ("point cloud: …"); the others get the prefix.
    let invalid = |e: &ReconError| {
        SessionError::Invalid(if matches!(e, ReconError::PointCloud(_)) {
            e.to_string()
        } else {
            format!("point cloud: {e}")
        })
    };
    match e {
        ReconError::Cancelled => SessionError::Cancelled,
        ReconError::Poisson(PoissonError::MemoryBudget { .. }) => {
            SessionError::Quota(Quota::Memory, format!("point cloud: {e}"))
        }
        ReconError::Poisson(PoissonError::Backend { .. }) => SessionError::Internal(e.to_string()),
        ReconError::Poisson(
            PoissonError::EmptyMask
            | PoissonError::TooFewPoints { .. }
            | PoissonError::DepthOutOfRange { .. }
            | PoissonError::LengthMismatch { .. }
            | PoissonError::BadSample { .. }
            | PoissonError::DegenerateBounds { .. }
            | PoissonError::BadParameter { .. }
            | PoissonError::SingularGrid,
        )
        | ReconError::NoLabels
        | ReconError::LabelsAbsent { .. }
        | ReconError::EmptyMask
        | ReconError::InvalidParameter { .. }
        | ReconError::NormalCount { .. }
        | ReconError::BadNormal { .. }
        | ReconError::PointCloud(_)
        | ReconError::Filter(_)
        | ReconError::Isosurface(_)
        | ReconError::Metrics(_)
        | ReconError::Geometry(_) => invalid(&e),
    }
}

/// The closed surface of `cloud` solved by `solver` (on the CPU again if the device fails),
/// encoded with `encode`.
fn close_cloud(
    cloud: PointCloud,
    options: &CloudOptions,
    solver: &PoissonSolver,
    encode: &EncodeOptions,
) -> Result<CloudSurface> {
    let positions: Vec<Vec3> = cloud.positions.iter().map(|&p| p.into()).collect();
    drop(cloud.positions);
    let normals: Option<Vec<Vec3>> = cloud
        .normals
        .map(|n| n.into_iter().map(Vec3::from).collect());
    let built = match reconstruct_cloud(&positions, normals.as_deref(), options, solver) {
        Err(ReconError::Poisson(e @ PoissonError::Backend { .. })) => {
            tracing::warn!(error = %e, "Poisson solver failed: closing the point cloud on the CPU");
            reconstruct_cloud(
                &positions,
                normals.as_deref(),
                options,
                &PoissonSolver::cpu(),
            )
        }
        other => other,
    }
    .map_err(cloud_error)?;
    let (topology, frame) = SurfaceFrame::from_trimesh(&built.mesh);
    let mesh = encode_mesh(&topology, &frame, encode).map_err(internal)?;
    Ok(CloudSurface {
        mesh,
        vertices: built.mesh.vertices().len(),
        triangles: built.mesh.triangles().len(),
        volume_ml: built.mesh.signed_volume() / 1000.0,
        neighbours: options.neighbours,
        report: built.report,
    })
}

/// The fraction reported once `done` models are built: the parenchyma (first, Poisson or the
/// largest MCSD) dominates; the rest share what is left.
fn progress_fraction(done: usize) -> Real {
    1.0 - 0.4 / done as Real
}

impl Service {
    /// Builds the surface models (parenchyma by screened Poisson or, on request, MCSD; one MCSD
    /// model per vessel label and per tumour component, specks counted in `Done`) off the
    /// runtime with `options`, checked before anything starts.
    /// Events arrive on the returned channel; dropping it cancels the work.
    pub async fn reconstruct(
        self: &Arc<Self>,
        id: &str,
        options: ReconOptions,
    ) -> Result<mpsc::Receiver<Result<ReconstructEvent>>> {
        let model_options = model_options(&options, self.config.psr_depth)?;
        let (s, st) = self.open(id).await?;
        let loaded = st.loaded.as_ref().ok_or_else(no_label_map)?;
        let labels = Arc::clone(&loaded.labels);
        let roles = loaded.summary.roles.clone();
        let generation = loaded.generation;
        drop(st);
        let depth = match model_options.parenchyma {
            ParenchymaMethod::Psr { depth } => depth,
            ParenchymaMethod::Mcsd => 0,
        };
        let voxels = labels.data().len() as u64;
        let memory = self
            .budget
            .reserve(Use::Reconstruction, reconstruction_bytes(voxels, depth))?;
        let (tx, rx) = mpsc::channel(64);
        let service = Arc::clone(self);
        let solver = self.config.poisson_solver.clone();
        tokio::spawn(async move {
            let _memory = memory;
            let started = std::time::Instant::now();
            let progress_tx = tx.clone();
            let built = pools::run(Priority::Background, move || {
                let mut done = 0usize;
                let mut progress = |name: &str| {
                    done += 1;
                    let event = ReconstructEvent::Progress {
                        stage: format!("built {name}"),
                        fraction: progress_fraction(done),
                    };
                    progress_tx.blocking_send(Ok(event)).is_ok()
                };
                let built = patient_models_with(&labels, &roles, &model_options, &solver, &mut progress);
                match built {
                    Err(ReconError::Poisson(e @ PoissonError::Backend { .. })) => {
                        tracing::warn!(error = %e, "Poisson solver failed: reconstructing on the CPU");
                        patient_models(&labels, &roles, &model_options, &mut progress)
                    }
                    other => other,
                }
                .map_err(recon_error)
            })
            .await
            .and_then(|built| built);
            let result = match built {
                Ok(built) => {
                    let dropped = built
                        .dropped
                        .iter()
                        .map(|d| DroppedComponents {
                            kind: surface_kind(d.role),
                            count: d.components,
                            volume_ml: d.volume_mm3 / 1000.0,
                        })
                        .collect();
                    service
                        .install_models(&s, generation, built.models)
                        .await
                        .map(|infos| (infos, dropped))
                }
                Err(e) => Err(e),
            };
            let end = match result {
                Ok((infos, dropped)) => {
                    for model in &infos {
                        let _ = tx
                            .send(Ok(ReconstructEvent::Model {
                                model: model.clone(),
                            }))
                            .await;
                    }
                    Ok(ReconstructEvent::Done {
                        models: infos.len(),
                        time_ms: started.elapsed().as_secs_f64() * 1e3,
                        dropped,
                        min_component_mm3: model_options.min_component_mm3,
                    })
                }
                Err(e) => Err(e),
            };
            let _ = tx.send(end).await;
        });
        Ok(rx)
    }

    /// The closed surface of a point cloud (normals estimated where missing, then screened
    /// Poisson and marching cubes; thesis ch. 9) with how it was built. Needs no session and
    /// keeps nothing. The limits (`max_cloud_points`, `max_cloud_depth`, the neighbourhood
    /// range) are checked first, then the memory its grid needs is reserved from the budget
    /// for as long as the work runs; the work runs on the background pool, as
    /// reconstructions do, with the service's Poisson solver. The mesh is encoded as the
    /// models are (`ServiceConfig::encode`), less the encodings the client does not decode.
    pub async fn reconstruct_points(&self, cloud: PointCloud) -> Result<CloudSurface> {
        let options = cloud_options(
            &cloud,
            self.config.max_cloud_points,
            self.config.max_cloud_depth,
        )?;
        let memory = self.budget.reserve(
            Use::PointCloud,
            cloud_bytes(cloud.positions.len(), options.depth, options.neighbours),
        )?;
        let encode = cloud_encoding(&self.config.encode, cloud.allow_zstd, cloud.allow_quantized);
        let solver = self.config.poisson_solver.clone();
        let started = std::time::Instant::now();
        let points = cloud.positions.len();
        // The reservation goes with the job: it is held until the work ends, even when the
        // caller has gone away meanwhile.
        let surface = pools::run(Priority::Background, move || {
            let _memory = memory;
            close_cloud(cloud, &options, &solver, &encode)
        })
        .await??;
        tracing::info!(
            points,
            depth = surface.report.depth,
            vertices = surface.vertices,
            ms = started.elapsed().as_secs_f64() * 1e3,
            "point cloud closed"
        );
        Ok(surface)
    }

    async fn install_models(
        &self,
        s: &Arc<Session>,
        generation: u64,
        built: Vec<resecta_recon::PatientModel>,
    ) -> Result<Vec<ModelInfo>> {
        let encode = self.config.encode;
        let models: Vec<Model> = built
            .into_iter()
            .map(|m| -> Result<Model> {
                let info = ModelInfo {
                    name: m.name(),
                    kind: surface_kind(m.role),
                    label: m.label.unwrap_or(0),
                    method: m.method.to_owned(),
                    triangles: m.mesh.triangles().len(),
                    vertices: m.mesh.vertices().len(),
                    volume_ml: m.mesh.signed_volume() / 1000.0,
                };
                let (topology, frame) = SurfaceFrame::from_trimesh(&m.mesh);
                let mesh = encode_mesh(&topology, &frame, &encode).map_err(internal)?;
                let surface = Surface::labelled(info.name.clone(), info.kind, info.label, mesh);
                Ok(Model {
                    info,
                    mesh: m.mesh,
                    surface,
                })
            })
            .collect::<Result<_>>()?;
        let mut st = s.state.lock().await;
        if st.generation != generation || st.loaded.is_none() {
            return Err(SessionError::Precondition(
                Missing::Other,
                "the label map changed during the reconstruction".into(),
            ));
        }
        let blob = log::encode_models(&models)?;
        let store = Arc::clone(&self.store);
        let key = s.id.clone();
        if let Err(e) = blocking(move || log::store_models(&*store, &key, &blob)).await {
            return Err(self.store_failed(&s.id, e).await);
        }
        self.budget
            .set(&s.id, Charge::Models, models_bytes(&models))?;
        let infos = models.iter().map(|m| m.info.clone()).collect();
        s.hub
            .publish_models(models.iter().map(|m| m.surface.clone()).collect())?;
        st.models = Some(Arc::new(models));
        Ok(infos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn invalid(options: ReconOptions) -> String {
        match model_options(&options, 7) {
            Err(SessionError::Invalid(m)) => m,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn defaults_are_poisson_at_the_configured_depth_and_mcsd_defaults() {
        let o = model_options(&ReconOptions::default(), 6).unwrap();
        assert_eq!(o.parenchyma, ParenchymaMethod::Psr { depth: 6 });
        assert_eq!(o.mcsd, McsdParams::default());
        assert_eq!(o.min_component_mm3, SPECK_MM3);
        assert!(!o.split_components);
    }

    #[test]
    fn named_options_are_taken() {
        let o = model_options(
            &ReconOptions {
                method: ReconMethod::Mcsd,
                psr_depth: Some(9),
                smoothing: Some(0.0),
                decimation: Some(0.5),
                split_components: true,
                min_component_mm3: Some(0.0),
            },
            7,
        )
        .unwrap();
        assert_eq!(o.parenchyma, ParenchymaMethod::Mcsd);
        assert_eq!((o.mcsd.smoothing, o.mcsd.decimation), (0.0, 0.5));
        assert!(o.split_components);
        assert_eq!(o.min_component_mm3, 0.0);
    }

    #[test]
    fn out_of_range_options_are_refused_by_name() {
        let base = ReconOptions::default();
        for depth in [0, 11] {
            let m = invalid(ReconOptions {
                psr_depth: Some(depth),
                ..base
            });
            assert!(m.contains("psr_depth"), "{m}");
        }
        // The configured depth is checked too, whatever the method.
        assert!(matches!(
            model_options(
                &ReconOptions {
                    method: ReconMethod::Mcsd,
                    ..base
                },
                0
            ),
            Err(SessionError::Invalid(_))
        ));
        for smoothing in [-0.1, 1.1, Real::NAN] {
            let m = invalid(ReconOptions {
                smoothing: Some(smoothing),
                ..base
            });
            assert!(m.contains("smoothing"), "{m}");
        }
        for decimation in [-0.1, 1.0] {
            let m = invalid(ReconOptions {
                decimation: Some(decimation),
                ..base
            });
            assert!(m.contains("decimation"), "{m}");
        }
        // Checked by `ModelOptions::check`.
        invalid(ReconOptions {
            min_component_mm3: Some(-1.0),
            ..base
        });
    }

    #[test]
    fn cancelled_reconstructions_are_cancelled_and_others_preconditions() {
        assert!(matches!(
            recon_error(ReconError::Cancelled),
            SessionError::Cancelled
        ));
        let e = recon_error(ReconError::EmptyMask);
        assert!(matches!(e, SessionError::Precondition(Missing::Other, _)));
        assert!(e.to_string().contains("reconstruction"), "{e}");
    }

    fn cloud(n: usize) -> PointCloud {
        PointCloud {
            positions: vec![[0.0; 3]; n],
            ..PointCloud::default()
        }
    }

    fn cloud_invalid(c: &PointCloud) -> String {
        match cloud_options(c, 100, 8) {
            Err(SessionError::Invalid(m)) => m,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn cloud_options_default_and_refuse_by_name_and_limit() {
        let o = cloud_options(&cloud(100), 100, 8).unwrap();
        assert_eq!(
            (o.depth, o.neighbours),
            (DEFAULT_CLOUD_DEPTH, DEFAULT_CLOUD_NEIGHBOURS)
        );
        let o = cloud_options(
            &PointCloud {
                depth: Some(8),
                neighbours: Some(64),
                ..cloud(4)
            },
            100,
            8,
        )
        .unwrap();
        assert_eq!((o.depth, o.neighbours), (8, 64));
        let m = cloud_invalid(&cloud(101));
        assert!(
            m.contains("101 points") && m.contains("max_cloud_points (100)"),
            "{m}"
        );
        for depth in [0, 9, u32::MAX] {
            let m = cloud_invalid(&PointCloud {
                depth: Some(depth),
                ..cloud(10)
            });
            assert!(m.contains("max_cloud_depth") && m.contains("1..=8"), "{m}");
        }
        for k in [0, 2, 65] {
            let m = cloud_invalid(&PointCloud {
                neighbours: Some(k),
                ..cloud(10)
            });
            assert!(m.contains("neighbours") && m.contains("3..=64"), "{m}");
        }
        let m = cloud_invalid(&PointCloud {
            normals: Some(vec![[0.0, 0.0, 1.0]; 9]),
            ..cloud(10)
        });
        assert!(m.contains("9 normals given for 10 points"), "{m}");
    }

    #[test]
    fn cloud_encoding_drops_what_the_client_does_not_decode() {
        let server = EncodeOptions::quantised().with_zstd(3);
        assert_eq!(cloud_encoding(&server, true, true), server);
        assert_eq!(
            cloud_encoding(&server, false, false),
            EncodeOptions::exact()
        );
        assert_eq!(
            cloud_encoding(&server, true, false),
            EncodeOptions::exact().with_zstd(3)
        );
        let exact = EncodeOptions::exact();
        assert_eq!(cloud_encoding(&exact, true, true), exact);
    }

    #[test]
    fn cloud_failures_are_invalid_but_memory_and_devices() {
        let e = cloud_error(ReconError::BadNormal { index: 3 });
        assert!(matches!(e, SessionError::Invalid(_)), "{e:?}");
        assert!(e.to_string().starts_with("point cloud: "), "{e}");

        let e = cloud_error(ReconError::Poisson(PoissonError::MemoryBudget {
            depth: 10,
            needed: 2,
            limit: 1,
        }));
        assert!(matches!(e, SessionError::Quota(Quota::Memory, _)), "{e:?}");
        let e = cloud_error(ReconError::Poisson(PoissonError::Backend {
            backend: "wgpu",
            reason: "lost".into(),
        }));
        assert!(matches!(e, SessionError::Internal(_)), "{e:?}");
    }

    #[test]
    fn progress_grows_towards_one() {
        assert_eq!(progress_fraction(1), 0.6);
        let fractions: Vec<_> = (1..50).map(progress_fraction).collect();
        assert!(fractions.windows(2).all(|w| w[0] < w[1] && w[1] < 1.0));
    }
}
