//! One control-point edit → new surface, per-vertex margins, inside flags and the global verdict
//! (the live path), at 40×40 and 200×200, also with a large tumour (~177 k voxels); volumetry
//! per edit on a 512×512×300 label map; and one edit of each method of Paper II (Bézier control
//! point, DS trace redrawn, CP deformation) side by side.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_geom::Real;
use resecta_phantom::{PhantomSpec, generate};
use resecta_plan::{Anatomy, Deformation, Plan, PlanEvent, Planner, Resection};

mod common;
use common::{edit, planar, spec_with_tumour};

fn spec(dims: [usize; 3], spacing: [Real; 3]) -> PhantomSpec {
    spec_with_tumour(dims, spacing, 15.0)
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

/// The live path with a large tumour: radius 28 mm on a CT grid of 0.57×0.57×1.6 mm (~177 k
/// voxels), 2 mm from the cut; margins measured to its voxel boundary.
fn live_edit_large_tumour(c: &mut Criterion) {
    let s = spec_with_tumour([512, 512, 130], [0.57, 0.57, 1.6], 28.0);
    let p = generate(&s).unwrap();
    let anatomy = Arc::new(Anatomy::new(&p.labels, &s.roles).unwrap());
    let t = &anatomy.tumours()[0];
    eprintln!(
        "large tumour: {} voxels, margin surface {} triangles",
        t.voxels,
        t.mesh.triangles().len()
    );
    for res in [40usize, 200] {
        let mut plan = Plan::new(s.roles.clone());
        plan.apply(&PlanEvent::AddResection {
            resection: planar(res),
        })
        .unwrap();
        let mut p = Planner::new(Arc::clone(&anatomy), plan).unwrap();
        let mut k = 0u64;
        c.bench_function(&format!("edit_{res}x{res}_large_tumour"), |b| {
            b.iter(|| {
                k += 1;
                p.edit(edit(k)).unwrap();
            })
        });
    }
}

/// The plane x = 5 as DS traces on five axial slices spanning the liver, redrawn with a bulge.
fn ds_trace(z: Real, bulge: Real) -> Vec<[Real; 3]> {
    (0..=24)
        .map(|k| {
            let y = -120.0 + 10.0 * Real::from(k);
            [5.0 + bulge * (1.0 - (y / 120.0).powi(2)), y, z]
        })
        .collect()
}

/// The plane x = 5 as a CP ring around the liver.
fn cp_ring() -> Vec<[Real; 3]> {
    (0..=48)
        .map(|k| {
            let t = std::f64::consts::TAU * Real::from(k) / 48.0;
            [5.0, 110.0 * t.cos(), 100.0 * t.sin()]
        })
        .collect()
}

/// One edit of each method on the same liver, each redoing its surface, margins and verdict:
/// Bézier moves a control point (40×40 samples), DS redraws a trace (40×40 samples of the
/// bi-quadratic surface), CP adds or takes back a 30 mm deformation (its 31×n grid).
fn methods_edit(c: &mut Criterion) {
    let s = spec([256, 256, 150], [1.5, 1.5, 2.0]);
    let p = generate(&s).unwrap();
    let anatomy = Arc::new(Anatomy::new(&p.labels, &s.roles).unwrap());
    let ds = Resection::ds(
        "r1",
        [-110.0, -55.0, 0.0, 55.0, 110.0]
            .iter()
            .map(|&z| ds_trace(z, 0.0))
            .collect(),
    );
    let cp = Resection::cp("r1", vec![cp_ring()], Vec::new());
    let mut g = c.benchmark_group("methods_edit");
    for r in [planar(40), ds, cp] {
        let kind = r.kind;
        let mut plan = Plan::new(s.roles.clone());
        plan.apply(&PlanEvent::AddResection { resection: r })
            .unwrap();
        let mut p = Planner::new(Arc::clone(&anatomy), plan).unwrap();
        let mut k = 0u64;
        g.bench_function(format!("{kind:?}").to_lowercase(), |b| {
            b.iter(|| {
                k += 1;
                let e = match kind {
                    resecta_plan::ResectionKind::Bezier => edit(k),
                    resecta_plan::ResectionKind::Ds => PlanEvent::SetTrace {
                        name: "r1".into(),
                        index: 2,
                        trace: ds_trace(0.0, if k.is_multiple_of(2) { 6.0 } else { 3.0 }),
                    },
                    resecta_plan::ResectionKind::Cp if !k.is_multiple_of(2) => {
                        PlanEvent::AddDeformation {
                            name: "r1".into(),
                            deformation: Deformation {
                                point: [5.0, 10.0, 5.0],
                                offset_mm: 4.0,
                                radius_mm: 30.0,
                            },
                        }
                    }
                    resecta_plan::ResectionKind::Cp => {
                        PlanEvent::UndoDeformation { name: "r1".into() }
                    }
                };
                p.edit(e).unwrap();
            })
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    live_edit,
    live_edit_large_tumour,
    volumetry,
    methods_edit
);
criterion_main!(benches);
