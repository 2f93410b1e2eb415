//! Vascular territories, risk analysis and the resectogram on a 512×512×300 label map with a
//! branching portal tree and three hepatic veins, each beside its anchor in the same run:
//! the anatomy without vessel trees, the volumes without risk analysis, the edit without a
//! resectogram.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_geom::{Real, Role, RoleMap, Volume};
use resecta_phantom::{PhantomSpec, VesselSpec, generate};
use resecta_plan::{Anatomy, Plan, PlanEvent, Planner};

mod common;
use common::{edit, planar, spec_with_tumour};
use resecta_vessels::{BranchSelection, RootChoice, TerritoryParams, VesselParams};

fn tube(role: Role, radius: Real, points: &[[Real; 3]]) -> VesselSpec {
    VesselSpec {
        role,
        radius,
        points: points.to_vec(),
    }
}

/// A liver of two ellipsoids on 512×512×300 voxels of 0.75×0.75×1 mm, a tumour, a portal tree
/// (trunk, two lobar, four segmental branches) and three hepatic veins, each widening at its
/// own ostium.
fn spec() -> PhantomSpec {
    let p = Role::Portal;
    let h = Role::Hepatic;
    let hilum = [-10.0, -20.0, -40.0];
    let (right, left) = ([30.0, -10.0, -20.0], [-45.0, 0.0, -25.0]);
    PhantomSpec {
        vessels: vec![
            tube(p, 7.0, &[[-10.0, -30.0, -80.0], hilum]),
            tube(p, 5.0, &[hilum, right]),
            tube(p, 5.0, &[hilum, left]),
            tube(p, 3.5, &[right, [75.0, -20.0, -10.0]]),
            tube(p, 3.5, &[right, [40.0, 30.0, 30.0]]),
            tube(p, 3.5, &[left, [-90.0, 10.0, -10.0]]),
            tube(p, 3.5, &[left, [-50.0, 45.0, 25.0]]),
            // Each hepatic vein widens at its own ostium (the tree's root).
            tube(h, 6.5, &[[10.0, 20.0, 72.0], [14.0, 18.0, 62.0]]),
            tube(h, 4.5, &[[14.0, 18.0, 62.0], [60.0, 0.0, 20.0]]),
            tube(h, 6.0, &[[-10.0, 22.0, 72.0], [-10.0, 16.0, 62.0]]),
            tube(h, 4.0, &[[-10.0, 16.0, 62.0], [-5.0, -20.0, 15.0]]),
            tube(h, 6.0, &[[-30.0, 20.0, 72.0], [-36.0, 21.0, 62.0]]),
            tube(h, 4.0, &[[-36.0, 21.0, 62.0], [-80.0, 25.0, 25.0]]),
        ],
        ..spec_with_tumour([512, 512, 300], [0.75, 0.75, 1.0], 15.0)
    }
}

fn planner(anatomy: &Arc<Anatomy>, roles: &RoleMap) -> Planner {
    let mut plan = Plan::new(roles.clone());
    plan.apply(&PlanEvent::AddResection {
        resection: planar(40),
    })
    .unwrap();
    Planner::new(Arc::clone(anatomy), plan).unwrap()
}

fn risk(c: &mut Criterion) {
    let s = spec();
    let labels = generate(&s).unwrap().labels;
    // The anchor's roles count the vessel labels as parenchyma: the same functional liver,
    // no trees.
    let plain: RoleMap =
        serde_json::from_str(r#"{"parenchyma":[1,3,4],"tumor":[2]}"#).expect("roles");
    let with = Arc::new(Anatomy::new(&labels, &s.roles).unwrap());
    let without = Arc::new(Anatomy::new(&labels, &plain).unwrap());

    let mut g = c.benchmark_group("risk_512x512x300");
    g.sample_size(10);
    g.bench_function("anatomy_without_trees", |b| {
        b.iter(|| Anatomy::new(&labels, &plain).unwrap())
    });
    g.bench_function("anatomy_with_trees", |b| {
        b.iter(|| Anatomy::new(&labels, &s.roles).unwrap())
    });
    let portal: Volume<bool> = Volume::from_vec(
        labels.grid().clone(),
        labels.data().iter().map(|&l| l == 3).collect(),
    )
    .unwrap();
    let liver = with.functional().clone();
    g.bench_function("territories_portal_order_2", |b| {
        b.iter(|| {
            let tree =
                resecta_vessels::vessel_tree(&portal, RootChoice::Auto, &VesselParams::default())
                    .unwrap();
            resecta_vessels::territories(
                &tree,
                &liver,
                &BranchSelection::Generation(2),
                &TerritoryParams::default(),
            )
            .unwrap()
        })
    });
    g.finish();

    // Per pause: volumes after an edit, without and with the risk analysis.
    let mut g = c.benchmark_group("risk_pause_512x512x300");
    g.sample_size(20);
    for (name, anatomy, roles) in [
        ("volumes_without_risk", &without, &plain),
        ("volumes_with_risk", &with, &s.roles),
    ] {
        let mut p = planner(anatomy, roles);
        let v = p.volumes().unwrap(); // one-time set-up
        if let Some(r) = &v.risk {
            let roots: Vec<usize> = anatomy
                .vascular()
                .model()
                .map(|m| m.trees().map(|(_, t)| t.roots.len()).collect())
                .unwrap_or_default();
            eprintln!(
                "risk: roots per system {roots:?}, {} cut, remnant {:.1} ml, devascularised \
                 {:.1} ml, congested {:.1} ml",
                r.cut_vessels.len(),
                v.remnant_ml.unwrap_or(0.0),
                r.devascularised_ml,
                r.congested_ml
            );
        }
        let mut k = 0u64;
        g.bench_function(name, |b| {
            b.iter(|| {
                k += 1;
                p.edit(edit(k)).unwrap();
                p.volumes().unwrap()
            })
        });
    }
    g.finish();

    // Per edit: the live path alone, and with the 200×200 resectogram.
    let mut g = c.benchmark_group("resectogram_200x200");
    let mut p = planner(&with, &s.roles);
    let mut k = 0u64;
    g.bench_function("edit", |b| {
        b.iter(|| {
            k += 1;
            p.edit(edit(k)).unwrap();
        })
    });
    g.bench_function("edit_then_resectogram", |b| {
        b.iter(|| {
            k += 1;
            p.edit(edit(k)).unwrap();
            p.resectogram("r1", 200, 200).unwrap()
        })
    });
    g.bench_function("resectogram_alone", |b| {
        b.iter(|| p.resectogram("r1", 200, 200).unwrap())
    });
    g.finish();
}

criterion_group!(benches, risk);
criterion_main!(benches);
