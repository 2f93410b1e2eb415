//! An edit, undo or redo applies its event once: the planner computes the step, the history
//! records the computed plan (counted by `plan::APPLIED` on this thread).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use resecta_geom::{RoleMap, Vec3};
use resecta_phantom::{PhantomSpec, generate};

use crate::plan::APPLIED;
use crate::{Anatomy, Change, History, LogEntry, Plan, PlanEvent, Planner, Resection, Target};

/// Events applied while `f` runs.
fn applied<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let before = APPLIED.with(std::cell::Cell::get);
    let out = f();
    (out, APPLIED.with(std::cell::Cell::get) - before)
}

fn roles() -> RoleMap {
    serde_json::from_str(r#"{"parenchyma":[1],"tumor":[2]}"#).unwrap()
}

fn planar() -> Resection {
    let pts = (0..16)
        .map(|k| [(k / 4) as f64 * 10.0, (k % 4) as f64 * 10.0, 5.0])
        .collect();
    Resection::new("r1", [4, 4], pts)
}

fn nudge(x: f64) -> PlanEvent {
    PlanEvent::SetControlPoint {
        name: "r1".into(),
        i: 1,
        j: 2,
        point: [x, 4.0, 3.0],
    }
}

#[test]
fn history_steps_apply_their_event_once() {
    let mut h = History::new(Plan::new(roles()));
    let add = PlanEvent::AddResection {
        resection: planar(),
    };
    let (r, n) = applied(|| h.edit(add.clone()).map(|_| ()));
    assert!(r.is_ok());
    assert_eq!(n, 1);
    for k in 0..64 {
        let (r, n) = applied(|| h.edit(nudge(f64::from(k))).map(|_| ()));
        assert!(r.is_ok());
        assert_eq!(n, 1);
    }
    // 65 events: the plan one back is the checkpoint after 64, applied from nothing.
    let (r, n) = applied(|| h.undo().map(|_| ()));
    assert!(r.is_ok());
    assert_eq!(n, 0);
    let (r, n) = applied(|| h.redo().map(|_| ()));
    assert!(r.is_ok());
    assert_eq!(n, 1);
    // A failing edit is applied once (to a copy) and refused.
    let (r, n) = applied(|| h.edit(nudge(f64::NAN)).map(|_| ()));
    assert!(r.is_err());
    assert_eq!(n, 1);
    // Replay applies each logged edit once.
    let log = h.log().to_vec();
    let edits = log
        .iter()
        .filter(|e| matches!(e, LogEntry::Edit { .. }))
        .count();
    let (replayed, n) = applied(|| History::replay(Plan::new(roles()), &log).unwrap());
    assert_eq!(replayed.plan(), h.plan());
    assert_eq!(n, edits + 1, "every edit once, the redo once");
}

#[test]
fn a_step_staged_before_another_was_recorded_is_refused() {
    let mut h = History::new(Plan::new(roles()));
    let first = h
        .stage_edit(PlanEvent::AddResection {
            resection: planar(),
        })
        .unwrap();
    let second = h
        .stage_edit(PlanEvent::AddResection {
            resection: Resection {
                name: "r2".into(),
                ..planar()
            },
        })
        .unwrap();
    h.record(first).unwrap();
    let plan = h.plan().clone();
    assert!(h.record(second).is_err());
    assert_eq!(h.plan(), &plan);
    assert_eq!(h.log().len(), 1);
}

#[test]
fn planner_steps_apply_their_event_once_and_say_what_changed() {
    let labels = generate(&PhantomSpec::small()).unwrap().labels;
    let roles = PhantomSpec::small().roles;
    let anatomy = Arc::new(Anatomy::new(&labels, &roles).unwrap());
    let mut p = Planner::new(anatomy, Plan::new(roles)).unwrap();
    let (r, _) = p
        .initial_resection("r1", &Target::default(), Vec3::new(-30.0, 0.0, 0.0), [4, 4])
        .unwrap();
    let add = PlanEvent::AddResection { resection: r };
    let (change, n) = applied(|| p.edit(add.clone()).unwrap());
    assert_eq!(n, 1);
    let names = |c: &Change| (c.changed.clone(), c.removed.clone());
    assert_eq!(names(&change), (vec!["r1".to_owned()], vec![]));
    assert_eq!(change.entry, LogEntry::Edit { event: add });

    let (change, n) = applied(|| p.edit(nudge(-6.0)).unwrap());
    assert_eq!(n, 1);
    assert_eq!(names(&change), (vec!["r1".to_owned()], vec![]));
    let moved = p.state("r1").unwrap().surface.points();

    // The same edit again changes nothing: no resection to recompute or show.
    let (change, n) = applied(|| p.edit(nudge(-6.0)).unwrap());
    assert_eq!(n, 1);
    assert_eq!(names(&change), (vec![], vec![]));

    // Undo rebuilds from the base checkpoint: taking back the no-op applies the two events
    // before it and changes nothing; taking back the drag applies one and changes r1.
    let (change, n) = applied(|| p.undo().unwrap());
    assert_eq!((names(&change), n), ((vec![], vec![]), 2));
    let (change, n) = applied(|| p.undo().unwrap());
    assert_eq!(n, 1);
    assert_eq!(names(&change), (vec!["r1".to_owned()], vec![]));
    assert_eq!(change.entry, LogEntry::Undo);
    let (change, n) = applied(|| p.redo().unwrap());
    assert_eq!(n, 1);
    assert_eq!(names(&change), (vec!["r1".to_owned()], vec![]));
    assert_eq!(change.entry, LogEntry::Redo);
    assert_eq!(p.state("r1").unwrap().surface.points(), moved);

    // A failing edit: applied once to a copy, nothing changes.
    let plan = p.plan().clone();
    let (r, n) = applied(|| p.edit(nudge(f64::NAN)));
    assert!(r.is_err());
    assert_eq!(n, 1);
    assert_eq!(p.plan(), &plan);
    assert_eq!(p.state("r1").unwrap().surface.points(), moved);

    let delete = PlanEvent::DeleteResection { name: "r1".into() };
    let (change, n) = applied(|| p.edit(delete).unwrap());
    assert_eq!(n, 1);
    assert_eq!(names(&change), (vec![], vec!["r1".to_owned()]));
    assert!(p.state("r1").is_err());
    let (change, _) = applied(|| p.undo().unwrap());
    assert_eq!(names(&change), (vec!["r1".to_owned()], vec![]));
    assert_eq!(p.state("r1").unwrap().surface.points(), moved);
}
