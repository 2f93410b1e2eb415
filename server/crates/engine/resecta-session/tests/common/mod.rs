//! What the operation layer's test files share: the small phantom as an upload, a fast
//! configuration, a first resection and a session holding the phantom.
#![allow(dead_code, clippy::unwrap_used)]

use std::time::Duration;

use resecta_geom::{LabelMap, RoleMap};
use resecta_phantom::{PhantomSpec, generate};
use resecta_session::api::{EditOp, LabelMapSource, RawLabelMap};
use resecta_session::{Service, ServiceConfig};

pub fn phantom() -> LabelMap {
    generate(&PhantomSpec::small()).unwrap().labels
}

pub fn config() -> ServiceConfig {
    ServiceConfig {
        volumes_delay: Duration::from_millis(5),
        psr_depth: 6,
        ..ServiceConfig::default()
    }
}

pub fn init_op() -> EditOp {
    EditOp::InitFromEndPoint {
        name: "r1".into(),
        target: Default::default(),
        end_point: [-30.0, 0.0, 0.0],
        grid: [4, 4],
    }
}

/// A new session of `service` named `name`, holding the phantom label map.
pub async fn loaded_session(service: &Service, name: &str) -> String {
    let id = service.create_session(name).await.unwrap().id;
    service
        .upload_label_map(
            &id,
            LabelMapSource::Raw(RawLabelMap::of(&phantom())),
            RoleMap::default(),
        )
        .await
        .unwrap();
    id
}
