//! Phantom generation against analytic truth.

use std::f64::consts::PI;
use std::time::Instant;

use nalgebra::Rotation3;
use resecta_geom::{Mat3, Real, Role, Vec3};
use resecta_phantom::{
    EllipsoidSpec, GridSpec, Method, Orientation, PhantomError, PhantomSpec, SphereSpec,
    VesselSpec, generate,
};

fn sphere_liver(spacing: [Real; 3], dir: Orientation) -> PhantomSpec {
    let n = spacing.map(|s| (110.0 / s).ceil() as usize);
    PhantomSpec {
        grid: GridSpec::centred(n, spacing, [3.0, -1.0, 2.0], dir),
        liver: vec![EllipsoidSpec {
            center: [3.3, -0.7, 2.1],
            radii: [50.0; 3],
            rotation: Orientation::Identity,
        }],
        tumors: vec![],
        vessels: vec![],
        roles: Default::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    }
}

#[test]
fn voxelised_sphere_volume_converges_to_analytic() {
    let exact = 4.0 / 3.0 * PI * 50f64.powi(3);
    let mut errors = Vec::new();
    for s in [4.0, 2.0, 1.0] {
        let p = generate(&sphere_liver(
            [s; 3],
            Orientation::EulerDeg([7.0, -4.0, 11.0]),
        ))
        .unwrap();
        assert_eq!(p.truth.liver.method, Method::Analytic);
        assert!((p.truth.liver.volume_mm3 - exact).abs() < 1e-6 * exact);
        let vox = p.truth.labels[&1].volume_mm3;
        errors.push(((vox - exact) / exact).abs());
    }
    eprintln!("relative voxelisation errors at 4, 2, 1 mm: {errors:?}");
    // 50 mm sphere: within 2 % at 4 mm, 0.5 % at 2 mm, 0.2 % at 1 mm.
    assert!(
        errors[0] < 0.02 && errors[1] < 0.005 && errors[2] < 0.002,
        "{errors:?}"
    );
}

#[test]
fn anisotropic_sphere_volume_within_two_percent() {
    let exact = 4.0 / 3.0 * PI * 50f64.powi(3);
    let p = generate(&sphere_liver(
        [0.8, 0.8, 2.5],
        Orientation::EulerDeg([3.0, 2.0, -5.0]),
    ))
    .unwrap();
    let vox = p.truth.labels[&1].volume_mm3;
    assert!(((vox - exact) / exact).abs() < 0.005, "{vox} vs {exact}");
}

/// Independent inside tests straight from the spec (no crate code besides the spec types).
fn label_by_hand(spec: &PhantomSpec, p: Vec3) -> u16 {
    let rot = |o: &Orientation| match o {
        Orientation::Identity => Mat3::identity(),
        Orientation::EulerDeg([r, pi, y]) => {
            Rotation3::from_euler_angles(r.to_radians(), pi.to_radians(), y.to_radians())
                .into_inner()
        }
        Orientation::Matrix(m) => Mat3::from_row_slice(m.as_flattened()),
    };
    if spec
        .tumors
        .iter()
        .any(|t| (p - Vec3::from(t.center)).norm() <= t.radius)
    {
        return 2;
    }
    for (role, label) in [(Role::Portal, 3), (Role::Hepatic, 4)] {
        for v in spec.vessels.iter().filter(|v| v.role == role) {
            for w in v.points.windows(2) {
                let (a, b) = (Vec3::from(w[0]), Vec3::from(w[1]));
                let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
                if (p - (a + (b - a) * t)).norm() <= v.radius {
                    return label;
                }
            }
        }
    }
    for e in &spec.liver {
        let q = rot(&e.rotation).transpose() * (p - Vec3::from(e.center));
        if (0..3).map(|i| (q[i] / e.radii[i]).powi(2)).sum::<Real>() <= 1.0 {
            return 1;
        }
    }
    0
}

#[test]
fn oblique_grid_labels_sit_at_the_right_world_positions() {
    for mut spec in [PhantomSpec::small(), PhantomSpec::demo()] {
        // Labels do not depend on the truth tolerance; a coarse one keeps debug runs short.
        spec.truth_tolerance_mm = 1.0;
        let p = generate(&spec).unwrap();
        let g = p.labels.grid();
        assert!(
            g.direction() != Mat3::identity(),
            "the grid must be oblique"
        );
        let step = if g.len() > 1_000_000 { 7 } else { 1 };
        let mut seen = [0usize; 5];
        for o in (0..g.len()).step_by(step) {
            let c = g.voxel_center(g.ijk(o));
            let want = label_by_hand(&spec, c);
            assert_eq!(p.labels.data()[o], want, "voxel {:?} at {c:?}", g.ijk(o));
            seen[usize::from(want)] += 1;
        }
        assert!(
            seen.iter().all(|&n| n > 0) || spec.vessels.len() < 2,
            "{seen:?}"
        );
        // The tumour centre's voxel is tumour; a grid corner is background.
        let t = Vec3::from(spec.tumors[0].center);
        let ijk = g.world_to_index(t).map(|x| x.round() as usize);
        assert_eq!(p.labels.get([ijk.x, ijk.y, ijk.z]), Some(2));
        assert_eq!(p.labels.get([0, 0, 0]), Some(0));
    }
}

#[test]
fn closed_forms_lie_within_the_numeric_bounds() {
    // small(): one ellipsoid, one tumour, one capsule inside the liver: everything closed-form.
    let spec = PhantomSpec::small();
    let p = generate(&spec).unwrap();
    let t = &p.truth;
    assert!(
        t.roles.values().all(|m| m.method == Method::Analytic),
        "{:?}",
        t.roles
    );
    let liver = 4.0 / 3.0 * PI * 40.0 * 30.0 * 25.0;
    let tumor = 4.0 / 3.0 * PI * 512.0;
    let len = (Vec3::new(-20.0, -5.0, -5.0) - Vec3::new(0.0, -10.0, 0.0)).norm();
    let portal = PI * 9.0 * len + 4.0 / 3.0 * PI * 27.0;
    assert!(t.liver.contains(liver, 1e-6));
    assert!(t.roles[&Role::Tumor].contains(tumor, 1e-6));
    assert!(t.roles[&Role::Portal].contains(portal, 1e-6));
    assert!(t.roles[&Role::Parenchyma].contains(liver - tumor - portal, 1e-6));
    // A second, tiny ellipsoid inside the first makes the liver a union: numeric, and its bounds
    // must contain the same closed forms.
    let mut numeric = spec.clone();
    numeric.liver.push(EllipsoidSpec {
        center: [0.0, 0.0, 0.0],
        radii: [1.0, 1.0, 1.0],
        rotation: Orientation::Identity,
    });
    numeric.truth_tolerance_mm = 0.01;
    let n = generate(&numeric).unwrap().truth;
    assert_eq!(n.liver.method, Method::Numeric);
    assert!(n.liver.contains(liver, 1e-6), "{:?} vs {liver}", n.liver);
    let par = n.roles[&Role::Parenchyma];
    assert_eq!(par.method, Method::Numeric);
    assert!(par.contains(liver - tumor - portal, 1e-6), "{par:?}");
    // Bound ≈ tolerance × area (liver ≈ 1.2e4 mm², tumour 804, capsule ≈ 700).
    assert!(par.error_bound_mm3 < 0.002 * par.volume_mm3, "{par:?}");
    eprintln!(
        "numeric parenchyma {par:?}, leaves {}",
        n.integration_leaves
    );
}

#[test]
fn overlapping_tumours_are_integrated() {
    let mut spec = PhantomSpec::small();
    spec.tumors = vec![
        SphereSpec {
            center: [0.0, 0.0, 0.0],
            radius: 8.0,
        },
        SphereSpec {
            center: [6.0, 0.0, 0.0],
            radius: 8.0,
        },
    ];
    spec.vessels.clear();
    spec.truth_tolerance_mm = 0.01;
    let t = generate(&spec).unwrap().truth;
    let m = t.roles[&Role::Tumor];
    assert_eq!(m.method, Method::Numeric);
    // Union of two balls of radius r at distance d: 2·(4/3πr³) − lens, lens = π(4r + d)(2r − d)²/12.
    let (r, d) = (8.0f64, 6.0f64);
    let union =
        2.0 * 4.0 / 3.0 * PI * r.powi(3) - PI * (4.0 * r + d) * (2.0 * r - d).powi(2) / 12.0;
    assert!(m.contains(union, 1e-6), "{m:?} vs {union}");
    assert!(m.error_bound_mm3 < 0.01 * union, "{m:?}");
}

#[test]
fn demo_is_liver_sized() {
    // Release timing is in the crate docs; here a coarser truth keeps debug runs short.
    let mut spec = PhantomSpec::demo();
    spec.truth_tolerance_mm = 0.2;
    let start = Instant::now();
    let p = generate(&spec).unwrap();
    eprintln!(
        "demo: {:?} in {:?}",
        p.labels.grid().dims(),
        start.elapsed()
    );
    let t = &p.truth;
    let ml = t.liver.volume_mm3 / 1000.0;
    assert!((1300.0..1700.0).contains(&ml), "{ml} ml");
    assert!(
        t.liver.error_bound_mm3 < 0.002 * t.liver.volume_mm3,
        "{:?}",
        t.liver
    );
    assert_eq!(t.roles[&Role::Tumor].method, Method::Analytic);
    assert_eq!(t.roles[&Role::Hepatic].method, Method::Analytic);
    // Voxelised volumes per label agree with the truth to within 1 % (3 % for thin tubes).
    for (l, lt) in &t.labels {
        let m = t.roles[&lt.role];
        let rel = (lt.volume_mm3 - m.volume_mm3).abs() / m.volume_mm3;
        let tol = if matches!(lt.role, Role::Portal | Role::Hepatic) {
            0.03
        } else {
            0.01
        };
        eprintln!(
            "label {l} {}: voxels {:.0} truth {:.0} ± {:.1} mm³ ({rel:.4})",
            lt.role, lt.volume_mm3, m.volume_mm3, m.error_bound_mm3
        );
        assert!(rel < tol, "label {l}: {} vs {m:?}", lt.volume_mm3);
    }
    // Parenchyma + tumour + the vessels inside the liver = liver (vessels are inside here).
    let sum: Real = t.roles.values().map(|m| m.volume_mm3).sum();
    let slack: Real =
        t.roles.values().map(|m| m.error_bound_mm3).sum::<Real>() + t.liver.error_bound_mm3;
    assert!(
        (sum - t.liver.volume_mm3).abs() <= slack + 1e-6,
        "{sum} vs {:?}",
        t.liver
    );
}

#[test]
fn large_tumour_is_one_bumpy_component() {
    // The same extent as the 512×512×130 CT grid at 2 mm, so that debug runs stay short.
    let mut spec = PhantomSpec::large_tumour();
    let (dims, spacing) = (spec.grid.dims, spec.grid.spacing);
    let coarse = std::array::from_fn(|i| (dims[i] as Real * spacing[i] / 2.0).floor() as usize);
    let centre = Vec3::from(spec.grid.origin)
        + spec.grid.direction.matrix("grid").unwrap()
            * Vec3::from_fn(|i, _| spacing[i] * (dims[i] - 1) as Real / 2.0);
    spec.grid = GridSpec::centred(coarse, [2.0; 3], centre.into(), spec.grid.direction);
    spec.truth_tolerance_mm = 0.2;
    let p = generate(&spec).unwrap();
    let t = &p.truth;
    let m = t.roles[&Role::Tumor];
    // Overlapping balls: integrated, larger than the core ball, smaller than the sum of balls.
    assert_eq!(m.method, Method::Numeric);
    let core = 4.0 / 3.0 * PI * spec.tumors[0].radius.powi(3);
    let sum: Real = spec
        .tumors
        .iter()
        .map(|b| 4.0 / 3.0 * PI * b.radius.powi(3))
        .sum();
    assert!(
        m.volume_mm3 > 1.15 * core && m.volume_mm3 < 0.9 * sum,
        "{m:?}"
    );
    // One tumour label whose voxels form one 6-connected component with the voxelised volume.
    let tumour = spec.roles.labels(Role::Tumor)[0];
    let lt = &t.labels[&tumour];
    assert!(
        (lt.volume_mm3 - m.volume_mm3).abs() < 0.03 * m.volume_mm3,
        "{lt:?} vs {m:?}"
    );
    let [nx, ny, nz] = p.labels.grid().dims();
    let data = p.labels.data();
    let is_tumour: Vec<bool> = data.iter().map(|&l| l == tumour).collect();
    let start = is_tumour.iter().position(|&b| b).unwrap();
    let mut seen = vec![false; data.len()];
    let (mut stack, mut reached) = (vec![start], 0u64);
    seen[start] = true;
    while let Some(v) = stack.pop() {
        reached += 1;
        let (i, j, k) = (v % nx, v / nx % ny, v / (nx * ny));
        let steps = [
            (i > 0, v.wrapping_sub(1)),
            (i + 1 < nx, v + 1),
            (j > 0, v.wrapping_sub(nx)),
            (j + 1 < ny, v + nx),
            (k > 0, v.wrapping_sub(nx * ny)),
            (k + 1 < nz, v + nx * ny),
        ];
        for (ok, w) in steps {
            if ok && is_tumour[w] && !seen[w] {
                seen[w] = true;
                stack.push(w);
            }
        }
    }
    assert_eq!(reached, lt.voxels);
    // Bumpy: some tumour voxel lies beyond the core ball by more than two voxels.
    let c = Vec3::from(PhantomSpec::LARGE_TUMOUR_CENTRE);
    let g = p.labels.grid();
    let farthest = (0..data.len())
        .filter(|&v| is_tumour[v])
        .map(|v| {
            let ijk = Vec3::new(
                (v % nx) as Real,
                (v / nx % ny) as Real,
                (v / (nx * ny)) as Real,
            );
            (g.index_to_world(ijk) - c).norm()
        })
        .fold(0.0, Real::max);
    assert!(farthest > spec.tumors[0].radius + 4.0, "{farthest}");
}

#[test]
fn spec_and_truth_round_trip_through_json() {
    let p = generate(&PhantomSpec::small()).unwrap();
    let js = serde_json::to_string_pretty(&p.truth).unwrap();
    let back: resecta_phantom::Truth = serde_json::from_str(&js).unwrap();
    assert_eq!(back, p.truth);
    let spec = PhantomSpec::demo();
    let js = serde_json::to_string(&spec).unwrap();
    assert_eq!(serde_json::from_str::<PhantomSpec>(&js).unwrap(), spec);
    // Defaults: roles, tolerance and limits may be left out.
    let minimal = r#"{"grid":{"dims":[10,10,10],"spacing":[2,2,2],"origin":[-9,-9,-9]},
        "liver":[{"center":[0,0,0],"radii":[5,6,7]}]}"#;
    let s: PhantomSpec = serde_json::from_str(minimal).unwrap();
    assert_eq!(generate(&s).unwrap().truth.liver.method, Method::Analytic);
}

#[test]
fn invalid_specs_are_typed_errors() {
    let base = PhantomSpec::small();
    let mut s = base.clone();
    s.tumors[0].center = [38.0, 0.0, 0.0];
    assert_eq!(
        generate(&s),
        Err(PhantomError::TumorOutsideLiver { index: 0 })
    );
    let mut s = base.clone();
    s.tumors[0].radius = 0.0;
    assert!(matches!(
        generate(&s),
        Err(PhantomError::NonPositive { .. })
    ));
    let mut s = base.clone();
    s.liver[0].radii[1] = Real::NAN;
    assert!(matches!(generate(&s), Err(PhantomError::NonFinite { .. })));
    let mut s = base.clone();
    s.vessels[0].points[1][2] = Real::INFINITY;
    assert!(matches!(generate(&s), Err(PhantomError::NonFinite { .. })));
    let mut s = base.clone();
    s.grid.dims = [2000, 2000, 2000];
    assert!(matches!(generate(&s), Err(PhantomError::VoxelLimit { .. })));
    let mut s = base.clone();
    s.max_voxels = Some(1000);
    assert!(matches!(
        generate(&s),
        Err(PhantomError::VoxelLimit { limit: 1000, .. })
    ));
    let mut s = base.clone();
    s.liver[0].radii[0] = 60.0;
    assert_eq!(
        generate(&s),
        Err(PhantomError::OutsideGrid {
            what: "liver[0]".into()
        })
    );
    let mut s = base.clone();
    s.liver[0].rotation = Orientation::Matrix([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    assert!(matches!(
        generate(&s),
        Err(PhantomError::NotOrthonormal { .. })
    ));
    let mut s = base.clone();
    s.vessels[0].points.truncate(1);
    assert_eq!(
        generate(&s),
        Err(PhantomError::TooFewPoints { index: 0, got: 1 })
    );
    let mut s = base.clone();
    s.vessels[0].role = Role::Tumor;
    assert!(matches!(
        generate(&s),
        Err(PhantomError::NotAVesselRole { .. })
    ));
    let mut s = base.clone();
    s.liver.clear();
    assert_eq!(generate(&s), Err(PhantomError::NoLiver));
    let mut s = base.clone();
    s.vessels.push(VesselSpec {
        role: Role::Hepatic,
        radius: 2.0,
        points: vec![[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]],
    });
    s.roles = serde_json::from_str(r#"{"parenchyma":[1],"tumor":[2],"portal":[3]}"#).unwrap();
    assert_eq!(generate(&s), Err(PhantomError::MissingRole(Role::Hepatic)));
    let mut s = base;
    s.truth_tolerance_mm = 0.0;
    assert!(matches!(
        generate(&s),
        Err(PhantomError::NonPositive { .. })
    ));
}
