//! The demo patient: the embedded liver phantom (two tumours, portal and hepatic vessels on an
//! oblique anisotropic grid) as a ready session with models and one resection, so that a newcomer
//! sees the server work without data of their own.

use std::sync::Arc;

use resecta_geom::RoleMap;
use resecta_phantom::{PhantomSpec, generate};
use resecta_plan::Target;
use resecta_session::Service;
use resecta_session::api::{EditOp, LabelMapSource, RawLabelMap, ReconstructEvent};

use crate::error::ServerError;

/// Display name of the demo session (one per store).
pub const DEMO_SESSION_NAME: &str = "demo patient (phantom)";

fn demo(e: impl std::fmt::Display) -> ServerError {
    ServerError::Demo(e.to_string())
}

/// Creates the demo session unless the store has one; returns its id.
pub async fn seed_demo(service: &Arc<Service>) -> Result<String, ServerError> {
    let sessions = service.list_sessions().await.map_err(demo)?;
    if let Some(s) = sessions
        .iter()
        .find(|s| s.display_name == DEMO_SESSION_NAME)
    {
        return Ok(s.id.clone());
    }
    let labels = tokio::task::spawn_blocking(|| generate(&PhantomSpec::demo()))
        .await
        .map_err(demo)?
        .map_err(demo)?
        .labels;
    let raw = RawLabelMap::of(&labels);
    let id = service
        .create_session(DEMO_SESSION_NAME)
        .await
        .map_err(demo)?
        .id;
    service
        .upload_label_map(&id, LabelMapSource::Raw(raw), RoleMap::default())
        .await
        .map_err(demo)?;
    let mut events = service
        .reconstruct(&id, Default::default())
        .await
        .map_err(demo)?;
    while let Some(event) = events.recv().await {
        if let ReconstructEvent::Done { .. } = event.map_err(demo)? {
            break;
        }
    }
    // Around the large tumour (centre (40, −10, 5) mm, radius 25 mm), towards the left lobe.
    service
        .edit(
            &id,
            0,
            EditOp::InitFromEndPoint {
                name: "r1".into(),
                target: Target {
                    labels: Vec::new(),
                    points: vec![[40.0, -10.0, 5.0]],
                },
                end_point: [-20.0, -10.0, 5.0],
                grid: [4, 4],
            },
        )
        .await
        .map_err(demo)?;
    Ok(id)
}
