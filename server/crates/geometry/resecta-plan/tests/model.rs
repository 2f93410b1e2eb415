//! Plan model, events, history and initialisation against analytic answers.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use proptest::prelude::*;
use resecta_geom::primitives::icosphere;
use resecta_geom::{Plane, RoleMap, Vec3};
use resecta_plan::{
    Group, History, LogEntry, Plan, PlanError, PlanEvent, Resection, initialise, slicing_plane,
};

fn roles() -> RoleMap {
    serde_json::from_str(r#"{"parenchyma":[1],"tumor":[2]}"#).unwrap()
}

fn planar(name: &str) -> Resection {
    let pts = (0..16)
        .map(|k| [(k / 4) as f64 * 10.0, (k % 4) as f64 * 10.0, 5.0])
        .collect();
    Resection::new(name, [4, 4], pts)
}

fn plan_with(r: Resection) -> Plan {
    let mut p = Plan::new(roles());
    p.apply(&PlanEvent::AddResection { resection: r }).unwrap();
    p
}

#[test]
fn minimal_issue_plan_parses_with_defaults_and_round_trips() {
    let pts: Vec<String> = (0..16).map(|k| format!("[{k},{},0]", k * 2)).collect();
    let text = format!(
        r#"{{"format":"resecta-plan/1","roles":{{"parenchyma":[1],"tumor":[2]}},"resections":[{{"name":"r1","kind":"bezier","grid":[4,4],"control_points":[{}],"margin_mm":10}}]}}"#,
        pts.join(",")
    );
    let plan = Plan::from_json(&text).unwrap();
    let r = &plan.resections[0];
    assert_eq!(r.resolution, [40, 40]);
    assert_eq!(r.band_mm, 5.0);
    assert_eq!(r.control_points[3], [3.0, 6.0, 0.0]);
    let again = Plan::from_json(&plan.to_json().unwrap()).unwrap();
    assert_eq!(again, plan);
    assert!(
        plan.to_json()
            .unwrap()
            .contains("\"format\": \"resecta-plan/1\"")
    );
}

#[test]
fn bad_plans_are_refused_with_named_errors() {
    let base = planar("r1");
    let cases: Vec<(Resection, &str)> = vec![
        (
            Resection {
                control_points: base.control_points[..15].to_vec(),
                ..base.clone()
            },
            "needs 16 control points, got 15",
        ),
        (
            Resection {
                grid: [1, 16],
                ..base.clone()
            },
            "each side must be",
        ),
        (
            Resection {
                margin_mm: 0.0,
                ..base.clone()
            },
            "margin_mm",
        ),
        (
            Resection {
                margin_mm: f64::NAN,
                ..base.clone()
            },
            "margin_mm",
        ),
        (
            Resection {
                band_mm: -1.0,
                ..base.clone()
            },
            "band_mm",
        ),
        (
            Resection {
                resolution: [40, 501],
                ..base.clone()
            },
            "resolution",
        ),
        (
            Resection {
                name: " ".into(),
                ..base.clone()
            },
            "name",
        ),
    ];
    for (r, want) in cases {
        let mut p = Plan::new(roles());
        let e = p
            .apply(&PlanEvent::AddResection { resection: r })
            .unwrap_err();
        assert!(e.to_string().contains(want), "{e} lacks {want}");
        assert!(p.resections.is_empty());
    }
    let mut nan = planar("r1");
    nan.control_points[5][1] = f64::INFINITY;
    let e = Plan::new(roles())
        .apply(&PlanEvent::AddResection { resection: nan })
        .unwrap_err();
    assert!(matches!(e, PlanError::NonFinite { .. }), "{e}");
    for (text, want) in [
        (
            r#"{"format":"resecta-plan/2","roles":{"parenchyma":[1],"tumor":[2]}}"#,
            "resecta-plan/2",
        ),
        (
            r#"{"format":"resecta-plan/1","roles":{"parenchyma":[1],"tumor":[2]},"extra":1}"#,
            "extra",
        ),
        (
            r#"{"format":"resecta-plan/1","roles":{"parenchyma":[1]}}"#,
            "",
        ),
        ("[1,2", "JSON"),
    ] {
        let e = Plan::from_json(text);
        if text.contains(r#""parenchyma":[1]}}"#) {
            // A plan without tumours is valid until a resection needs one.
            assert!(e.is_ok());
            continue;
        }
        let e = e.unwrap_err();
        assert!(e.to_string().contains(want), "{e} lacks {want}");
    }
}

#[test]
fn failing_edits_leave_the_plan_unchanged() {
    let mut p = plan_with(planar("r1"));
    let before = p.clone();
    for ev in [
        PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 4,
            j: 0,
            point: [0.0; 3],
        },
        PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 1,
            j: 1,
            point: [f64::NAN, 0.0, 0.0],
        },
        PlanEvent::SetMargin {
            name: "r1".into(),
            margin_mm: -2.0,
        },
        PlanEvent::Translate {
            name: "nope".into(),
            delta: [1.0, 0.0, 0.0],
        },
        PlanEvent::Rotate {
            name: "r1".into(),
            axis: [0.0; 3],
            angle_deg: 10.0,
            centre: None,
        },
        PlanEvent::MoveGroup {
            name: "r1".into(),
            group: Group::Ring(2),
            delta: [1.0, 0.0, 0.0],
        },
        PlanEvent::AddResection {
            resection: planar("r1"),
        },
        PlanEvent::SetTarget {
            name: "r1".into(),
            target: resecta_plan::Target {
                labels: vec![1],
                points: vec![],
            },
        },
    ] {
        assert!(p.apply(&ev).is_err(), "{ev:?} should fail");
        assert_eq!(p, before);
    }
}

#[test]
fn groups_split_grids_into_rings() {
    let count = |g: Group, m: usize, n: usize| {
        (0..m * n)
            .filter(|&k| g.contains(m, n, k / n, k % n))
            .count()
    };
    assert_eq!(count(Group::Inner, 4, 4), 4);
    assert_eq!(count(Group::Outer, 4, 4), 12);
    assert_eq!(count(Group::Ring(1), 6, 7), 14);
    assert_eq!(count(Group::Ring(2), 6, 7), 6);
    assert_eq!(count(Group::Inner, 2, 5), 0);
    let mut p = plan_with(planar("r1"));
    p.apply(&PlanEvent::MoveGroup {
        name: "r1".into(),
        group: Group::Inner,
        delta: [0.0, 0.0, 7.0],
    })
    .unwrap();
    let r = &p.resections[0];
    let raised: Vec<usize> = (0..16)
        .filter(|&k| r.control_points[k][2] == 12.0)
        .collect();
    assert_eq!(raised, vec![5, 6, 9, 10]);
}

#[test]
fn rotation_is_rigid_and_full_turns_return() {
    let mut p = plan_with(planar("r1"));
    let before = p.resections[0].clone();
    let rot = |deg: f64| PlanEvent::Rotate {
        name: "r1".into(),
        axis: [1.0, 2.0, 0.5],
        angle_deg: deg,
        centre: None,
    };
    p.apply(&rot(37.0)).unwrap();
    let after = &p.resections[0];
    let d = |r: &Resection, a: usize, b: usize| {
        let (x, y) = (r.control_points[a], r.control_points[b]);
        ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt()
    };
    for (a, b) in [(0, 15), (3, 12), (5, 6)] {
        assert!((d(&before, a, b) - d(after, a, b)).abs() < 1e-9);
    }
    assert!((after.centre() - before.centre()).norm() < 1e-9);
    p.apply(&rot(323.0)).unwrap();
    for (x, y) in p.resections[0]
        .control_points
        .iter()
        .zip(&before.control_points)
    {
        for c in 0..3 {
            assert!((x[c] - y[c]).abs() < 1e-9);
        }
    }
}

fn arb_event() -> impl Strategy<Value = PlanEvent> {
    let v = || prop::array::uniform3(-20.0..20.0f64);
    prop_oneof![
        (0..5usize, 0..4usize, v()).prop_map(|(i, j, point)| PlanEvent::SetControlPoint {
            name: "r1".into(),
            i,
            j,
            point
        }),
        (prop::bool::ANY, v()).prop_map(|(inner, delta)| PlanEvent::MoveGroup {
            name: "r1".into(),
            group: if inner { Group::Inner } else { Group::Outer },
            delta
        }),
        v().prop_map(|delta| PlanEvent::Translate {
            name: "r1".into(),
            delta
        }),
        (v(), -90.0..90.0f64).prop_map(|(axis, angle_deg)| PlanEvent::Rotate {
            name: "r1".into(),
            axis,
            angle_deg,
            centre: None
        }),
        (-1.0..30.0f64).prop_map(|margin_mm| PlanEvent::SetMargin {
            name: "r1".into(),
            margin_mm
        }),
    ]
}

#[derive(Debug, Clone)]
enum Step {
    Edit(PlanEvent),
    Undo,
    Redo,
}

fn arb_step() -> impl Strategy<Value = Step> {
    prop_oneof![
        3 => arb_event().prop_map(Step::Edit),
        1 => Just(Step::Undo),
        1 => Just(Step::Redo),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// Any mix of edits, undos and redos (some failing): undoing everything returns the base,
    /// redoing everything returns the latest state, and replaying the log rebuilds the same plan.
    #[test]
    fn undo_redo_and_replay_are_exact(steps in prop::collection::vec(arb_step(), 1..150)) {
        let base = plan_with(planar("r1"));
        let mut h = History::new(base.clone());
        for s in &steps {
            let _ = match s {
                Step::Edit(e) => h.edit(e.clone()).map(|_| ()),
                Step::Undo => h.undo().map(|_| ()),
                Step::Redo => h.redo().map(|_| ()),
            };
        }
        let now = h.plan().clone();
        let replayed = History::replay(base.clone(), h.log()).unwrap();
        prop_assert_eq!(replayed.plan(), &now);
        let depth = h.undo_depth();
        let pending = h.redo_depth();
        let mut states = vec![now.clone()];
        for _ in 0..depth { states.push(h.undo().unwrap().clone()); }
        prop_assert_eq!(h.plan(), &base);
        prop_assert!(h.undo().is_err());
        for k in (0..depth).rev() {
            prop_assert_eq!(h.redo().unwrap(), &states[k]);
        }
        prop_assert_eq!(h.redo_depth(), pending);
    }
}

/// Resections that differ between two plans: (added or changed, removed), in plan order.
fn plan_difference(before: &Plan, after: &Plan) -> (Vec<String>, Vec<String>) {
    let changed = after
        .resections
        .iter()
        .filter(|r| before.resection(&r.name).ok() != Some(*r))
        .map(|r| r.name.clone())
        .collect();
    let removed = before
        .resections
        .iter()
        .filter(|r| after.resection(&r.name).is_err())
        .map(|r| r.name.clone())
        .collect();
    (changed, removed)
}

/// Edits of two resections that come and go; margins from two values (so some edits change
/// nothing).
fn arb_step_on_two() -> impl Strategy<Value = Step> {
    let name = || prop_oneof![Just("r1".to_owned()), Just("r2".to_owned())];
    let event = prop_oneof![
        (
            name(),
            0..5usize,
            0..4usize,
            prop::array::uniform3(-20.0..20.0f64)
        )
            .prop_map(|(name, i, j, point)| PlanEvent::SetControlPoint {
                name,
                i,
                j,
                point
            }),
        (name(), prop_oneof![Just(5.0), Just(10.0)])
            .prop_map(|(name, margin_mm)| PlanEvent::SetMargin { name, margin_mm }),
        name().prop_map(|n| PlanEvent::AddResection {
            resection: planar(&n)
        }),
        name().prop_map(|name| PlanEvent::DeleteResection { name }),
    ];
    prop_oneof![
        3 => event.prop_map(Step::Edit),
        1 => Just(Step::Undo),
        1 => Just(Step::Redo),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// A staged step's plan is the one recorded, and what it says changed is what differs
    /// between the plans before and after (the whole plans compared); a failing step changes
    /// nothing.
    #[test]
    fn a_recorded_step_reports_exactly_what_changed(
        steps in prop::collection::vec(arb_step_on_two(), 1..150),
    ) {
        let base = plan_with(planar("r1"));
        let mut h = History::new(base.clone());
        for s in &steps {
            let before = h.plan().clone();
            let log_len = h.log().len();
            let staged = match s {
                Step::Edit(e) => h.stage_edit(e.clone()),
                Step::Undo => h.stage_undo(),
                Step::Redo => h.stage_redo(),
            };
            let Ok(staged) = staged else {
                prop_assert_eq!(h.plan(), &before);
                prop_assert_eq!(h.log().len(), log_len);
                continue;
            };
            let next = staged.plan().clone();
            let change = h.record(staged).unwrap();
            prop_assert_eq!(h.plan(), &next);
            prop_assert_eq!(h.log().last(), Some(&change.entry));
            let expected = match s {
                Step::Edit(e) => LogEntry::Edit { event: e.clone() },
                Step::Undo => LogEntry::Undo,
                Step::Redo => LogEntry::Redo,
            };
            prop_assert_eq!(&change.entry, &expected);
            prop_assert_eq!(
                (change.changed, change.removed),
                plan_difference(&before, h.plan())
            );
        }
        let replayed = History::replay(base, h.log()).unwrap();
        prop_assert_eq!(replayed.plan(), h.plan());
    }
}

#[test]
fn undo_beyond_a_checkpoint_then_edit_drops_the_redo_branch() {
    let mut h = History::new(plan_with(planar("r1")));
    for k in 0..200 {
        h.edit(PlanEvent::Translate {
            name: "r1".into(),
            delta: [f64::from(k % 7), 0.0, 0.0],
        })
        .unwrap();
    }
    for _ in 0..150 {
        h.undo().unwrap();
    }
    let at50 = h.plan().clone();
    h.edit(PlanEvent::SetMargin {
        name: "r1".into(),
        margin_mm: 3.0,
    })
    .unwrap();
    assert_eq!(h.redo_depth(), 0);
    h.undo().unwrap();
    assert_eq!(h.plan(), &at50);
    let log_len = h.log().len();
    assert_eq!(log_len, 200 + 150 + 1 + 1);
    assert!(matches!(h.log()[200], LogEntry::Undo));
    let replayed = History::replay(h.base().clone(), h.log()).unwrap();
    assert_eq!(replayed.plan(), h.plan());
}

#[test]
fn initial_grid_of_a_sphere_cut_through_its_centre_is_the_thesis_extent() {
    // A sphere's great circle of radius r: variance r²/2 along every in-plane axis, so
    // l = 4·√(r²/2) = 2√2·r, centred on the sphere's centre.
    let (c, r) = (Vec3::new(10.0, -20.0, 30.0), 50.0);
    let liver = icosphere(c, r, 6).unwrap();
    let tumour = c + Vec3::new(-3.0, 4.0, 12.0);
    let end = c + Vec3::new(3.0, -4.0, -12.0);
    let plane = slicing_plane(tumour, end).unwrap();
    let init = initialise(&liver, &plane, [4, 5]).unwrap();
    // Chord error of a level-6 icosphere: < 0.02 % of r.
    let want = 2.0 * 2f64.sqrt() * r;
    for l in init.lengths {
        assert!((l - want).abs() < 2e-3 * want, "{l} vs {want}");
    }
    let centre = Vec3::from(init.centre);
    assert!((centre - c).norm() < 1e-6 * r + 1e-6, "{centre:?}");
    let n = (end - tumour).normalize();
    assert!((Vec3::from(init.plane_normal) - n).norm() < 1e-12);
    let [e1, e2] = init.axes.map(Vec3::from);
    assert!((e1.cross(&e2) - n).norm() < 1e-9);
    assert_eq!(init.control_points.len(), 20);
    for p in &init.control_points {
        assert!(plane.signed_distance(&Vec3::from(*p)).abs() < 1e-9);
    }
    let corner = |k: usize| Vec3::from(init.control_points[k]);
    assert!((corner(19) - corner(0) - e1 * init.lengths[0] - e2 * init.lengths[1]).norm() < 1e-9);
    assert!(((corner(0) + corner(19)) / 2.0 - centre).norm() < 1e-9);
}

#[test]
fn initialisation_refuses_degenerate_input() {
    let liver = icosphere(Vec3::zeros(), 40.0, 3).unwrap();
    let c = Vec3::new(1.0, 2.0, 3.0);
    assert!(matches!(
        slicing_plane(c, c),
        Err(PlanError::EndPointAtCentroid)
    ));
    assert!(matches!(
        slicing_plane(c, Vec3::new(f64::NAN, 0.0, 0.0)),
        Err(PlanError::NonFinite { .. })
    ));
    let far = Plane::new(Vec3::new(0.0, 0.0, 100.0), Vec3::z()).unwrap();
    assert!(matches!(
        initialise(&liver, &far, [4, 4]),
        Err(PlanError::PlaneMissesLiver)
    ));
    let mid = Plane::new(Vec3::zeros(), Vec3::z()).unwrap();
    assert!(initialise(&liver, &mid, [1, 4]).is_err());
    assert!(initialise(&liver, &mid, [4, 4]).is_ok());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]
    /// Mutated plan files: a typed error or a valid plan that round-trips; never a panic.
    #[test]
    fn mutated_plan_files_never_panic(
        edits in prop::collection::vec((0usize..400, any::<u8>()), 1..6),
        cut in 0usize..400,
    ) {
        let mut p = plan_with(planar("r1"));
        p.apply(&PlanEvent::SetTarget {
            name: "r1".into(),
            target: resecta_plan::Target { labels: vec![2], points: vec![[1.0, 2.0, 3.0]] },
        }).unwrap();
        let mut bytes = p.to_json().unwrap().into_bytes();
        for (at, b) in edits {
            let k = at % bytes.len();
            bytes[k] = b;
        }
        bytes.truncate(bytes.len().max(cut) - cut.min(bytes.len() / 2));
        let Ok(text) = String::from_utf8(bytes) else { return Ok(()) };
        if let Ok(plan) = Plan::from_json(&text) {
            for r in &plan.resections {
                prop_assert!(r.validate().is_ok());
            }
            prop_assert_eq!(Plan::from_json(&plan.to_json().unwrap()).unwrap(), plan);
        }
    }
}
