//! The operation layer's errors never carry client text (issue #19): names (display, resection,
//! model), file names and header values of uploads, and of ids at most a short prefix. Each
//! request below carries [`MARKER`] where a client would put a patient's name and fails.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;

use resecta_geom::RoleMap;
use resecta_io::mesh::MeshFormat;
use resecta_phantom::{PhantomSpec, generate};
use resecta_plan::{PlanEvent, SlicePositions};
use resecta_session::api::{EditOp, FileFormat, LabelMapSource, RawLabelMap};
use resecta_session::{ErrorKind, Service, ServiceConfig, SessionError};
use resecta_store::{MemoryStore, StoreOptions};

const MARKER: &str = "PATIENTMARKER";

/// The error of `r`, checked: no marker in its message or `Debug`, a bounded message, and the
/// expected kind. Returns the message.
fn refused<T: std::fmt::Debug>(
    case: &str,
    r: resecta_session::Result<T>,
    kind: ErrorKind,
) -> String {
    let e: SessionError = r.expect_err(case);
    let (shown, debug) = (e.to_string(), format!("{e:?}"));
    assert!(
        !shown.contains(MARKER),
        "{case}: client text in the message: {shown}"
    );
    assert!(
        !debug.contains(MARKER),
        "{case}: client text in the Debug: {debug}"
    );
    assert!(
        shown.len() < 400,
        "{case}: an unbounded message ({} bytes)",
        shown.len()
    );
    assert_eq!(e.kind(), kind, "{case}: {shown}");
    shown
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_error_of_the_service_carries_client_text() {
    let store = Arc::new(MemoryStore::new(StoreOptions::default()));
    let service = Arc::new(Service::new(store, ServiceConfig::default()));
    let info = service
        .create_session(&format!("{MARKER} liver"))
        .await
        .unwrap();
    // The display name is the client's own data, returned as such (not an error).
    assert!(info.display_name.contains(MARKER));
    let id = info.id;

    // Ids: a 10 KB id, an id typed as a name.
    let long = format!("{MARKER}{}", "x".repeat(10_000));
    let m = refused(
        "long id",
        service.get_session(&long).await,
        ErrorKind::NotFound,
    );
    assert!(m.contains("\"PATIENTM…\""), "{m}");
    refused(
        "typed id",
        service.get_session(&format!("Jane {MARKER}")).await,
        ErrorKind::NotFound,
    );
    refused(
        "delete",
        service.delete_session(&long).await,
        ErrorKind::NotFound,
    );
    refused(
        "edit on an unknown session",
        service.edit(&long, 0, EditOp::Undo).await,
        ErrorKind::NotFound,
    );
    refused(
        "display name",
        service.create_session(&format!("{MARKER}\u{7}")).await,
        ErrorKind::InvalidArgument,
    );

    // Uploads: a detached NRRD header names its data file after the patient.
    let nhdr = format!(
        "NRRD0004\n# {MARKER}\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\
         content: {MARKER}\ndata file: {MARKER}.raw\n"
    );
    for format in [FileFormat::Nrrd, FileFormat::Auto] {
        let m = refused(
            "nhdr",
            service
                .upload_label_map(
                    &id,
                    LabelMapSource::File {
                        format,
                        bytes: nhdr.clone().into_bytes(),
                    },
                    RoleMap::default(),
                )
                .await,
            ErrorKind::InvalidArgument,
        );
        assert!(m.contains("data file"), "{m}");
    }
    let mha = format!(
        "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = {MARKER}\nElementDataFile = LOCAL\n"
    );
    let m = refused(
        "mha",
        service
            .upload_label_map(
                &id,
                LabelMapSource::File {
                    format: FileFormat::MetaImage,
                    bytes: mha.into_bytes(),
                },
                RoleMap::default(),
            )
            .await,
        ErrorKind::InvalidArgument,
    );
    assert!(m.contains("ElementType"), "{m}");

    // A label map, then edits, models and slices naming resections that do not exist.
    let labels = generate(&PhantomSpec::small()).unwrap().labels;
    let raw = RawLabelMap::of(&labels);
    service
        .upload_label_map(&id, LabelMapSource::Raw(raw), RoleMap::default())
        .await
        .unwrap();
    let drag = |point| EditOp::Event {
        event: PlanEvent::SetControlPoint {
            name: MARKER.into(),
            i: 1,
            j: 2,
            point,
        },
    };
    refused(
        "unknown resection",
        service.edit(&id, 1, drag([0.0; 3])).await,
        ErrorKind::NotFound,
    );
    let init = EditOp::InitFromEndPoint {
        name: MARKER.into(),
        target: Default::default(),
        end_point: [-30.0, 0.0, 0.0],
        grid: [4, 4],
    };
    let out = service.edit(&id, 1, init.clone()).await.unwrap();
    // The resection's name comes back in a successful answer: the client's own data.
    assert_eq!(out.resections[0].resection.name, MARKER);
    refused(
        "duplicate name",
        service.edit(&id, 2, init).await,
        ErrorKind::InvalidArgument,
    );
    let m = refused(
        "non-finite point",
        service.edit(&id, 2, drag([f64::NAN, 0.0, 0.0])).await,
        ErrorKind::InvalidArgument,
    );
    assert!(m.contains("finite"), "{m}");
    refused(
        "model",
        service
            .export_model(&id, &format!("{MARKER}_vein"), MeshFormat::Stl)
            .await,
        ErrorKind::NotFound,
    );
    refused(
        "slices",
        service
            .slices(
                &id,
                &format!("{MARKER}_2"),
                SlicePositions {
                    axial: Some(0.0),
                    coronal: None,
                    sagittal: None,
                },
            )
            .await,
        ErrorKind::NotFound,
    );

    // Plans: a format, names and values of the client's JSON.
    for json in [
        format!("{{\"format\": \"{MARKER}\", \"roles\": {{}}, \"resections\": []}}"),
        format!("{{\"format\": \"resecta-plan/1\", \"roles\": \"{MARKER}\"}}"),
        format!("{{\"format\": \"resecta-plan/1\", \"{MARKER}\": 1}}"),
        format!("{{\"{MARKER}"),
    ] {
        refused(
            "plan",
            service.import_plan(&id, &json, 2).await,
            ErrorKind::InvalidArgument,
        );
    }
}
