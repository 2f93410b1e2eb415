//! Marching cubes against analytic surfaces, and closedness on adversarial fields.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::HashMap;

use resecta_geom::{Grid, Mat3, Mat4, TriMesh, Vec3, Volume};
use resecta_isosurface::{IsoError, Options, extract, extract_mask};

fn field(dims: [usize; 3], f: impl Fn(Vec3) -> f32) -> Vec<f32> {
    let mut v = Vec::with_capacity(dims.iter().product());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                v.push(f(Vec3::new(i as f64, j as f64, k as f64)));
            }
        }
    }
    v
}

/// Every vertex's triangles form one closed fan (no pinched vertices), besides report().
fn assert_closed_manifold(mesh: &TriMesh) {
    let report = mesh.report();
    assert!(report.watertight, "{report:?}");
    let mut around: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
    for &[a, b, c] in mesh.triangles() {
        around.entry(a).or_default().push((b, c));
        around.entry(b).or_default().push((c, a));
        around.entry(c).or_default().push((a, b));
    }
    for (v, fan) in around {
        // Follow next-pointers of the link; one cycle must cover all of it.
        let next: HashMap<u32, u32> = fan.iter().copied().collect();
        assert_eq!(next.len(), fan.len(), "vertex {v} has a repeated link edge");
        let start = fan[0].0;
        let (mut cur, mut steps) = (start, 0);
        loop {
            cur = next[&cur];
            steps += 1;
            if cur == start {
                break;
            }
            assert!(steps <= fan.len(), "vertex {v}: open link");
        }
        assert_eq!(
            steps,
            fan.len(),
            "vertex {v} is pinched (link has several cycles)"
        );
    }
}

#[test]
fn sphere_field_is_accurate_closed_and_outward() {
    let (n, r) = (41usize, 15.0f64);
    let c = Vec3::repeat(20.0);
    let values = field([n; 3], |p| (r - (p - c).norm()) as f32);
    let mesh = extract([n; 3], &values, 0.0, Options::default()).unwrap();
    assert_closed_manifold(&mesh);
    // Linear interpolation of a distance field: vertices within 0.02 cells of the sphere.
    let worst = mesh
        .vertices()
        .iter()
        .map(|v| ((v - c).norm() - r).abs())
        .fold(0.0, f64::max);
    assert!(worst < 0.02, "worst vertex error {worst}");
    let exact = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    let vol = mesh.signed_volume();
    assert!(vol > 0.0, "triangles must face outward");
    assert!(
        (vol - exact).abs() / exact < 0.005,
        "volume {vol} vs {exact}"
    );
}

#[test]
fn random_fields_give_closed_manifolds() {
    // Noise makes every ambiguous configuration occur; with the border closed the surface must
    // still be closed and manifold everywhere.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for trial in 0..20 {
        let dims = [7 + trial % 3, 8, 6 + trial % 4];
        let values: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        let opts = Options { close_border: true };
        let mesh = extract(dims, &values, 0.5, opts).unwrap();
        assert!(!mesh.is_empty());
        assert_closed_manifold(&mesh);
        assert!(mesh.signed_volume() > 0.0);
        // The binary version of the same field hits every tie of the decider.
        let mask: Vec<u8> = values.iter().map(|&v| u8::from(v > 0.5)).collect();
        let binary = extract(dims, &mask, 0.5, opts).unwrap();
        assert_closed_manifold(&binary);
    }
}

#[test]
fn single_voxel_mask_is_an_octahedron() {
    let grid = Grid::axis_aligned([3, 3, 3], [1.0; 3], Vec3::zeros()).unwrap();
    let mut mask = Volume::filled(grid, false);
    mask.set([1, 1, 1], true);
    let mesh = extract_mask(&mask).unwrap();
    assert_eq!(mesh.triangles().len(), 8);
    assert_closed_manifold(&mesh);
    let expected = 4.0 / 3.0 * 0.5f64.powi(3);
    assert!((mesh.signed_volume() - expected).abs() < 1e-12);
    for v in mesh.vertices() {
        assert!(((v - Vec3::repeat(1.0)).norm() - 0.5).abs() < 1e-12);
    }
}

#[test]
fn mask_touching_the_border_is_closed() {
    let grid = Grid::axis_aligned([5, 4, 3], [1.0; 3], Vec3::zeros()).unwrap();
    let mask = Volume::filled(grid, true);
    let mesh = extract_mask(&mask).unwrap();
    assert_closed_manifold(&mesh);
    // A full box of 5×4×3 voxel centres: the midpoint surface is the box grown by half a voxel
    // minus its chamfered edges and corners.
    let vol = mesh.signed_volume();
    assert!(
        vol > 4.0 * 3.0 * 2.0 && vol < 5.0 * 4.0 * 3.0,
        "volume {vol}"
    );
}

#[test]
fn mask_volume_matches_voxel_count_for_a_large_ellipsoid() {
    let dims = [60, 50, 40];
    let grid = Grid::axis_aligned(dims, [1.0; 3], Vec3::zeros()).unwrap();
    let c = Vec3::new(30.0, 25.0, 20.0);
    let inside = |p: Vec3| {
        let d = p - c;
        (d.x / 25.0).powi(2) + (d.y / 20.0).powi(2) + (d.z / 15.0).powi(2) <= 1.0
    };
    let data = field(dims, |p| if inside(p) { 1.0 } else { 0.0 });
    let mask = Volume::from_vec(grid, data.iter().map(|&v| v > 0.5).collect()).unwrap();
    let count = mask.data().iter().filter(|&&b| b).count() as f64;
    let mesh = extract_mask(&mask).unwrap();
    assert_closed_manifold(&mesh);
    let rel = (mesh.signed_volume() - count) / count;
    // Midpoint marching cubes chamfers the staircase: a little under the voxel volume.
    assert!(rel < 0.0 && rel > -0.03, "relative volume difference {rel}");
}

#[test]
fn transform_to_ras_keeps_outward_orientation() {
    let values = field([9; 3], |p| (3.0 - (p - Vec3::repeat(4.0)).norm()) as f32);
    let mesh = extract([9; 3], &values, 0.0, Options::default()).unwrap();
    // LPS-like flip of two axes and an anisotropic, mirrored index→RAS map.
    let mut m = Mat4::identity();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(Mat3::from_diagonal(&Vec3::new(-0.8, 0.8, 2.5))));
    m[(0, 3)] = 100.0;
    let ras = mesh.transformed(&m).unwrap();
    assert!(ras.signed_volume() > 0.0);
    let ratio = ras.signed_volume() / mesh.signed_volume();
    assert!((ratio - 0.8 * 0.8 * 2.5).abs() < 1e-9);
}

#[test]
fn output_is_independent_of_thread_count() {
    let values = field([48, 40, 36], |p| {
        (10.0 - (p - Vec3::new(20.0, 18.0, 17.0)).norm() + (p.x * 0.7).sin() * 2.0) as f32
    });
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| extract([48, 40, 36], &values, 0.0, Options::default()).unwrap())
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn bad_input_is_refused() {
    assert!(matches!(
        extract([1, 4, 4], &[0.0f32; 16], 0.0, Options::default()),
        Err(IsoError::TooSmall { .. })
    ));
    assert!(matches!(
        extract([2, 2, 2], &[0.0f32; 7], 0.0, Options::default()),
        Err(IsoError::DataLength { .. })
    ));
    let mut v = vec![0.0f32; 8];
    v[3] = f32::NAN;
    assert_eq!(
        extract([2, 2, 2], &v, 0.0, Options::default()),
        Err(IsoError::NonFinite(3))
    );
    assert_eq!(
        extract([2, 2, 2], &[0.0f32; 8], f32::INFINITY, Options::default()),
        Err(IsoError::BadIso(f32::INFINITY))
    );
    // Nothing inside: an empty, valid mesh.
    assert!(
        extract([3, 3, 3], &[0.0f32; 27], 0.5, Options::default())
            .unwrap()
            .is_empty()
    );
}
