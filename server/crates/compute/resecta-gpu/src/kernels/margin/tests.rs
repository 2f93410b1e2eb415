//! GPU vs CPU (`MarginField::distances_into`, `distances_grid_into`, `MarginSettings::classify`)
//! on the test device (lavapipe in CI).

use resecta_geom::primitives::icosphere;
use resecta_geom::{RoleMap, TriMesh, Vec3};
use resecta_margin::{MarginClass, MarginField, MarginSettings};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::Anatomy;

use super::GpuMarginField;
use crate::device::testing::context;
use crate::device::{GpuContext, GpuError};
use crate::kernels::bezier::tests::Rng;

/// GPU and CPU distances agree to this (mm): rounding only.
const EXACT_MM: f64 = 1e-9;

fn point(rng: &mut Rng, lo: &Vec3, hi: &Vec3) -> Vec3 {
    Vec3::from_fn(|a, _| lo[a] + (hi[a] - lo[a]) * rng.unit())
}

fn direction(rng: &mut Rng) -> Vec3 {
    loop {
        let v = point(rng, &Vec3::repeat(-1.0), &Vec3::repeat(1.0));
        if v.norm() > 0.1 && v.norm() <= 1.0 {
            return v.normalize();
        }
    }
}

/// Largest |GPU − CPU| over the points, asserting NaN exactly where the CPU has NaN.
fn max_diff(gpu: &[f64], cpu: &[f64]) -> f64 {
    assert_eq!(gpu.len(), cpu.len());
    let mut worst = 0.0f64;
    for (k, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert_eq!(g.is_nan(), c.is_nan(), "point {k}: gpu {g}, cpu {c}");
        if !c.is_nan() {
            worst = worst.max((g - c).abs());
        }
    }
    worst
}

/// Distances of `points` on the GPU and by `MarginField::distances_into`, compared.
fn compare(ctx: &GpuContext, field: &MarginField, points: &[Vec3], what: &str) -> Vec<f64> {
    let mut gpu_field = GpuMarginField::new(ctx, field).unwrap();
    let mut gpu = vec![0.0; points.len()];
    gpu_field.distances_into(points, &mut gpu).unwrap();
    let mut cpu = vec![0.0; points.len()];
    field.distances_into(points, &mut cpu).unwrap();
    let d = max_diff(&gpu, &cpu);
    eprintln!(
        "{what}: {} points, max |gpu - cpu| = {d:.3e} mm",
        points.len()
    );
    assert!(d <= EXACT_MM, "{what}: max |gpu - cpu| = {d:e} mm");
    gpu
}

/// A liver ellipsoid with two spherical tumours on an oblique anisotropic grid, and the
/// planner's margin field of both tumours (their voxel boundaries).
fn phantom() -> (Anatomy, std::sync::Arc<resecta_plan::TargetModel>) {
    let spec = PhantomSpec {
        grid: GridSpec::centred(
            [48, 40, 26],
            [2.0, 1.7, 3.0],
            [1.0, -2.0, 3.0],
            Orientation::EulerDeg([3.0, -2.0, 6.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.0, 0.0, 0.0],
            radii: [40.0, 30.0, 25.0],
            rotation: Orientation::EulerDeg([0.0, 0.0, 20.0]),
        }],
        tumors: vec![
            SphereSpec {
                center: [10.0, 5.0, 0.0],
                radius: 8.0,
            },
            SphereSpec {
                center: [-18.0, -6.0, 4.0],
                radius: 5.0,
            },
        ],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    };
    let p = generate(&spec).unwrap();
    let anatomy = Anatomy::new(&p.labels, &spec.roles).unwrap();
    let all: Vec<usize> = (0..anatomy.tumours().len()).collect();
    assert_eq!(all.len(), 2);
    let target = anatomy.target(&all).unwrap();
    (anatomy, target)
}

/// Points on (vertices, centroids), near, inside and far from `mesh`, beyond the tree's reach,
/// and non-finite.
fn probe_points(rng: &mut Rng, mesh: &TriMesh, field: &MarginField) -> Vec<Vec3> {
    let (lo, hi) = mesh.bounds().unwrap();
    let mut pts: Vec<Vec3> = mesh.vertices().iter().step_by(7).copied().collect();
    pts.extend(
        (0..mesh.triangles().len())
            .step_by(5)
            .map(|t| mesh.corners(t).iter().sum::<Vec3>() / 3.0),
    );
    // Near the surface: a vertex moved up to 2 mm in any direction (inside or outside).
    for _ in 0..500 {
        let v = mesh.vertices()[rng.range(0, mesh.vertices().len() - 1)];
        pts.push(v + direction(rng) * 2.0 * rng.unit());
    }
    // Inside and around the tumours' box, and over the whole region.
    let pad = Vec3::repeat(3.0);
    pts.extend((0..500).map(|_| point(rng, &(lo - pad), &(hi + pad))));
    let (rlo, rhi) = field.region();
    pts.extend((0..500).map(|_| point(rng, &rlo, &rhi)));
    // Far: beyond the hint grid, and beyond the tree's reach (every triangle measured).
    let centre = (lo + hi) * 0.5;
    let reach = field.tree().reach();
    pts.extend((0..20).map(|_| centre + direction(rng) * (0.5 * reach + 100.0 * rng.unit())));
    pts.extend((0..8).map(|_| centre + direction(rng) * (reach + 1.0 + 500.0 * rng.unit())));
    pts.extend([
        Vec3::new(f64::NAN, 0.0, 0.0),
        Vec3::new(0.0, f64::INFINITY, 0.0),
    ]);
    pts
}

#[test]
fn phantom_points_near_on_inside_and_far_equal_the_cpu() {
    let Some(ctx) = context() else { return };
    let (_, target) = phantom();
    let mesh = target.field.tree().triangles();
    eprintln!("tumour triangles: {}", mesh.len());
    let mut rng = Rng(7);
    let tumours = tumour_mesh(mesh);
    let pts = probe_points(&mut rng, &tumours, &target.field);
    let d = compare(&ctx, &target.field, &pts, "phantom");
    // The probes are what they claim: some on the surface, some far away.
    assert!(d.iter().filter(|d| **d < 1e-9).count() > 50);
    assert!(d.iter().any(|d| *d > 300.0));
}

/// The tree's triangles as a mesh (slot order).
fn tumour_mesh(tris: &[[Vec3; 3]]) -> TriMesh {
    let v: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let t = (0..tris.len() as u32)
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .collect();
    TriMesh::new(v, t).unwrap()
}

/// Triangle soups with slivers, needles, repeated and collinear corners (flat at corner 0: the
/// WGSL's transcription of the reference routine).
#[test]
fn triangle_soups_equal_the_cpu() {
    let Some(ctx) = context() else { return };
    for seed in [3u64, 11, 29] {
        let mut rng = Rng(seed);
        let (lo, hi) = (Vec3::repeat(-20.0), Vec3::repeat(20.0));
        let mut v = Vec::new();
        let mut t = Vec::new();
        for i in 0..400u32 {
            let a = point(&mut rng, &lo, &hi);
            let size = [4.0, 1e-3, 1e-7][i as usize % 3];
            let b = a + direction(&mut rng) * size;
            let c = match i % 5 {
                0 => a + (b - a) * rng.unit(),
                1 => b,
                _ => a + direction(&mut rng) * size * rng.unit(),
            };
            let k = v.len() as u32;
            v.extend([a, b, c]);
            t.push([k, k + 1, k + 2]);
        }
        let mesh = TriMesh::new(v, t).unwrap();
        let field =
            MarginField::new(&mesh, lo - Vec3::repeat(5.0), hi + Vec3::repeat(5.0), 1.5).unwrap();
        let flat = field
            .tree()
            .prepared()
            .iter()
            .filter(|p| p.is_none())
            .count();
        assert!(flat > 100, "{flat} flat slots");
        let pts = probe_points(&mut rng, &mesh, &field);
        compare(&ctx, &field, &pts, &format!("soup {seed} ({flat} flat)"));
    }
}

/// A finely tessellated sphere (20 480 triangles: a deep tree, many near-ties far away).
#[test]
fn a_fine_sphere_equals_the_cpu() {
    let Some(ctx) = context() else { return };
    let mesh = icosphere(Vec3::new(3.0, -2.0, 1.0), 15.0, 5).unwrap();
    assert_eq!(mesh.triangles().len(), 20_480);
    let field = MarginField::new(&mesh, Vec3::repeat(-40.0), Vec3::repeat(40.0), 2.0).unwrap();
    let mut rng = Rng(5);
    let pts = probe_points(&mut rng, &mesh, &field);
    compare(&ctx, &field, &pts, "icosphere");
}

/// A tilted 200×200 surface grid through the phantom liver in one call: distances equal the
/// CPU's surface-grid path, classes (margin 5 mm, band 5 mm) are identical and all four occur;
/// then smaller and larger calls reuse the resident field.
#[test]
fn a_200x200_grid_in_one_call_has_the_cpus_classes() {
    let Some(ctx) = context() else { return };
    let (anatomy, target) = phantom();
    let field = &target.field;
    let (n, r) = (200usize, 200usize);
    // Plane through the big tumour's edge: 6 mm from its centre, tilted.
    let centre = Vec3::new(10.0, 5.0, 0.0);
    let (du, dv) = (
        Vec3::new(1.0, 0.1, 0.2).normalize(),
        Vec3::new(-0.1, 1.0, 0.3).normalize(),
    );
    let normal = du.cross(&dv).normalize();
    let points: Vec<Vec3> = (0..n * r)
        .map(|k| {
            let (i, j) = ((k / r) as f64, (k % r) as f64);
            centre
                + normal * 6.0
                + du * (i / (n - 1) as f64 * 110.0 - 60.0)
                + dv * (j / (r - 1) as f64 * 90.0 - 45.0)
        })
        .collect();
    let inside: Vec<f64> = points.iter().map(|p| anatomy.inside_level(p)).collect();
    let settings = MarginSettings {
        margin_mm: 5.0,
        band_mm: 5.0,
    };
    let mut gpu_field = GpuMarginField::new(&ctx, field).unwrap();
    assert_eq!(gpu_field.field_id(), field.id());
    let mut gpu = vec![0.0; points.len()];
    let mut gpu_classes = vec![MarginClass::Outside; points.len()];
    gpu_field
        .margins_into(&settings, &points, &inside, &mut gpu, &mut gpu_classes)
        .unwrap();
    let mut cpu = vec![0.0; points.len()];
    field.distances_grid_into(n, r, &points, &mut cpu).unwrap();
    let d = max_diff(&gpu, &cpu);
    eprintln!("200x200 grid: max |gpu - cpu| = {d:.3e} mm");
    assert!(d <= EXACT_MM, "{d:e}");
    let cpu_classes: Vec<MarginClass> = cpu
        .iter()
        .zip(&inside)
        .map(|(&d, &s)| settings.classify(d, s))
        .collect();
    assert_eq!(gpu_classes, cpu_classes);
    for c in [
        MarginClass::Outside,
        MarginClass::Safe,
        MarginClass::Warning,
        MarginClass::Violation,
    ] {
        let count = gpu_classes.iter().filter(|&&k| k == c).count();
        eprintln!("{c:?}: {count}");
        assert!(count > 100, "{c:?}: {count}");
    }
    // Resident reuse: a part, then everything again, on the same buffers and field.
    let mut part = vec![0.0; 1000];
    gpu_field
        .distances_into(&points[5000..6000], &mut part)
        .unwrap();
    assert_eq!(part, gpu[5000..6000]);
    let mut again = vec![0.0; points.len()];
    gpu_field.distances_into(&points, &mut again).unwrap();
    assert_eq!(again, gpu);
}

#[test]
fn mismatched_lengths_and_bad_settings_are_typed_errors() {
    let Some(ctx) = context() else { return };
    let (_, target) = phantom();
    let mut g = GpuMarginField::new(&ctx, &target.field).unwrap();
    let pts = vec![Vec3::zeros(); 4];
    let e = g.distances_into(&pts, &mut [0.0; 3]).unwrap_err();
    assert!(matches!(e, GpuError::Margin(_)), "{e}");
    let bad = MarginSettings {
        margin_mm: 0.0,
        band_mm: 1.0,
    };
    let e = g
        .margins_into(
            &bad,
            &pts,
            &[1.0; 4],
            &mut [0.0; 4],
            &mut [MarginClass::Outside; 4],
        )
        .unwrap_err();
    assert!(matches!(e, GpuError::Margin(_)), "{e}");
    // No points: nothing to do.
    g.distances_into(&[], &mut []).unwrap();
}

#[test]
fn a_lost_device_is_a_typed_error() {
    if context().is_none() {
        return;
    }
    // A device of its own: destroyed below.
    let ctx = GpuContext::new().unwrap();
    let (_, target) = phantom();
    let mut g = GpuMarginField::new(&ctx, &target.field).unwrap();
    let pts = vec![Vec3::new(1.0, 2.0, 3.0); 100];
    let mut out = vec![0.0; 100];
    g.distances_into(&pts, &mut out).unwrap();
    ctx.device.destroy();
    let e = g.distances_into(&pts, &mut out).unwrap_err();
    eprintln!("lost: {e}");
    assert!(matches!(e, GpuError::DeviceLost(_)), "{e}");
    let e = GpuMarginField::new(&ctx, &target.field).unwrap_err();
    assert!(matches!(e, GpuError::DeviceLost(_)), "{e}");
}
