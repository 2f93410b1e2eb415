//! The operation layer's limits (issue #19): the memory budget admits plans, watchers,
//! reconstructions, point clouds and uploads before their work starts and takes them back on
//! every path; a stored session that cannot be restored is listed as damaged; idle expiry
//! spares watched sessions.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::Arc;
use std::time::Duration;

use common::{config, init_op, loaded_session};
use resecta_plan::PlanEvent;
use resecta_session::api::{EditOp, PointCloud, ReconOptions, SessionState};
use resecta_session::{ErrorKind, Service, ServiceConfig};
use resecta_store::{Blob, MemoryStore, SessionStore, StoreOptions};

fn service_with(store: Arc<dyn SessionStore>, config: ServiceConfig) -> Arc<Service> {
    Arc::new(Service::new(store, config))
}

fn memory_store() -> Arc<dyn SessionStore> {
    Arc::new(MemoryStore::new(StoreOptions::default()))
}

/// Room for the phantom's label map with its replay ring (8 bytes a voxel, as the budget
/// estimates) and `plan` bytes more.
fn budget(plan: u64) -> ServiceConfig {
    let config = config();
    let voxels = common::phantom().data().len() as u64;
    ServiceConfig {
        max_memory_bytes: voxels * 8 + config.ring.bytes as u64 + plan,
        ..config
    }
}

fn resolution(name: &str, r: usize) -> EditOp {
    EditOp::Event {
        event: PlanEvent::SetResolution {
            name: name.into(),
            resolution: [r, r],
        },
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_beyond_the_memory_budget_are_refused_before_they_are_computed() {
    // 32 MiB for surfaces: a 40×40 resection (~1 MiB with its headroom) fits, 500×500 does not.
    let service = service_with(memory_store(), budget(32 << 20));
    let id = loaded_session(&service, "Budget").await;
    let added = service.edit(&id, 0, init_op()).await.unwrap();
    let e = service
        .edit(&id, added.plan_version, resolution("r1", 500))
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::ResourceExhausted, "{e}");
    assert_eq!(e.code(), "MEMORY_QUOTA");
    assert!(e.to_string().contains("the plan's surfaces"), "{e}");
    // Nothing changed, and a resolution within the budget is taken.
    let now = service.get_session(&id).await.unwrap();
    assert_eq!(now.plan_version, added.plan_version);
    let finer = service
        .edit(&id, added.plan_version, resolution("r1", 120))
        .await
        .unwrap();
    assert_eq!(finer.plan_version, added.plan_version + 1);

    // A whole plan of 32 resections at 500×500 (the heavy plan of #19) is refused at once,
    // not after computing its surfaces.
    let exported = service.export_plan(&id).await.unwrap().value;
    let mut plan: serde_json::Value = serde_json::from_str(&exported).unwrap();
    let one = plan["resections"][0].clone();
    plan["resections"] = (0..32)
        .map(|k| {
            let mut r = one.clone();
            r["name"] = format!("h{k}").into();
            r["resolution"] = serde_json::json!([500, 500]);
            r
        })
        .collect();
    let e = service
        .import_plan(&id, &plan.to_string(), 0)
        .await
        .unwrap_err();
    assert_eq!(e.code(), "MEMORY_QUOTA", "{e}");
    let after = service.get_session(&id).await.unwrap();
    assert_eq!(after.plan_version, finer.plan_version);
    // Undoing the finer resolution frees room; its redo is admitted again.
    service.edit(&id, 0, EditOp::Undo).await.unwrap();
    service.edit(&id, 0, EditOp::Redo).await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watchers_hold_memory_while_they_watch() {
    let service = service_with(memory_store(), budget(64 << 20));
    let id = loaded_session(&service, "Watched").await;
    service.edit(&id, 0, init_op()).await.unwrap();
    service.edit(&id, 0, resolution("r1", 200)).await.unwrap();
    let first = service.watch(&id, None).await.unwrap();
    // Another upload takes what is left, MiB by MiB, until the budget refuses it.
    let mut filler = service.admit_upload().unwrap();
    while filler.grow(1 << 20).is_ok() {}
    let e = service.watch(&id, None).await.unwrap_err();
    assert_eq!(e.code(), "MEMORY_QUOTA", "{e}");
    assert!(e.to_string().contains("the watch stream"), "{e}");
    // The first watcher's memory comes back when it goes: the new one is admitted.
    drop(first);
    let _second = service.watch(&id, None).await.unwrap();
    // Edits that move a surface need no room of their own: the plan's charge has it.
    let moved = EditOp::Event {
        event: PlanEvent::Translate {
            name: "r1".into(),
            delta: [1.0, 0.0, 0.0],
        },
    };
    service.edit(&id, 0, moved).await.unwrap();
    drop(filler);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconstructions_are_admitted_by_their_grid() {
    let service = service_with(memory_store(), budget(64 << 20));
    let id = loaded_session(&service, "Recon").await;
    // Depth 9: (2⁹+1)³ nodes, about 2 GiB: refused before anything starts.
    let deep = ReconOptions {
        psr_depth: Some(9),
        ..ReconOptions::default()
    };
    let e = service.reconstruct(&id, deep).await.unwrap_err();
    assert_eq!(e.code(), "MEMORY_QUOTA", "{e}");
    assert!(e.to_string().contains("the reconstruction"), "{e}");
    // Depth 5 fits, and its reservation is given back when it ends: a second one runs too.
    for _ in 0..2 {
        let shallow = ReconOptions {
            psr_depth: Some(5),
            ..ReconOptions::default()
        };
        let mut events = service.reconstruct(&id, shallow).await.unwrap();
        let mut done = false;
        while let Some(event) = events.recv().await {
            done = matches!(
                event.unwrap(),
                resecta_session::api::ReconstructEvent::Done { .. }
            );
        }
        assert!(done);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn point_clouds_are_admitted_by_their_grid_and_give_it_back() {
    // Room for a depth-6 grid (65³ nodes, about 5 MiB with the rest) but not a depth-8 one
    // (257³ nodes, about 300 MiB).
    let service = service_with(
        memory_store(),
        ServiceConfig {
            max_memory_bytes: 64 << 20,
            ..config()
        },
    );
    let positions: Vec<[f64; 3]> = (0..400)
        .map(|k| {
            let z = 1.0 - 2.0 * (k as f64 + 0.5) / 400.0;
            let (r, t) = ((1.0 - z * z).sqrt(), 2.399_963 * k as f64);
            [10.0 * r * t.cos(), 10.0 * r * t.sin(), 10.0 * z]
        })
        .collect();
    let cloud = |depth| PointCloud {
        positions: positions.clone(),
        depth: Some(depth),
        ..PointCloud::default()
    };
    let e = service.reconstruct_points(cloud(8)).await.unwrap_err();
    assert_eq!(e.code(), "MEMORY_QUOTA", "{e}");
    assert!(
        e.to_string().contains("the point cloud's reconstruction"),
        "{e}"
    );
    // Depth 6 fits, and each call gives its reservation back: many in a row all run.
    for _ in 0..3 {
        service.reconstruct_points(cloud(6)).await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_grow_within_their_limit_and_the_budget_and_give_it_back() {
    let service = service_with(
        memory_store(),
        ServiceConfig {
            max_memory_bytes: 1000,
            max_upload_bytes: 800,
            ..config()
        },
    );
    let mut first = service.admit_upload().unwrap();
    first.grow(600).unwrap();
    let e = first.grow(201).unwrap_err();
    assert_eq!(e.code(), "UPLOAD_TOO_LARGE", "{e}");
    assert_eq!(first.bytes(), 600, "a refused growth keeps what was held");
    // A stalled second upload gets only what the first leaves.
    let mut second = service.admit_upload().unwrap();
    second.grow(400).unwrap();
    let e = second.grow(1).unwrap_err();
    assert_eq!(e.code(), "MEMORY_QUOTA", "{e}");
    assert!(e.to_string().contains("the upload"), "{e}");
    drop(first);
    second.grow(400).unwrap();
    drop(second);
    service.admit_upload().unwrap().grow(800).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stored_session_that_cannot_be_restored_is_listed_as_damaged() {
    let store = memory_store();
    let (good, bad_summary, bad_log) = {
        let service = service_with(Arc::clone(&store), config());
        let good = loaded_session(&service, "Good").await;
        let bad_summary = loaded_session(&service, "Summary").await;
        let bad_log = loaded_session(&service, "Log").await;
        service.edit(&bad_log, 0, init_op()).await.unwrap();
        (good, bad_summary, bad_log)
    };
    // Stored data this build cannot read: a summary that is not JSON, a log record that is
    // not a record.
    let garbage = Blob {
        meta_json: "{not json".into(),
        data: Vec::new(),
    };
    store.put_blob(&bad_summary, "summary", &garbage).unwrap();
    let len = store.log_len(&bad_log).unwrap();
    store
        .append(&bad_log, len, &["{\"v\":2,\"garbage\":1}".to_owned()])
        .unwrap();

    let restarted = service_with(Arc::clone(&store), config());
    // Touch the session with the bad log so that its restore fails first.
    let e = restarted.edit(&bad_log, 0, init_op()).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::FailedPrecondition, "{e}");
    assert!(e.to_string().contains("damaged"), "{e}");
    let listed = restarted.list_sessions().await.unwrap();
    let state = |id: &str| listed.iter().find(|s| s.id == id).map(|s| s.state);
    assert_eq!(state(&good), Some(SessionState::LabelMap));
    assert_eq!(state(&bad_summary), Some(SessionState::Damaged));
    assert_eq!(state(&bad_log), Some(SessionState::Damaged));
    assert_eq!(
        restarted.get_session(&bad_log).await.unwrap().state,
        SessionState::Damaged
    );
    // The good one plans; the damaged ones can be deleted, and the listing is whole again.
    restarted.edit(&good, 0, init_op()).await.unwrap();
    for id in [&bad_summary, &bad_log] {
        restarted.delete_session(id).await.unwrap();
    }
    let listed = restarted.list_sessions().await.unwrap();
    assert_eq!(listed.len(), 1);
    assert_eq!(listed[0].id, good);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_expiry_spares_a_watched_session() {
    let service = service_with(
        memory_store(),
        ServiceConfig {
            idle_expiry: Some(Duration::from_millis(20)),
            ..config()
        },
    );
    let watched = service.create_session("Watched").await.unwrap().id;
    let idle = service.create_session("Idle").await.unwrap().id;
    let stream = service.watch(&watched, None).await.unwrap();
    tokio::time::sleep(Duration::from_millis(60)).await;
    assert_eq!(service.expire_idle().await.unwrap(), 1);
    assert_eq!(
        service.get_session(&idle).await.unwrap_err().kind(),
        ErrorKind::NotFound
    );
    // Once nobody watches it, it expires like any other.
    drop(stream);
    tokio::time::sleep(Duration::from_millis(60)).await;
    assert_eq!(service.expire_idle().await.unwrap(), 1);
    assert_eq!(
        service.get_session(&watched).await.unwrap_err().kind(),
        ErrorKind::NotFound
    );
}
