//! One control-point edit → new surface, per-vertex margins, inside flags and the global verdict
//! (the live path), at 40×40 and 200×200; and volumetry per edit on a 512×512×300 label map.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_geom::{Real, RoleMap};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::{Anatomy, Plan, PlanEvent, Planner, Resection};

fn spec(dims: [usize; 3], spacing: [Real; 3]) -> PhantomSpec {
    PhantomSpec {
        grid: GridSpec::centred(dims, spacing, [0.0; 3], Orientation::default()),
        liver: vec![
            EllipsoidSpec {
                center: [0.0, 0.0, 0.0],
                radii: [95.0, 75.0, 65.0],
                rotation: Orientation::EulerDeg([0.0, 0.0, 15.0]),
            },
            EllipsoidSpec {
                center: [-60.0, 20.0, 10.0],
                radii: [60.0, 50.0, 45.0],
                rotation: Orientation::default(),
            },
        ],
        tumors: vec![SphereSpec {
            center: [35.0, 10.0, 5.0],
            radius: 15.0,
        }],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.5,
    }
}

fn planar(res: usize) -> Resection {
    let pts = (0..16)
        .map(|k| {
            let (i, j) = ((k / 4) as Real / 3.0, (k % 4) as Real / 3.0);
            [5.0, -120.0 + 240.0 * i, -110.0 + 220.0 * j]
        })
        .collect();
    let mut r = Resection::new("r1", [4, 4], pts);
    r.resolution = [res, res];
    r
}

fn planner(s: &PhantomSpec, res: usize) -> Planner {
    let p = generate(s).unwrap();
    let anatomy = Arc::new(Anatomy::new(&p.labels, &s.roles).unwrap());
    let mut plan = Plan::new(s.roles.clone());
    plan.apply(&PlanEvent::AddResection {
        resection: planar(res),
    })
    .unwrap();
    Planner::new(anatomy, plan).unwrap()
}

fn edit(k: u64) -> PlanEvent {
    // Drag an inner control point back and forth, as a surgeon does.
    let dx = if k.is_multiple_of(2) { 8.0 } else { 5.0 };
    PlanEvent::SetControlPoint {
        name: "r1".into(),
        i: 1,
        j: 2,
        point: [dx, -40.0, 36.7],
    }
}

fn live_edit(c: &mut Criterion) {
    let s = spec([256, 256, 150], [1.5, 1.5, 2.0]);
    for res in [40usize, 200] {
        let mut p = planner(&s, res);
        let mut k = 0u64;
        c.bench_function(&format!("edit_{res}x{res}"), |b| {
            b.iter(|| {
                k += 1;
                p.edit(edit(k)).unwrap();
            })
        });
    }
}

fn volumetry(c: &mut Criterion) {
    let s = spec([512, 512, 300], [0.75, 0.75, 1.0]);
    let mut p = planner(&s, 40);
    p.volumes().unwrap(); // one-time set-up
    let mut k = 0u64;
    let mut g = c.benchmark_group("volumetry_512x512x300");
    g.sample_size(20);
    g.bench_function("edit_then_volumes", |b| {
        b.iter(|| {
            k += 1;
            p.edit(edit(k)).unwrap();
            p.volumes().unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, live_edit, volumetry);
criterion_main!(benches);
