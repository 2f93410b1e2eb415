//! Volumes against analytic caps of ellipsoid livers on oblique anisotropic grids, a curved cut
//! against dense numerical integration, unions, incomplete cuts, the thesis' method, bad input.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::f64::consts::PI;

use resecta_bezier::{ControlNet, basis_at, binomial_row};
use resecta_geom::{CutSurface, Grid, Mat3, Real, Vec3, Volume};
use resecta_volumetry::{IncompleteCut, LiverVoxels, Volumetry, VolumetryError, thesis_volumetry};

const AXES: [Real; 3] = [50.0, 38.0, 30.0];

fn oblique_grid(spacing: [Real; 3], half: Real) -> Grid {
    let dir = nalgebra::Rotation3::from_euler_angles(0.12, -0.08, 0.2).into_inner();
    let dims = spacing.map(|s| (2.0 * half / s).ceil() as usize + 1);
    let centre = Vec3::new(0.3, -0.2, 0.1);
    let half_extent = Vec3::from_fn(|i, _| spacing[i] * (dims[i] - 1) as Real / 2.0);
    Grid::new(dims, spacing, centre - dir * half_extent, dir).unwrap()
}

fn mask(grid: &Grid, inside: impl Fn(Vec3) -> bool + Sync) -> Volume<bool> {
    let [nx, ny, _] = grid.dims();
    let data = (0..grid.len())
        .map(|v| inside(grid.voxel_center([v % nx, (v / nx) % ny, v / (nx * ny)])))
        .collect();
    Volume::from_vec(grid.clone(), data).unwrap()
}

fn in_ellipsoid(p: Vec3) -> bool {
    (p.x / AXES[0]).powi(2) + (p.y / AXES[1]).powi(2) + (p.z / AXES[2]).powi(2) <= 1.0
}

/// Volume of {n·x > t} ∩ ellipsoid (n unit).
fn cap(n: Vec3, t: Real) -> Real {
    let dn = Vec3::new(AXES[0] * n.x, AXES[1] * n.y, AXES[2] * n.z);
    let h = t / dn.norm();
    AXES.iter().product::<Real>() * PI * (1.0 - h).powi(2) * (2.0 + h) / 3.0
}

/// A planar 4×4 net on {n·x = t}, spanning ±`half` in the plane.
fn plane_net(n: Vec3, t: Real, half: Real) -> ControlNet<Real> {
    let a = n.cross(&Vec3::new(0.3, 0.9, 0.1)).normalize();
    let b = n.cross(&a);
    let o = n * t - a * half - b * half;
    let (eu, ev) = (a * 2.0 * half, b * 2.0 * half);
    ControlNet::planar(4, 4, o.into(), eu.into(), ev.into()).unwrap()
}

/// The liver mask's own share of {n·x > t}: each liver voxel's fraction above the plane by 8³
/// sub-samples — what a perfect cut of the voxelised liver gives.
fn voxel_truth(m: &Volume<bool>, above: impl Fn(Vec3) -> bool) -> Real {
    let grid = m.grid();
    let lin = grid.linear();
    let [nx, ny, _] = grid.dims();
    let k = 8;
    let mut sum = 0.0;
    for (v, _) in m.data().iter().enumerate().filter(|(_, b)| **b) {
        let c = grid.voxel_center([v % nx, (v / nx) % ny, v / (nx * ny)]);
        let corners_agree = (0..8).all(|q| {
            let o = Vec3::new(
                (q & 1) as Real - 0.5,
                ((q >> 1) & 1) as Real - 0.5,
                (q >> 2) as Real - 0.5,
            );
            above(c + lin * o) == above(c)
        });
        if corners_agree {
            sum += if above(c) { 1.0 } else { 0.0 };
            continue;
        }
        let mut hits = 0;
        for s in 0..k * k * k {
            let o = Vec3::new(
                ((s % k) as Real + 0.5) / k as Real - 0.5,
                ((s / k % k) as Real + 0.5) / k as Real - 0.5,
                ((s / (k * k)) as Real + 0.5) / k as Real - 0.5,
            );
            if above(c + lin * o) {
                hits += 1;
            }
        }
        sum += Real::from(hits) / (k * k * k) as Real;
    }
    sum * grid.voxel_volume_mm3()
}

#[test]
fn planar_cuts_of_an_ellipsoid_match_the_analytic_cap() {
    let grid = oblique_grid([0.8, 0.9, 2.5], 56.0);
    let m = mask(&grid, in_ellipsoid);
    let liver = LiverVoxels::new(&m).unwrap();
    let whole = 4.0 / 3.0 * PI * AXES.iter().product::<Real>();
    assert!((liver.total_mm3() - whole).abs() < 0.002 * whole);
    let mut vol = Volumetry::new(liver);
    for (n, t) in [
        (Vec3::x(), 10.0),
        (Vec3::new(1.0, 0.5, 0.3).normalize(), -12.0),
        (Vec3::new(-0.2, 1.0, -0.7).normalize(), 5.5),
        (Vec3::z(), 17.3),
    ] {
        // The tumour side: a point well on the +n side.
        let r = vol.cut(&plane_net(n, t, 90.0), &[n * (t + 3.0)]).unwrap();
        assert!(r.complete, "{r:?}");
        // Against the voxelised liver's exact share: the cut itself is sub-voxel exact…
        let vt = voxel_truth(&m, |p| n.dot(&p) > t);
        let err_v = (r.resected_mm3 - vt) / vt;
        assert!(
            err_v.abs() < 0.001,
            "n {n:?} t {t}: {} vs voxel truth {vt} ({:.3} %)",
            r.resected_mm3,
            err_v * 100.0
        );
        // …and against the analytic ellipsoid (which adds the liver's own voxelisation: 2.5 mm
        // slices near the pole of the small z cap).
        let truth = cap(n, t);
        let err = (r.resected_mm3 - truth) / truth;
        assert!(
            err.abs() < 0.005,
            "n {n:?} t {t}: {} vs {truth} ({:.3} %)",
            r.resected_mm3,
            err * 100.0
        );
        // The other side.
        let r2 = vol.cut(&plane_net(n, t, 90.0), &[n * (t - 3.0)]).unwrap();
        let whole_vox = vol.liver().total_mm3();
        assert!((r2.resected_mm3 + r.resected_mm3 - whole_vox).abs() < 1e-3 * whole_vox);
    }
}

/// A planar net whose control points bunch towards one edge (the parametrisation is uneven:
/// most of the surface lies in the last control interval) still cuts completely and resects
/// what the evenly spaced net does — the samples follow the speed, not the polygon's length.
#[test]
fn an_unevenly_parametrised_net_cuts_as_the_even_one() {
    let grid = oblique_grid([0.8, 0.9, 2.5], 56.0);
    let m = mask(&grid, in_ellipsoid);
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let (n, t) = (Vec3::x(), 10.0);
    let even = plane_net(n, t, 90.0);
    let p = even.points();
    // u-steps of 2 %, 3 % and 95 % of the side instead of thirds, in both directions.
    let f = [0.0, 0.02, 0.05, 1.0];
    let (o, eu, ev) = (
        Vec3::from(p[0]),
        Vec3::from(p[12]) - Vec3::from(p[0]),
        Vec3::from(p[3]) - Vec3::from(p[0]),
    );
    let bunched = ControlNet::new(
        4,
        4,
        (0..16)
            .map(|k| (o + eu * f[k / 4] + ev * f[k % 4]).into())
            .collect(),
    )
    .unwrap();
    let tumour = [n * (t + 3.0)];
    let a = vol.cut(&even, &tumour).unwrap();
    let b = vol.cut(&bunched, &tumour).unwrap();
    assert!(b.complete, "{b:?}");
    assert!(
        (a.resected_mm3 - b.resected_mm3).abs() < 1e-3 * a.resected_mm3,
        "{} vs {}",
        a.resected_mm3,
        b.resected_mm3
    );
}

#[test]
fn a_tumour_hole_is_not_liver() {
    let grid = oblique_grid([1.0, 1.0, 1.5], 56.0);
    let (c, r) = (Vec3::new(25.0, 5.0, 0.0), 8.0);
    let m = mask(&grid, |p| in_ellipsoid(p) && (p - c).norm() > r);
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let res = vol.cut(&plane_net(Vec3::x(), 6.0, 90.0), &[c]).unwrap();
    let truth = cap(Vec3::x(), 6.0) - 4.0 / 3.0 * PI * r.powi(3);
    assert!(
        (res.resected_mm3 - truth).abs() < 0.003 * truth,
        "{} vs {truth}",
        res.resected_mm3
    );
}

/// The bent net x = X(u, v), y = −70 + 140u, z = −70 + 140v (linear in y, z by linear precision).
fn bent() -> (ControlNet<Real>, impl Fn(Real, Real) -> Real) {
    let xs = |i: usize, j: usize| {
        5.0 + 14.0 * ((i as Real - 1.5).powi(2) + (j as Real - 1.5).powi(2)) / 4.5 - 8.0
    };
    let net = ControlNet::from_fn(4, 4, |i, j| {
        [
            xs(i, j),
            -70.0 + 140.0 * i as Real / 3.0,
            -70.0 + 140.0 * j as Real / 3.0,
        ]
    })
    .unwrap();
    let height = move |y: Real, z: Real| {
        let (u, v) = ((y + 70.0) / 140.0, (z + 70.0) / 140.0);
        let (mut bu, mut bv) = ([0.0; 4], [0.0; 4]);
        basis_at(&binomial_row(4), u, &mut bu);
        basis_at(&binomial_row(4), v, &mut bv);
        (0..16)
            .map(|k| bu[k / 4] * bv[k % 4] * xs(k / 4, k % 4))
            .sum()
    };
    (net, height)
}

#[test]
fn a_curved_cut_matches_dense_integration() {
    let grid = oblique_grid([0.9, 1.1, 2.0], 56.0);
    let m = mask(&grid, in_ellipsoid);
    let (net, height) = bent();
    // Truth: voxels far from the surface by their centre, near ones by 8³ sub-samples.
    let lin = grid.linear();
    let [nx, ny, _] = grid.dims();
    let mut truth = 0.0;
    for (v, _) in m.data().iter().enumerate().filter(|(_, b)| **b) {
        let c = grid.voxel_center([v % nx, (v / nx) % ny, v / (nx * ny)]);
        let gap = c.x - height(c.y, c.z);
        if gap.abs() > 4.0 {
            truth += if gap > 0.0 { 1.0 } else { 0.0 };
            continue;
        }
        let k = 8;
        let mut inside = 0;
        for s in 0..k * k * k {
            let o = Vec3::new(
                ((s % k) as Real + 0.5) / k as Real - 0.5,
                ((s / k % k) as Real + 0.5) / k as Real - 0.5,
                ((s / (k * k)) as Real + 0.5) / k as Real - 0.5,
            );
            let p = c + lin * o;
            if p.x > height(p.y, p.z) {
                inside += 1;
            }
        }
        truth += Real::from(inside) / (k * k * k) as Real;
    }
    truth *= grid.voxel_volume_mm3();
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let r = vol.cut(&net, &[Vec3::new(40.0, 0.0, 0.0)]).unwrap();
    assert!(r.complete, "{r:?}");
    let err = (r.resected_mm3 - truth) / truth;
    // Sub-sampling resolves fractions to 1/512; the band's tangent-plane fractions are unbiased.
    assert!(
        err.abs() < 0.002,
        "{} vs {truth} ({:.3} %)",
        r.resected_mm3,
        err * 100.0
    );
}

#[test]
fn unions_labels_and_the_thesis_method() {
    let grid = oblique_grid([1.0, 1.0, 2.0], 56.0);
    let m = mask(&grid, in_ellipsoid);
    let whole_vox = m.data().iter().filter(|&&b| b).count() as Real * grid.voxel_volume_mm3();
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let a = plane_net(Vec3::x(), 20.0, 90.0);
    let b = plane_net(Vec3::y(), 10.0, 90.0);
    let ta = [Vec3::new(35.0, 0.0, 0.0)];
    let tb = [Vec3::new(0.0, 25.0, 0.0)];
    let multi = vol.cuts(&[(&a, &ta), (&b, &tb)]).unwrap();
    assert!(multi.complete);
    // Union of {x > 20} and {y > 10}: inclusion–exclusion with the quarter {x > 20, y > 10},
    // integrated numerically over the voxel centres (exact for the union's voxel count).
    let ra = multi.cuts[0].resected_mm3;
    let rb = multi.cuts[1].resected_mm3;
    assert!((ra - cap(Vec3::x(), 20.0)).abs() < 0.004 * ra);
    assert!((rb - cap(Vec3::y(), 10.0)).abs() < 0.004 * rb);
    let [nx, ny, _] = grid.dims();
    let both = m
        .data()
        .iter()
        .enumerate()
        .filter(|(v, b)| {
            let c = grid.voxel_center([v % nx, (v / nx) % ny, v / (nx * ny)]);
            **b && c.x > 20.0 && c.y > 10.0
        })
        .count() as Real
        * grid.voxel_volume_mm3();
    let union = ra + rb - both;
    assert!(
        (multi.resected_mm3 - union).abs() < 0.004 * union,
        "{} vs {union}",
        multi.resected_mm3
    );
    assert!((multi.remnant_mm3 + multi.resected_mm3 - whole_vox).abs() < 1e-6 * whole_vox);
    // Per-voxel fractions sum to the volumes, one cut or two, and sit at their voxels.
    let offsets = vol.liver().offsets();
    let (da, db): (&dyn CutSurface, &dyn CutSurface) = (&a, &b);
    for cuts in [&[(da, &ta[..]), (db, &tb[..])][..], &[(da, &ta[..])][..]] {
        let (again, fractions) = vol.cuts_with_fractions(cuts).unwrap();
        let sum: Real = fractions.iter().map(|&f| Real::from(f)).sum();
        assert!((sum * grid.voxel_volume_mm3() - again.resected_mm3).abs() < 1e-3 * union);
        for (&o, &f) in offsets.iter().zip(&fractions) {
            assert!(m.data()[o]);
            let c = grid.voxel_center(grid.ijk(o));
            if c.x > 22.0 {
                assert_eq!(f, 1.0);
            } else if c.x < 18.0 && (cuts.len() == 1 || c.y < 8.0) {
                assert_eq!(f, 0.0);
            }
        }
    }
    assert_eq!(multi, vol.cuts(&[(&a, &ta), (&b, &tb)]).unwrap());
    // Labels: the ≥ ½ voxels agree with the fractional volume within the band's rounding.
    let labels = vol.resected_labels(&[(&a, &ta)]).unwrap();
    let n2 = labels.data().iter().filter(|&&l| l == 2).count() as Real * grid.voxel_volume_mm3();
    assert!((n2 - ra).abs() < 0.01 * ra, "{n2} vs {ra}");
    assert_eq!(
        labels.data().iter().filter(|&&l| l > 0).count(),
        m.data().iter().filter(|&&b| b).count()
    );
    // The thesis' method loses the barrier voxels: a clear deficit on both sides.
    let t = thesis_volumetry(&m, &a, ta[0], 300, 3).unwrap();
    assert!(t.lost_mm3 > 0.0);
    let truth = cap(Vec3::x(), 20.0);
    let ours = (ra - truth).abs() / truth;
    let theirs = (t.resected_mm3 - truth).abs() / truth;
    assert!(
        theirs > 3.0 * ours && theirs > 0.01,
        "thesis {theirs}, ours {ours}"
    );
    assert!((t.resected_mm3 + t.remnant_mm3 + t.lost_mm3 - whole_vox).abs() < 1e-6 * whole_vox);
}

#[test]
fn incomplete_cuts_are_reported() {
    let grid = oblique_grid([1.0, 1.0, 2.0], 56.0);
    let mut vol = Volumetry::new(LiverVoxels::new(&mask(&grid, in_ellipsoid)).unwrap());
    let t = [Vec3::new(30.0, 0.0, 0.0)];
    let small = vol.cut(&plane_net(Vec3::x(), 5.0, 15.0), &t).unwrap();
    assert!(!small.complete);
    assert!(
        matches!(
            small.incomplete,
            Some(IncompleteCut::EdgeInsideLiver { .. })
        ),
        "{small:?}"
    );
    let beside = vol.cut(&plane_net(Vec3::x(), 70.0, 90.0), &t).unwrap();
    assert_eq!(beside.incomplete, Some(IncompleteCut::MissesLiver));
    // A ring-shaped liver cut through one arm only, the patch's edges outside the ring: the
    // ring still connects both sides.
    let ring = |p: Vec3| ((p.x * p.x + p.y * p.y).sqrt() - 40.0).powi(2) + p.z * p.z <= 144.0;
    let g2 = oblique_grid([1.0, 1.0, 1.5], 56.0);
    let mut v2 = Volumetry::new(LiverVoxels::new(&mask(&g2, ring)).unwrap());
    let net =
        ControlNet::planar(4, 4, [20.0, 0.0, -20.0], [40.0, 0.0, 0.0], [0.0, 0.0, 40.0]).unwrap();
    let leak = v2.cut(&net, &[Vec3::new(40.0, 6.0, 0.0)]).unwrap();
    assert_eq!(leak.incomplete, Some(IncompleteCut::Leak), "{leak:?}");
    // Cutting both arms separates it.
    let both = ControlNet::planar(
        4,
        4,
        [-60.0, 0.0, -20.0],
        [120.0, 0.0, 0.0],
        [0.0, 0.0, 40.0],
    )
    .unwrap();
    let ok = v2.cut(&both, &[Vec3::new(40.0, 6.0, 0.0)]).unwrap();
    assert!(ok.complete, "{ok:?}");
    let half = v2.liver().total_mm3() / 2.0;
    assert!((ok.resected_mm3 - half).abs() < 0.01 * half);
}

#[test]
fn bad_input_is_refused() {
    let grid = oblique_grid([2.0, 2.0, 2.0], 20.0);
    let empty = Volume::filled(grid.clone(), false);
    assert!(matches!(
        LiverVoxels::new(&empty),
        Err(VolumetryError::EmptyLiver)
    ));
    let m = mask(&grid, |p| p.norm() < 15.0);
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let net = plane_net(Vec3::x(), 0.0, 30.0);
    assert!(matches!(
        vol.cut(&net, &[]),
        Err(VolumetryError::NoTumourPoints)
    ));
    assert!(matches!(
        vol.cut(&net, &[Vec3::zeros(), Vec3::new(Real::NAN, 0.0, 0.0)]),
        Err(VolumetryError::NonFinitePoint(1))
    ));
    assert!(thesis_volumetry(&m, &net, Vec3::zeros(), 1, 3).is_err());
    assert!(thesis_volumetry(&m, &net, Vec3::zeros(), 300, 2).is_err());
    assert!(thesis_volumetry(&m, &net, Vec3::new(Real::NAN, 0.0, 0.0), 300, 3).is_err());
    let _ = Mat3::identity();
}
