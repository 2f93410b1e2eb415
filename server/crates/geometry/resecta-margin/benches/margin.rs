//! Distances from resection-surface samples (5–80 mm away) to tumours of 1.3–20 k triangles:
//! hinted batch queries against plain BVH queries, and the whole evaluation (margins + classes
//! + verdict).
#![allow(clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_bezier::{ControlNet, MleEvaluator, Outputs, Resolution, eval_point};
use resecta_geom::primitives::icosphere;
use resecta_geom::{MeshBvh, Real, Vec3};
use resecta_margin::{MarginField, MarginSettings, SurfaceOracle, evaluate};

struct Surf(ControlNet<Real>);

impl SurfaceOracle for Surf {
    fn point(&self, u: Real, v: Real) -> Vec3 {
        let p = eval_point(&self.0, u, v).point;
        Vec3::new(p[0], p[1], p[2])
    }
    fn inside(&self, p: &Vec3) -> Real {
        90.0 - p.norm()
    }
}

fn surface() -> Surf {
    // A gently bent 4×4 net 5–40 mm from the tumour.
    Surf(
        ControlNet::from_fn(4, 4, |i, j| {
            let (s, t) = (i as Real / 3.0 - 0.5, j as Real / 3.0 - 0.5);
            [-5.0 - 30.0 * (s * s + t * t), 160.0 * s, 160.0 * t]
        })
        .unwrap(),
    )
}

fn bench(c: &mut Criterion) {
    // Tumours of 1 280, 5 120 and 20 480 triangles (radius 15 mm).
    for level in [3u32, 4, 5] {
        let tumour = icosphere(Vec3::new(20.0, 5.0, 0.0), 15.0, level).unwrap();
        run(c, &tumour, &format!("{}tri", tumour.triangles().len()));
    }
}

fn run(c: &mut Criterion, tumour: &resecta_geom::TriMesh, tag: &str) {
    let field = MarginField::new(tumour).unwrap();
    let bvh = MeshBvh::new(tumour).unwrap();
    let surf = surface();
    for res in [40usize, 200] {
        let mut e = MleEvaluator::new(surf.0.clone(), Resolution::new(res, res).unwrap());
        let pts: Vec<Vec3> = e
            .evaluate(Outputs::Points)
            .points()
            .iter()
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let inside: Vec<Real> = pts.iter().map(|p| surf.inside(p)).collect();
        let mut out = vec![field.nearest(&pts[0]); pts.len()];
        c.bench_function(&format!("field_nearest_{res}x{res}_{tag}"), |b| {
            b.iter(|| field.nearest_into(&pts, &mut out).unwrap())
        });
        c.bench_function(&format!("bvh_closest_{res}x{res}_{tag}"), |b| {
            b.iter(|| bvh.closest_points(&pts))
        });
        let s = MarginSettings {
            margin_mm: 10.0,
            band_mm: 5.0,
        };
        c.bench_function(&format!("evaluate_{res}x{res}_{tag}"), |b| {
            b.iter(|| evaluate(&field, res, res, &pts, &inside, &s, &surf).unwrap())
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
