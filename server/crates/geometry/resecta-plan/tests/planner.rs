//! The planner on an ellipsoid-liver phantom: analytic cap volumes, margins to a spherical
//! tumour, incomplete cuts, undo/redo identity and bad input.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::f64::consts::PI;
use std::sync::Arc;

use resecta_geom::{Real, Role, RoleMap, Vec3};
use resecta_margin::{FAR_TOLERANCE_MM, MarginClass, Verdict};
use resecta_phantom::{PhantomSpec, SphereSpec, generate};
use resecta_plan::{
    Anatomy, Group, Plan, PlanError, PlanEvent, Planner, Resection, SlicePositions, Target,
    slice_projections,
};

mod common;

use common::{RADII, TUMOUR, TUMOUR_R, anatomy, spec};

/// The test phantom's tumour voxel centres (RAS) and its voxel edge vectors (columns).
fn tumour_voxels() -> (Vec<Vec3>, resecta_geom::Mat3) {
    let p = generate(&spec()).unwrap();
    let g = p.labels.grid();
    let tumour = spec().roles.labels(Role::Tumor).to_vec();
    let centres = (0..g.len())
        .filter(|&k| tumour.contains(&p.labels.data()[k]))
        .map(|k| g.voxel_center(g.ijk(k)))
        .collect();
    (centres, g.linear())
}

/// A planar 4×4 resection on x = `x0`, spanning `half` mm either side in y and z.
fn plane_x(name: &str, x0: Real, half: Real) -> Resection {
    let pts = (0..16)
        .map(|k| {
            let (i, j) = ((k / 4) as Real / 3.0, (k % 4) as Real / 3.0);
            [x0, -half + 2.0 * half * i, -half + 2.0 * half * j]
        })
        .collect();
    Resection::new(name, [4, 4], pts)
}

fn planner_with(r: Resection) -> Planner {
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection { resection: r })
        .unwrap();
    Planner::new(anatomy(), plan).unwrap()
}

/// Volume of {x > x0} of the ellipsoid.
fn cap(x0: Real) -> Real {
    let [a, b, c] = RADII;
    let h = x0 / a;
    a * b * c * PI * (1.0 - h).powi(2) * (2.0 + h) / 3.0
}

#[test]
fn planar_cut_resects_the_ellipsoidal_cap_without_the_tumour() {
    let x0 = 2.0;
    let mut p = planner_with(plane_x("r1", x0, 70.0));
    let v = p.volumes().unwrap();
    let r = &v.resections[0];
    assert!(r.complete_cut, "{r:?}");
    let truth = cap(x0) - 4.0 / 3.0 * PI * TUMOUR_R.powi(3);
    let got = r.resected_ml.unwrap() * 1000.0;
    let err = (got - truth) / truth;
    assert!(
        err.abs() < 0.005,
        "resected {got} vs {truth} ({:.3} %)",
        err * 100.0
    );
    let total_truth =
        4.0 / 3.0 * PI * RADII.iter().product::<Real>() - 4.0 / 3.0 * PI * TUMOUR_R.powi(3);
    assert!((v.total_ml * 1000.0 - total_truth).abs() < 0.005 * total_truth);
    let remnant = v.remnant_ml.unwrap();
    assert!((remnant + got / 1000.0 - v.total_ml).abs() < 1e-9);
    assert!((v.remnant_pct.unwrap() - 100.0 * remnant / v.total_ml).abs() < 1e-9);
    assert_eq!(v.flr_warning, Some(false));
}

#[test]
fn margin_to_the_spherical_tumour_and_its_location() {
    // Plane x = 2, tumour centre at x = 25, radius 10: the nearest point of the tumour is 13 mm
    // away, at (2, 0, 0) on the surface. With a 15 mm margin the violating disc has radius
    // √(25² − 23²). Tolerances cover the voxelised (1–1.3 mm) tumour model.
    let mut r = plane_x("r1", 2.0, 70.0);
    r.margin_mm = 15.0;
    r.band_mm = 3.0;
    r.resolution = [120, 120];
    let p = planner_with(r);
    let v = &p.state("r1").unwrap().verdict;
    // Margins are measured to the tumour's voxels as cubes: the smallest plane-to-cube distance,
    // never more than the nearest voxel centre's, within half a voxel of the analytic 13 mm.
    let min = v.min_margin_mm.unwrap();
    let (centres, cell) = tumour_voxels();
    let h = 0.5 * (0..3).map(|i| cell.column(i).x.abs()).sum::<Real>();
    let to_centre = centres
        .iter()
        .map(|c| c.x - 2.0)
        .fold(Real::INFINITY, Real::min);
    assert!(
        min <= to_centre,
        "min margin {min} > nearest voxel centre {to_centre}"
    );
    assert!(
        (min - (to_centre - h)).abs() < 0.01,
        "{min} vs {}",
        to_centre - h
    );
    assert!((min - 13.0).abs() <= h, "min margin {min}, half voxel {h}");
    let uncertainty = v.margin_uncertainty_mm.unwrap();
    assert!((uncertainty - h).abs() < 1e-3, "{uncertainty} vs {h}");
    let at = v.point.unwrap();
    assert!((at - Vec3::new(2.0, 0.0, 0.0)).norm() < 3.5, "{at:?}");
    let [u, w] = v.uv.unwrap();
    assert!((u - 0.5).abs() < 0.03 && (w - 0.5).abs() < 0.03, "{u} {w}");
    assert!(v.violation);
    // The voxelised tumour is a ball of radius about 23 − min (its cubes reach beyond the
    // sphere): the violating disc has radius √((15 + r)² − 23²), the warning ring reaches
    // √((18 + r)² − 23²).
    let r = 23.0 - min;
    let area = PI * ((15.0 + r).powi(2) - 23.0f64.powi(2));
    assert!(
        (v.violating_area_mm2 - area).abs() < 0.2 * area,
        "{} vs {area}",
        v.violating_area_mm2
    );
    let warn = PI * ((18.0 + r).powi(2) - 23.0f64.powi(2)) - area;
    assert!(
        (v.warning_area_mm2 - warn).abs() < 0.1 * warn,
        "{}",
        v.warning_area_mm2
    );
    // Inside area: the ellipse section of the liver at x = 2.
    let [a, b, c] = RADII;
    let section = PI * b * c * (1.0 - (2.0 / a).powi(2));
    assert!(
        (v.inside_area_mm2 - section).abs() < 0.02 * section,
        "{}",
        v.inside_area_mm2
    );
    let classes = &p.state("r1").unwrap().margins.class;
    assert!(classes.iter().any(|&c| c as u8 == 0) && classes.iter().any(|&c| c as u8 == 3));
}

#[test]
fn a_patch_whose_edge_is_inside_the_liver_is_an_incomplete_cut() {
    let mut p = planner_with(plane_x("r1", 2.0, 20.0));
    let v = p.volumes().unwrap();
    assert!(!v.complete);
    assert!(!v.resections[0].complete_cut);
    assert_eq!(v.resections[0].resected_ml, None);
    assert_eq!(v.remnant_ml, None);
    // A surface beside the liver misses it altogether.
    let mut q = planner_with(plane_x("r1", 80.0, 70.0));
    assert!(!q.volumes().unwrap().resections[0].complete_cut);
}

#[test]
fn two_resections_add_up_and_the_remnant_warning_fires() {
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x("a", 2.0, 70.0),
    })
    .unwrap();
    // A second cut on the other side, targeting the same tumour (its side is the tumour's).
    let mut b = plane_x("b", -30.0, 70.0);
    b.target = Target::default();
    plan.apply(&PlanEvent::AddResection { resection: b })
        .unwrap();
    let mut p = Planner::new(anatomy(), plan).unwrap();
    let v = p.volumes().unwrap();
    assert!(v.complete);
    // Union = {x > −30} minus the tumour; remnant = {x < −30}.
    let remnant_truth = 4.0 / 3.0 * PI * RADII.iter().product::<Real>() - cap(-30.0);
    let got = v.remnant_ml.unwrap() * 1000.0;
    assert!(
        (got - remnant_truth).abs() < 0.005 * remnant_truth,
        "{got} vs {remnant_truth}"
    );
    assert_eq!(v.flr_warning, Some(true));
}

#[test]
fn undo_redo_and_replay_reproduce_surfaces_classes_and_verdicts() {
    let mut p = planner_with(plane_x("r1", 2.0, 70.0));
    type Snapshot = (Vec<Vec3>, Vec<Real>, Vec<MarginClass>, Verdict);
    let snapshot = |p: &Planner| -> Snapshot {
        let s = p.state("r1").unwrap();
        (
            s.surface.points(),
            s.margins.distance.clone(),
            s.margins.class.clone(),
            s.verdict.clone(),
        )
    };
    // The same surface, classes and refined minimum; distances kept from earlier edits (far
    // from the tumour or outside the liver) within their tolerances of a fresh evaluation's.
    let same = |a: &Snapshot, b: &Snapshot| {
        assert_eq!(a.0, b.0);
        assert_eq!(a.2, b.2);
        for (x, y) in a.1.iter().zip(&b.1) {
            assert!((x - y).abs() <= 2.0 * FAR_TOLERANCE_MM, "{x} vs {y}");
        }
        let (v, w) = (&a.3, &b.3);
        assert!((v.min_margin_mm.unwrap() - w.min_margin_mm.unwrap()).abs() < 1e-9);
        assert!((v.point.unwrap() - w.point.unwrap()).norm() < 1e-6);
        assert_eq!(v.violation, w.violation);
        for (x, y) in [
            (v.violating_area_mm2, w.violating_area_mm2),
            (v.warning_area_mm2, w.warning_area_mm2),
            (v.inside_area_mm2, w.inside_area_mm2),
        ] {
            assert!((x - y).abs() <= 2e-3 * y.max(1.0), "area {x} vs {y}");
        }
    };
    let before = snapshot(&p);
    p.edit(PlanEvent::MoveGroup {
        name: "r1".into(),
        group: Group::Inner,
        delta: [6.0, 0.0, 0.0],
    })
    .unwrap();
    let bent = snapshot(&p);
    assert_ne!(bent.0, before.0);
    // Bending towards the tumour reduces the margin.
    assert!(bent.3.min_margin_mm.unwrap() < before.3.min_margin_mm.unwrap());
    p.edit(PlanEvent::Rotate {
        name: "r1".into(),
        axis: [0.0, 0.0, 1.0],
        angle_deg: 10.0,
        centre: None,
    })
    .unwrap();
    p.undo().unwrap();
    same(&snapshot(&p), &bent);
    p.undo().unwrap();
    same(&snapshot(&p), &before);
    p.redo().unwrap();
    same(&snapshot(&p), &bent);
    // A failing edit changes nothing.
    let held = snapshot(&p);
    let e = p.edit(PlanEvent::SetControlPoint {
        name: "r1".into(),
        i: 1,
        j: 1,
        point: [f64::NAN, 0.0, 0.0],
    });
    assert!(e.is_err());
    assert_eq!(snapshot(&p), held);
    // Replaying the log on a fresh planner gives the same state.
    let replayed =
        resecta_plan::History::replay(p.history().base().clone(), p.history().log()).unwrap();
    let q = Planner::resume(anatomy(), replayed).unwrap();
    same(&snapshot(&q), &bent);
}

#[test]
fn initial_resection_lies_between_tumour_and_end_point() {
    let mut p = Planner::new(anatomy(), Plan::new(spec().roles)).unwrap();
    let end = Vec3::new(-15.0, 0.0, 0.0);
    let (r, init) = p
        .initial_resection("r1", &Target::default(), end, [4, 4])
        .unwrap();
    // Plane x = 5 (midpoint of the tumour centroid x = 25 and x = −15): the liver section is
    // an ellipse with semi-axes 45·√(1 − (5/60)²), 40·√(…); its perimeter-weighted variances
    // make l_i = 4√e_i exceed the section's diameters.
    let s = (1.0 - (5.0f64 / 60.0).powi(2)).sqrt();
    assert!(
        (init.plane_point[0] - 5.0).abs() < 0.2,
        "{:?}",
        init.plane_point
    );
    assert!(init.lengths[0] > 2.0 * 45.0 * s && init.lengths[1] > 2.0 * 40.0 * s);
    assert!(init.lengths[0] < 3.0 * 45.0 * s);
    for q in &r.control_points {
        assert!((q[0] - init.plane_point[0]).abs() < 0.5, "{q:?}");
    }
    p.edit(PlanEvent::AddResection { resection: r }).unwrap();
    let v = p.volumes().unwrap();
    assert!(v.complete, "{v:?}");
    let got = v.resections[0].resected_ml.unwrap() * 1000.0;
    let x0 = init.plane_point[0];
    let truth = cap(x0) - 4.0 / 3.0 * PI * TUMOUR_R.powi(3);
    assert!((got - truth).abs() < 0.01 * truth, "{got} vs {truth}");
    // Bad input: end point at the centroid, or a plane beside the liver.
    let c = p.anatomy().tumours()[0].centroid;
    assert!(matches!(
        p.initial_resection("r2", &Target::default(), c, [4, 4]),
        Err(PlanError::EndPointAtCentroid)
    ));
    assert!(matches!(
        p.initial_resection(
            "r2",
            &Target::default(),
            c + Vec3::new(0.0, 0.0, 200.0),
            [4, 4]
        ),
        Err(PlanError::PlaneMissesLiver)
    ));
}

#[test]
fn slice_projections_of_a_planar_resection_are_lines_on_both_planes() {
    let p = planner_with(plane_x("r1", 2.0, 70.0));
    let mesh = p.state("r1").unwrap().surface.mesh().unwrap();
    let s = slice_projections(
        &mesh,
        &SlicePositions {
            axial: Some(10.0),
            coronal: Some(-5.0),
            sagittal: Some(30.0),
        },
    )
    .unwrap();
    assert_eq!(s.axial.len(), 1);
    assert_eq!(s.coronal.len(), 1);
    assert!(s.sagittal.is_empty(), "the plane x = 2 never meets x = 30");
    for q in &s.axial[0].points {
        assert!((q.z - 10.0).abs() < 1e-9 && (q.x - 2.0).abs() < 1e-9);
    }
    let len: Real = s.coronal[0].length();
    assert!((len - 140.0).abs() < 1e-6, "{len}");
}

#[test]
fn bad_anatomy_and_targets_are_refused() {
    let mut p = generate(&spec()).unwrap();
    let roles = spec().roles;
    let tumour = roles.labels(Role::Tumor)[0];
    // A tumour blob away from the liver.
    let dims = p.labels.grid().dims();
    for k in 0..3 {
        for j in 0..3 {
            for i in 0..3 {
                p.labels.set([i + 1, j + 1, k + 1], tumour);
            }
        }
    }
    assert!(dims[0] > 5);
    assert!(matches!(
        Anatomy::new(&p.labels, &roles),
        Err(PlanError::TumourOutsideLiver(_))
    ));
    // A role map whose tumour label is absent.
    let q = generate(&spec()).unwrap();
    let mut json = serde_json::to_value(&roles).unwrap();
    json["tumor"] = serde_json::json!([9]);
    let absent: RoleMap = serde_json::from_value(json).unwrap();
    let a = Arc::new(Anatomy::new(&q.labels, &absent).unwrap());
    let mut planner = Planner::new(a, Plan::new(absent)).unwrap();
    assert!(matches!(
        planner.initial_resection("r", &Target::default(), Vec3::zeros(), [4, 4]),
        Err(PlanError::LabelAbsent(9))
    ));
}

#[test]
fn margin_surfaces_are_the_tumour_voxels() {
    // The small phantom (an 8 mm tumour on 2×2×3 mm voxels) and the large tumour of the test
    // phantom: the margin surface encloses exactly the tumour's voxels.
    let s = PhantomSpec::small();
    let p = generate(&s).unwrap();
    let small = Anatomy::new(&p.labels, &s.roles).unwrap();
    for t in [&small.tumours()[0], &anatomy().tumours()[0]] {
        let v = t.mesh.enclosed_volume();
        assert!(
            (v - t.volume_mm3).abs() < 1e-9 * t.volume_mm3,
            "{v} vs {}",
            t.volume_mm3
        );
    }
}

#[test]
fn the_targets_are_the_reconstructions_tumour_models_specks_left_out() {
    // Two tumours, one-voxel tumour specks (1.3 mm³) inside and outside the liver: neither speck
    // is a target (the one outside would otherwise refuse the anatomy) nor gets a model.
    let mut s = spec();
    s.tumors.push(SphereSpec {
        center: [-30.0, 5.0, 0.0],
        radius: 6.0,
    });
    let mut labels = generate(&s).unwrap().labels;
    for p in [[0.0, 30.0, 0.0], [64.0, 0.0, 0.0]] {
        let c = labels
            .grid()
            .world_to_index(Vec3::from(p))
            .map(|c| c.round() as usize);
        assert!(labels.set([c.x, c.y, c.z], 2));
    }
    let a = Anatomy::new(&labels, &s.roles).unwrap();
    let options = resecta_recon::ModelOptions {
        parenchyma: resecta_recon::ParenchymaMethod::Mcsd,
        ..Default::default()
    };
    let built = resecta_recon::patient_models(&labels, &s.roles, &options, &mut |_| true).unwrap();
    let models: Vec<_> = built
        .models
        .iter()
        .filter(|m| m.role == Role::Tumor)
        .map(|m| (m.label, m.voxels))
        .collect();
    let targets: Vec<_> = a
        .tumours()
        .iter()
        .map(|t| (Some(t.label), t.voxels))
        .collect();
    assert_eq!(models.len(), 2);
    assert_eq!(models, targets);
    assert_eq!(built.dropped.len(), 1);
    assert_eq!(
        (built.dropped[0].role, built.dropped[0].components),
        (Role::Tumor, 2)
    );
}

#[test]
fn a_cancelled_set_up_stops_and_an_uncancelled_one_matches_its_stages_run_alone() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let p = generate(&spec()).unwrap();
    let roles = RoleMap::default();
    // Cancelled at the first check: nothing is built.
    let asked = AtomicUsize::new(0);
    let stopped = Anatomy::new_cancellable(&p.labels, &roles, &|| {
        asked.fetch_add(1, Ordering::Relaxed);
        true
    });
    assert!(matches!(
        stopped,
        Err(PlanError::Recon(resecta_recon::ReconError::Cancelled))
    ));
    assert_eq!(asked.load(Ordering::Relaxed), 1);
    // Cancelled half-way (after some checks passed): also stopped.
    let asked = AtomicUsize::new(0);
    let stopped = Anatomy::new_cancellable(&p.labels, &roles, &|| {
        asked.fetch_add(1, Ordering::Relaxed) >= 2
    });
    assert!(matches!(
        stopped,
        Err(PlanError::Recon(resecta_recon::ReconError::Cancelled))
    ));
    // Not cancelled: the stages run side by side give what each gives run alone.
    let a = Anatomy::new_cancellable(&p.labels, &roles, &|| false).unwrap();
    let envelope = resecta_recon::mask::liver_envelope(&p.labels, &roles).unwrap();
    assert_eq!(a.envelope().data(), envelope.data());
    let surface =
        resecta_recon::mcsd::reconstruct(&envelope, &resecta_recon::McsdParams::default()).unwrap();
    assert_eq!(a.parenchyma().vertices(), surface.vertices());
    assert_eq!(a.parenchyma().triangles(), surface.triangles());
}

#[test]
fn volumes_on_the_voxels_indexed_with_the_anatomy_equal_those_indexed_afresh() {
    let p = generate(&spec()).unwrap();
    let a = Arc::new(Anatomy::new(&p.labels, &spec().roles).unwrap());
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x("r1", 2.0, 70.0),
    })
    .unwrap();
    // The first planner's engine takes the anatomy's indexed voxels; the second indexes anew.
    let mut first = Planner::new(Arc::clone(&a), plan.clone()).unwrap();
    let prebuilt = first.volumes().unwrap();
    assert!(a.take_liver_voxels().is_none());
    let afresh = Planner::new(a, plan).unwrap().volumes().unwrap();
    assert_eq!(format!("{prebuilt:?}"), format!("{afresh:?}"));
    assert!(prebuilt.resections[0].resected_ml.unwrap() > 0.0);
}

/// A CPU evaluator that reports a device failure on its `fail_at`-th evaluation and counts
/// the single-point updates it is handed.
#[derive(Debug)]
struct Flaky {
    inner: resecta_bezier::MleEvaluator<f64>,
    evaluations: usize,
    fail_at: usize,
    single: Arc<std::sync::atomic::AtomicUsize>,
}

impl resecta_bezier::SurfaceEvaluator for Flaky {
    fn backend(&self) -> &'static str {
        "flaky"
    }
    fn net(&self) -> &resecta_bezier::ControlNet<f64> {
        self.inner.net()
    }
    fn resolution(&self) -> resecta_bezier::Resolution {
        self.inner.resolution()
    }
    fn set_net(&mut self, net: resecta_bezier::ControlNet<f64>) {
        self.inner.set_net(net);
    }
    fn set_control_points(&mut self, p: &[[f64; 3]]) -> Result<(), resecta_bezier::BezierError> {
        self.inner.set_control_points(p)
    }
    fn set_control_point(
        &mut self,
        i: usize,
        j: usize,
        p: [f64; 3],
    ) -> Result<(), resecta_bezier::BezierError> {
        self.single
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.inner.set_control_point(i, j, p)
    }
    fn set_resolution(&mut self, r: resecta_bezier::Resolution) {
        self.inner.set_resolution(r);
    }
    fn evaluate_into(
        &mut self,
        grid: &mut resecta_bezier::SurfaceGrid<f64>,
    ) -> Result<(), resecta_bezier::BezierError> {
        self.evaluations += 1;
        if self.evaluations == self.fail_at {
            return Err(resecta_bezier::BezierError::Device("lost".into()));
        }
        self.inner.evaluate_into(grid)
    }
}

#[test]
fn a_device_failure_moves_the_surface_to_the_cpu_and_the_edit_succeeds() {
    use resecta_bezier::SurfaceEngine;
    let single = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let s = Arc::clone(&single);
    let engine = SurfaceEngine::new("flaky", move |net, res| {
        Ok(Box::new(Flaky {
            inner: resecta_bezier::MleEvaluator::new(net, res),
            evaluations: 0,
            fail_at: 3,
            single: Arc::clone(&s),
        }))
    });
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x("r1", 12.0, 70.0),
    })
    .unwrap();
    let mut flaky = Planner::with_engine(anatomy(), plan.clone(), engine).unwrap();
    let mut cpu = Planner::new(anatomy(), plan).unwrap();
    assert_eq!(flaky.compute_engine().backend(), "flaky");
    for step in 0..3 {
        let edit = PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 1,
            j: 2,
            point: [14.0 + step as Real, -23.0, 23.0],
        };
        flaky.edit(edit.clone()).unwrap();
        cpu.edit(edit).unwrap();
        let (f, c) = (flaky.state("r1").unwrap(), cpu.state("r1").unwrap());
        // Evaluation 3 (the second edit) fails: from then on the CPU evaluates.
        let (backend, fallbacks) = if step == 0 { ("flaky", 0) } else { ("cpu", 1) };
        assert_eq!(f.surface.backend(), backend, "step {step}");
        assert_eq!(f.surface.device_fallbacks(), fallbacks, "step {step}");
        assert_eq!(f.surface.grid(), c.surface.grid(), "step {step}");
        assert_eq!(f.margins.class, c.margins.class);
        assert_eq!(f.verdict, c.verdict);
    }
    let err = flaky.state("r1").unwrap().surface.device_error().unwrap();
    assert!(err.is_device(), "{err}");
    // The planner moved to the CPU: its next surfaces are made there.
    assert_eq!(flaky.device_fallbacks(), 1);
    assert_eq!(flaky.compute_engine().backend(), "cpu");
    // One moved point is handed over as one point (the first two edits reach the flaky one).
    assert_eq!(single.load(std::sync::atomic::Ordering::Relaxed), 2);
}

#[test]
fn an_engine_that_cannot_make_an_evaluator_for_its_device_leaves_the_cpu_to_it() {
    let engine = resecta_bezier::SurfaceEngine::new("gone", |_, _| {
        Err(resecta_bezier::BezierError::Device("no adapter".into()))
    });
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x("r1", 12.0, 70.0),
    })
    .unwrap();
    let p = Planner::with_engine(anatomy(), plan, engine).unwrap();
    let s = &p.state("r1").unwrap().surface;
    assert_eq!((s.backend(), s.device_fallbacks()), ("cpu", 1));
    assert_eq!(p.device_fallbacks(), 1);
    assert_eq!(s.points().len(), 40 * 40);
}

/// A probe measuring exactly on the CPU (the contract a device probe meets), failing as a lost
/// device at its `fail_at`-th measurement.
#[derive(Debug)]
struct ExactProbe {
    anatomy: Arc<Anatomy>,
    target: Arc<resecta_plan::TargetModel>,
    measured: usize,
    fail_at: usize,
}

impl resecta_plan::SampleProbe for ExactProbe {
    fn measure(
        &mut self,
        surface: &mut dyn resecta_bezier::SurfaceEvaluator,
        grid: &mut resecta_bezier::SurfaceGrid<f64>,
        inside: &mut Vec<f64>,
        distance: &mut Vec<f64>,
    ) -> Result<(), resecta_bezier::BezierError> {
        self.measured += 1;
        if self.measured == self.fail_at {
            return Err(resecta_bezier::BezierError::Device("lost".into()));
        }
        surface.evaluate_into(grid)?;
        let points: Vec<Vec3> = grid.points().iter().map(|p| Vec3::from(*p)).collect();
        *inside = points
            .iter()
            .map(|p| self.anatomy.inside_level(p))
            .collect();
        *distance = points
            .iter()
            .map(|p| self.target.field.nearest(p).distance)
            .collect();
        Ok(())
    }
}

#[test]
fn a_probe_measures_the_samples_and_its_device_failure_leaves_them_to_the_cpu() {
    let probes = resecta_plan::ProbeEngine::new("exact", |anatomy, target| {
        Ok(Box::new(ExactProbe {
            anatomy: Arc::clone(anatomy),
            target: Arc::clone(target),
            measured: 0,
            fail_at: 3,
        }))
    });
    let engine = resecta_plan::ComputeEngine {
        surfaces: resecta_bezier::SurfaceEngine::cpu(),
        probes: Some(probes),
        volumetry: None,
        host_bytes_per_sample: 0,
        host_bytes_per_voxel: 0,
    };
    let mut plan = Plan::new(spec().roles);
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x("r1", 12.0, 70.0),
    })
    .unwrap();
    let mut probed = Planner::with_engine(anatomy(), plan.clone(), engine).unwrap();
    let mut cpu = Planner::new(anatomy(), plan).unwrap();
    for step in 0..3 {
        let edit = PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 1,
            j: 2,
            point: [9.0 + step as Real, -23.0, 23.0],
        };
        probed.edit(edit.clone()).unwrap();
        cpu.edit(edit).unwrap();
        let (p, c) = (probed.state("r1").unwrap(), cpu.state("r1").unwrap());
        assert_eq!(p.surface.grid(), c.surface.grid(), "step {step}");
        assert_eq!(p.inside, c.inside, "step {step}");
        assert_eq!(p.margins.class, c.margins.class, "step {step}");
        let (pm, cm) = (p.verdict.min_margin_mm, c.verdict.min_margin_mm);
        assert_eq!(pm, cm, "step {step}");
        // Exact distances against the CPU's tolerant (and, through a drag, kept) ones.
        for (a, b) in p.margins.distance.iter().zip(&c.margins.distance) {
            assert!((a - b).abs() <= FAR_TOLERANCE_MM, "step {step}: {a} vs {b}");
        }
        // Measurement 3 (the second edit) fails: from then on the CPU measures.
        assert_eq!(
            probed.device_fallbacks(),
            u32::from(step > 0),
            "step {step}"
        );
    }
    assert!(probed.compute_engine().probes.is_none());
    assert!(
        probed
            .state("r1")
            .unwrap()
            .surface
            .device_error()
            .unwrap()
            .is_device()
    );
}

#[test]
fn metrics_of_a_plane_and_a_parabolic_cylinder() {
    use resecta_plan::{resection_metrics, volume_deviation_pct};
    // A plane: flat; its margin deviation is the verdict's minimum less the margin, whose exact
    // value is the plane's distance to the tumour sphere (to the voxel boundary: within a voxel).
    let p = planner_with(plane_x("r1", 12.0, 70.0));
    let (s, r) = (p.state("r1").unwrap(), &p.plan().resections[0]);
    let m = resection_metrics(s, r.margin_mm);
    assert!(m.median_abs_mean_curvature_per_mm.unwrap() < 1e-12);
    let exact = (TUMOUR[0] - TUMOUR_R - 12.0).abs() - r.margin_mm;
    let dev = m.margin_deviation_mm.unwrap();
    assert!((dev - exact).abs() <= 1.0, "{dev} vs {exact}");
    assert_eq!(m.volume_deviation_pct, None);
    assert_eq!(volume_deviation_pct(Some(200.0), Some(160.0)), Some(25.0));
    assert_eq!(volume_deviation_pct(Some(1.0), None), None);
    // x = 12 + a·y² (quadratic in u along y, linear in v along z): H = a / (1 + 4a²y²)^{3/2},
    // between a/1.03 and a over |y| ≤ 70 mm.
    let a = 1e-3;
    let pts = (0..6)
        .map(|k| {
            let (i, j) = (k / 2, k % 2);
            let y = -70.0 + 70.0 * i as Real;
            let x = 12.0 + if i == 1 { -a * 4900.0 } else { a * 4900.0 };
            [x, y, -70.0 + 140.0 * j as Real]
        })
        .collect();
    let p = planner_with(Resection::new("r1", [3, 2], pts));
    let s = p.state("r1").unwrap();
    let h = resection_metrics(s, 10.0)
        .median_abs_mean_curvature_per_mm
        .unwrap();
    assert!(h <= a * (1.0 + 1e-9) && h >= a / 1.03, "{h}");
}
