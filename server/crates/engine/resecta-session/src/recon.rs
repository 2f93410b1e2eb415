//! Reconstruction: the surface models of a session's label map, built off the runtime with
//! progress events, then stored and shown to watchers.

use std::sync::Arc;

use resecta_delta::{SurfaceFrame, encode_mesh};
use resecta_geom::{Real, Role};
use resecta_recon::{
    McsdParams, ModelOptions, ParenchymaMethod, ReconError, SPECK_MM3, patient_models,
};
use tokio::sync::mpsc;

use crate::api::{
    DroppedComponents, ModelInfo, ReconMethod, ReconOptions, ReconstructEvent, Surface, SurfaceKind,
};
use crate::error::{Missing, Result, SessionError};
use crate::log;
use crate::pools::{self, Priority};
use crate::service::Service;
use crate::state::{Model, Session, no_label_map};
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

impl Service {
    /// The model options of `options`, or [`SessionError::Invalid`] naming the field out of
    /// range.
    fn recon_params(&self, options: &ReconOptions) -> Result<ModelOptions> {
        let depth = options.psr_depth.unwrap_or(self.config.psr_depth);
        if !(1..=10).contains(&depth) {
            return Err(SessionError::Invalid(format!(
                "psr_depth {depth} is outside 1..=10"
            )));
        }
        let defaults = McsdParams::default();
        let smoothing = options.smoothing.unwrap_or(defaults.smoothing);
        if !(0.0..=1.0).contains(&smoothing) {
            return Err(SessionError::Invalid(format!(
                "smoothing {smoothing} is outside [0, 1]"
            )));
        }
        let decimation = options.decimation.unwrap_or(defaults.decimation);
        if !(0.0..1.0).contains(&decimation) {
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

    /// Builds the surface models (parenchyma by screened Poisson or, on request, MCSD; one MCSD
    /// model per vessel label and per tumour component, specks counted in `Done`) off the
    /// runtime with `options`, checked before anything starts.
    /// Events arrive on the returned channel; dropping it cancels the work.
    pub async fn reconstruct(
        self: &Arc<Self>,
        id: &str,
        options: ReconOptions,
    ) -> Result<mpsc::Receiver<Result<ReconstructEvent>>> {
        let model_options = self.recon_params(&options)?;
        let (s, st) = self.open(id).await?;
        let loaded = st.loaded.as_ref().ok_or_else(no_label_map)?;
        let labels = Arc::clone(&loaded.labels);
        let roles = loaded.summary.roles.clone();
        let generation = loaded.generation;
        drop(st);
        let (tx, rx) = mpsc::channel(64);
        let service = Arc::clone(self);
        tokio::spawn(async move {
            let started = std::time::Instant::now();
            let progress_tx = tx.clone();
            let built = pools::run(Priority::Background, move || {
                let mut done = 0usize;
                let mut progress = |name: &str| {
                    done += 1;
                    // The parenchyma (first, Poisson or the largest MCSD) dominates; the rest
                    // share what is left.
                    let fraction = 1.0 - 0.4 / done as Real;
                    let event = ReconstructEvent::Progress {
                        stage: format!("built {name}"),
                        fraction,
                    };
                    progress_tx.blocking_send(Ok(event)).is_ok()
                };
                patient_models(&labels, &roles, &model_options, &mut progress).map_err(
                    |e| match e {
                        ReconError::Cancelled => SessionError::Cancelled,
                        e @ (ReconError::NoLabels
                        | ReconError::LabelsAbsent { .. }
                        | ReconError::EmptyMask
                        | ReconError::InvalidParameter { .. }
                        | ReconError::Poisson(_)
                        | ReconError::Filter(_)
                        | ReconError::Isosurface(_)
                        | ReconError::Metrics(_)
                        | ReconError::Geometry(_)) => SessionError::Precondition(
                            Missing::Other,
                            format!("reconstruction: {e}"),
                        ),
                    },
                )
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
        blocking(move || log::store_models(&*store, &key, &blob)).await?;
        let infos = models.iter().map(|m| m.info.clone()).collect();
        s.hub
            .publish_models(models.iter().map(|m| m.surface.clone()).collect())?;
        st.models = Some(Arc::new(models));
        Ok(infos)
    }

    // ---- plan edits -----------------------------------------------------------------------
}
