//! A fixed workload of resection edits for counting the CPU one edit costs (instructions under
//! `valgrind --tool=callgrind`, repeatable on a loaded machine): the small phantom, one
//! resection, then `<edits>` steps of `<op>` through the session edit path (`service`: an
//! in-memory store, no volumetry) or the planner alone (`planner`). Run it with two counts and
//! divide the difference of the totals by the difference of the counts:
//! `docs/bench/edit-once/README.md`.
//!
//! `edit_cost <service|planner> <drag|undo-redo> <edits>`
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;
use std::time::Duration;

use resecta_geom::{LabelMap, RoleMap, Vec3};
use resecta_phantom::{PhantomSpec, generate};
use resecta_plan::{Anatomy, Plan, PlanEvent, Planner, Target};
use resecta_session::api::{EditOp, LabelMapSource, RawLabelMap};
use resecta_session::{Service, ServiceConfig};
use resecta_store::{MemoryStore, StoreOptions};

const END_POINT: [f64; 3] = [-30.0, 0.0, 0.0];

/// The k-th drag: an inner control point back and forth, as a surgeon drags it.
fn drag(k: usize) -> PlanEvent {
    let x = if k.is_multiple_of(2) { -6.0 } else { -8.0 };
    PlanEvent::SetControlPoint {
        name: "r1".into(),
        i: 1,
        j: 2,
        point: [x, 4.0, 3.0],
    }
}

/// Step `k` of the workload: a drag, or (after one drag) alternately an undo and a redo.
enum Step {
    Event(PlanEvent),
    Undo,
    Redo,
}

fn step(undo_redo: bool, k: usize) -> Step {
    match (undo_redo, k.is_multiple_of(2)) {
        (false, _) => Step::Event(drag(k)),
        (true, true) => Step::Undo,
        (true, false) => Step::Redo,
    }
}

fn service(labels: &LabelMap, undo_redo: bool, edits: usize) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let hour = Duration::from_secs(3600);
        let config = ServiceConfig {
            volumes_delay: hour,
            volumes_max_interval: hour,
            ..ServiceConfig::default()
        };
        let store = Arc::new(MemoryStore::new(StoreOptions::default()));
        let service = Arc::new(Service::new(store, config));
        let id = service.create_session("edit cost").await.unwrap().id;
        service
            .upload_label_map(
                &id,
                LabelMapSource::Raw(RawLabelMap::of(labels)),
                RoleMap::default(),
            )
            .await
            .unwrap();
        let init = EditOp::InitFromEndPoint {
            name: "r1".into(),
            target: Target::default(),
            end_point: END_POINT,
            grid: [4, 4],
        };
        service.edit(&id, 0, init).await.unwrap();
        service
            .edit(&id, 0, EditOp::Event { event: drag(1) })
            .await
            .unwrap();
        for k in 0..edits {
            let op = match step(undo_redo, k) {
                Step::Event(event) => EditOp::Event { event },
                Step::Undo => EditOp::Undo,
                Step::Redo => EditOp::Redo,
            };
            service.edit(&id, 0, op).await.unwrap();
        }
    });
}

fn planner(labels: &LabelMap, undo_redo: bool, edits: usize) {
    let roles = RoleMap::default();
    let anatomy = Arc::new(Anatomy::new(labels, &roles).unwrap());
    let mut p = Planner::new(anatomy, Plan::new(roles)).unwrap();
    let (r, _) = p
        .initial_resection("r1", &Target::default(), Vec3::from(END_POINT), [4, 4])
        .unwrap();
    p.edit(PlanEvent::AddResection { resection: r }).unwrap();
    p.edit(drag(1)).unwrap();
    for k in 0..edits {
        match step(undo_redo, k) {
            Step::Event(e) => p.edit(e).map(|_| ()),
            Step::Undo => p.undo().map(|_| ()),
            Step::Redo => p.redo().map(|_| ()),
        }
        .unwrap();
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: edit_cost <service|planner> <drag|undo-redo> <edits>";
    let [_, path, op, edits] = args.as_slice() else {
        panic!("{usage}");
    };
    let edits: usize = edits.parse().expect(usage);
    let undo_redo = match op.as_str() {
        "drag" => false,
        "undo-redo" => true,
        _ => panic!("{usage}"),
    };
    let labels = generate(&PhantomSpec::small()).unwrap().labels;
    match path.as_str() {
        "service" => service(&labels, undo_redo, edits),
        "planner" => planner(&labels, undo_redo, edits),
        _ => panic!("{usage}"),
    }
}
