//! DS and CP surfaces against analytic answers.

use std::f64::consts::PI;

use resecta_geom::{CutSurface, Real, Vec3, grid_param};
use resecta_traces::{
    CpSurface, DS_POINTS_PER_TRACE, Deformation, DsSurface, SliceOrientation, TraceError,
};

fn arr(v: Vec3) -> [Real; 3] {
    [v.x, v.y, v.z]
}

/// Every (u, v) of a 25×25 grid.
fn params() -> impl Iterator<Item = (Real, Real)> {
    (0..625).map(|k| (grid_param(k / 25, 25), grid_param(k % 25, 25)))
}

/// Straight traces on axial slices lying in the plane n·x = d (n with a z component).
fn plane_traces(n: Vec3, d: Real, slices: &[Real]) -> Vec<Vec<[Real; 3]>> {
    slices
        .iter()
        .map(|&z| {
            (0..7)
                .map(|k| {
                    let x = -40.0 + 13.0 * Real::from(k);
                    // Solve n·(x, y, z) = d for y.
                    let y = (d - n.x * x - n.z * z) / n.y;
                    [x, y, z]
                })
                .collect()
        })
        .collect()
}

#[test]
fn ds_straight_traces_on_a_plane_make_that_plane() {
    let n = Vec3::new(0.3, 0.9, -0.2).normalize();
    let s = DsSurface::new(&plane_traces(n, 12.0, &[-20.0, -5.0, 3.0, 25.0])).unwrap();
    assert_eq!(s.orientation(), SliceOrientation::Axial);
    for (u, v) in params() {
        let e = s.at(u, v);
        assert!(
            (n.dot(&e.p) - 12.0).abs() < 1e-9,
            "off the plane at ({u}, {v})"
        );
        assert!(e.mean_curvature().unwrap().abs() < 1e-6);
        assert!(e.normal().unwrap().cross(&n).norm() < 1e-9);
    }
    // It spans the first to the last slice.
    assert!((s.at(0.5, 0.0).p.z + 20.0).abs() < 1e-9);
    assert!((s.at(0.5, 1.0).p.z - 25.0).abs() < 1e-9);
}

/// Arcs of a cylinder of radius r about the S axis, on axial slices.
fn cylinder_traces(r: Real, slices: &[Real], points: usize) -> Vec<Vec<[Real; 3]>> {
    slices
        .iter()
        .map(|&z| {
            (0..points)
                .map(|k| {
                    let t = -PI / 3.0 + (2.0 * PI / 3.0) * k as Real / (points - 1) as Real;
                    [r * t.cos(), r * t.sin(), z]
                })
                .collect()
        })
        .collect()
}

#[test]
fn ds_on_a_cylinder_reproduces_its_curvature() {
    let r = 60.0;
    let s = DsSurface::new(&cylinder_traces(r, &[0.0, 10.0, 20.0, 30.0, 40.0], 90)).unwrap();
    let mut worst: Real = 0.0;
    let mut h_all = Vec::new();
    for (u, v) in params() {
        let e = s.at(u, v);
        // A cylinder's principal curvatures are 1/r and 0: |H| = 1/(2r).
        let h = e.mean_curvature().unwrap().abs();
        h_all.push(h);
        worst = worst.max((2.0 * h * r - 1.0).abs());
        // Its points stay on the cylinder (chords of 20 points over 120°).
        assert!((e.p.xy().norm() - r).abs() < 0.05, "{}", e.p.xy().norm());
    }
    h_all.sort_by(Real::total_cmp);
    let median = (2.0 * h_all[h_all.len() / 2] * r - 1.0).abs();
    println!(
        "DS cylinder: relative curvature error worst {:.3} %, of the median {:.3} %",
        100.0 * worst,
        100.0 * median
    );
    assert!(median < 0.005, "median off by {:.2} %", 100.0 * median);
    assert!(worst < 0.02, "curvature off by {:.2} %", 100.0 * worst);
}

#[test]
fn ds_is_independent_of_drawing_order_and_direction() {
    let traces = cylinder_traces(50.0, &[0.0, 8.0, 20.0], 30);
    let a = DsSurface::new(&traces).unwrap();
    let mut shuffled = vec![traces[2].clone(), traces[0].clone(), traces[1].clone()];
    shuffled[1].reverse();
    let b = DsSurface::new(&shuffled).unwrap();
    for (u, v) in params() {
        assert!((a.at(u, v).p - b.at(u, v).p).norm() < 1e-9);
    }
    let resampled = a.resampled();
    assert_eq!(resampled.len(), 3);
    assert!(resampled.iter().all(|t| t.len() == DS_POINTS_PER_TRACE));
    // Equal arc-length steps on the middle trace.
    let steps: Vec<Real> = resampled[1]
        .windows(2)
        .map(|w| (w[1] - w[0]).norm())
        .collect();
    let spread = steps.iter().cloned().fold(0.0, Real::max)
        - steps.iter().cloned().fold(Real::INFINITY, Real::min);
    assert!(spread < 1e-2, "{spread}");
    assert_eq!(a.slices(), &[0.0, 8.0, 20.0]);
}

#[test]
fn ds_refuses_bad_traces_naming_them() {
    let good = cylinder_traces(50.0, &[0.0, 8.0, 20.0], 10);
    assert!(matches!(
        DsSurface::new(&good[..2]),
        Err(TraceError::TraceCount { got: 2, .. })
    ));
    let mut short = good.clone();
    short[1].truncate(2);
    assert!(matches!(
        DsSurface::new(&short),
        Err(TraceError::PointCount { trace: 1, got: 2 })
    ));
    // A coronal trace among axial ones.
    let mut mixed = good.clone();
    mixed[2] = (0..10)
        .map(|k| [Real::from(k), 5.0, Real::from(k) * 2.0])
        .collect();
    let e = DsSurface::new(&mixed).unwrap_err();
    assert!(
        matches!(e, TraceError::MixedOrientations { trace: 2, .. }),
        "{e}"
    );
    // Off any slice.
    let mut oblique = good.clone();
    oblique[0] = (0..10)
        .map(|k| [Real::from(k), Real::from(k), Real::from(k)])
        .collect();
    assert!(matches!(
        DsSurface::new(&oblique),
        Err(TraceError::NotOnSlice { trace: 0, .. })
    ));
    // A figure of eight.
    let mut eight = good.clone();
    eight[1] = vec![
        [0.0, 0.0, 8.0],
        [10.0, 10.0, 8.0],
        [10.0, 0.0, 8.0],
        [0.0, 10.0, 8.0],
    ];
    let e = DsSurface::new(&eight).unwrap_err();
    assert!(
        matches!(
            e,
            TraceError::SelfIntersecting {
                trace: 1,
                first: 0,
                second: 2
            }
        ),
        "{e}"
    );
    // Two traces on one slice.
    let mut same = good.clone();
    same[2] = same[0].iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
    assert!(matches!(
        DsSurface::new(&same),
        Err(TraceError::SameSlice { a: 0, b: 2, .. })
    ));
    let mut nan = good.clone();
    nan[0][3][1] = Real::NAN;
    assert!(matches!(
        DsSurface::new(&nan),
        Err(TraceError::NonFinite { trace: 0, point: 3 })
    ));
    let mut dot = good;
    dot[1] = vec![[1.0, 1.0, 8.0]; 4];
    assert!(matches!(
        DsSurface::new(&dot),
        Err(TraceError::NoLength { trace: 1 })
    ));
}

/// An ellipse where the plane through `c` with in-plane axes a, b meets an ellipsoid liver, as
/// two traces (a ring drawn in two strokes).
fn ring(c: Vec3, a: Vec3, b: Vec3) -> Vec<Vec<[Real; 3]>> {
    let arc = |t0: Real| -> Vec<[Real; 3]> {
        (0..=24)
            .map(|k| {
                let t = t0 + PI * Real::from(k) / 24.0;
                arr(c + a * t.cos() + b * t.sin())
            })
            .collect()
    };
    vec![arc(0.0), arc(PI)]
}

#[test]
fn cp_ring_on_a_plane_makes_that_plane_with_the_pca_extents() {
    let n = Vec3::new(0.2, -0.4, 0.9).normalize();
    let a = n.cross(&Vec3::x()).normalize();
    let b = n.cross(&a);
    let c = Vec3::new(10.0, -20.0, 35.0);
    let s = CpSurface::new(&ring(c, a * 70.0, b * 45.0), &[]).unwrap();
    assert!(s.normal().cross(&n).norm() < 1e-9);
    let [nu, nv] = s.dims();
    assert_eq!(nu, 31);
    // Square quads: the short side is 4√e₂ with e₂ ≈ 45²/2 (the ring's variance along b).
    let l2 = s.quad_mm() * 30.0;
    assert!((l2 - 4.0 * 45.0 / 2f64.sqrt()).abs() < 0.03 * l2, "{l2}");
    assert!(nv > (30.0 * 70.0 / 45.0) as usize);
    for (u, v) in params() {
        let e = s.at(u, v);
        assert!((n.dot(&(e.p - c))).abs() < 1e-6);
        assert!(e.mean_curvature().unwrap().abs() < 1e-6);
    }
}

#[test]
fn cp_fits_the_traces_and_smooths_between_them() {
    // A ring on a saddle z = (x² − y²)/200: the trace vertices take the ring's heights, the
    // others lie between the trace heights (a harmonic field has no interior extrema).
    let ring: Vec<[Real; 3]> = (0..=80)
        .map(|k| {
            let t = 2.0 * PI * Real::from(k) / 80.0;
            let (x, y) = (60.0 * t.cos(), 40.0 * t.sin());
            [x, y, (x * x - y * y) / 200.0]
        })
        .collect();
    let s = CpSurface::new(std::slice::from_ref(&ring), &[]).unwrap();
    let heights = ring
        .iter()
        .map(|p| Vec3::new(p[0], p[1], p[2]).dot(&s.normal()));
    let (lo, hi) = heights.fold((Real::INFINITY, Real::NEG_INFINITY), |(a, b), h| {
        (a.min(h), b.max(h))
    });
    let [nu, nv] = s.dims();
    for a in 0..nu {
        for b in 0..nv {
            let h = s.vertex(a, b).dot(&s.normal());
            assert!(h > lo - 1e-6 && h < hi + 1e-6, "vertex ({a}, {b}) at {h}");
        }
    }
    // Every ring point is within half a quad diagonal plus the slope of its nearest vertex.
    for p in ring {
        let p = Vec3::new(p[0], p[1], p[2]);
        let best = (0..nu * nv)
            .map(|k| (s.vertex(k / nv, k % nv) - p).norm())
            .fold(Real::INFINITY, Real::min);
        assert!(best < s.quad_mm(), "{best}");
    }
}

#[test]
fn cp_deformation_moves_the_peak_by_the_offset_and_nothing_beyond_its_radius() {
    let n = Vec3::z();
    let rings = ring(Vec3::zeros(), Vec3::x() * 80.0, Vec3::y() * 50.0);
    let flat = CpSurface::new(&rings, &[]).unwrap();
    let r = 25.0;
    let d = Deformation {
        point: [7.3, -4.1, 3.0],
        offset_mm: 6.5,
        radius_mm: r,
    };
    let bent = CpSurface::new(&rings, &[d]).unwrap();
    let [nu, nv] = flat.dims();
    let centre = (0..nu * nv)
        .min_by(|&x, &y| {
            let q = Vec3::new(7.3, -4.1, 0.0);
            let f = |k: usize| (flat.vertex(k / nv, k % nv) - q).norm();
            f(x).total_cmp(&f(y))
        })
        .unwrap();
    let c = flat.vertex(centre / nv, centre % nv);
    let mut moved = 0;
    for k in 0..nu * nv {
        let (p, q) = (flat.vertex(k / nv, k % nv), bent.vertex(k / nv, k % nv));
        let shift = (q - p).dot(&n).abs();
        assert!(
            (q - p).cross(&n).norm() < 1e-12,
            "moves only along the normal"
        );
        if (p - c).norm() >= r {
            assert_eq!(shift, 0.0, "vertex {k} beyond the radius moved");
        } else if shift > 0.0 {
            moved += 1;
        }
    }
    assert_eq!((bent.vertex(centre / nv, centre % nv) - c).norm(), 6.5);
    assert!(moved > 20);
}

#[test]
fn cp_refuses_collinear_traces_and_bad_deformations() {
    let line: Vec<[Real; 3]> = (0..10).map(|k| [Real::from(k) * 5.0, 0.0, 0.0]).collect();
    assert!(matches!(
        CpSurface::new(&[line], &[]),
        Err(TraceError::NoPlane(_))
    ));
    let rings = ring(Vec3::zeros(), Vec3::x() * 80.0, Vec3::y() * 50.0);
    let far = Deformation {
        point: [500.0, 0.0, 0.0],
        offset_mm: 5.0,
        radius_mm: 10.0,
    };
    let e = CpSurface::new(&rings, &[far]).unwrap_err();
    assert!(e.to_string().contains("beyond the cutting plane"), "{e}");
    let zero = Deformation {
        radius_mm: 0.0,
        ..far
    };
    assert!(matches!(
        CpSurface::new(&rings, &[far, zero]),
        Err(TraceError::Deformation { index: 1, .. })
    ));
}

#[test]
fn cp_fit_converges_quickly_on_a_long_plane() {
    // The longest plane allowed (about ten times its width), a wavy ring: the smoothing still
    // converges (no vertex moves in a further sweep beyond the tolerance) well within its cap.
    let ring: Vec<[Real; 3]> = (0..=200)
        .map(|k| {
            let t = 2.0 * PI * Real::from(k) / 200.0;
            [280.0 * t.cos(), 29.0 * t.sin(), 3.0 * (5.0 * t).sin()]
        })
        .collect();
    let t0 = std::time::Instant::now();
    let s = CpSurface::new(std::slice::from_ref(&ring), &[]).unwrap();
    let [nu, nv] = s.dims();
    assert_eq!(nu, 31);
    assert!(nv > 250, "{nv}");
    // Harmonic: every inner vertex away from the ring is the mean of its neighbours.
    let h = |a: usize, b: usize| s.vertex(a, b).dot(&s.normal());
    let off_ring = |a: usize, b: usize| {
        let (p, q) = (s.vertex(a, b), s.normal());
        ring.iter().all(|r| {
            let d = Vec3::new(r[0], r[1], r[2]) - p;
            (d - q * d.dot(&q)).norm() > 2.0 * s.quad_mm()
        })
    };
    let worst = (1..nu - 1)
        .flat_map(|a| (1..nv - 1).map(move |b| (a, b)))
        .filter(|&(a, b)| off_ring(a, b))
        .map(|(a, b)| {
            (h(a, b) - 0.25 * (h(a - 1, b) + h(a + 1, b) + h(a, b - 1) + h(a, b + 1))).abs()
        })
        .fold(0.0, Real::max);
    assert!(worst < 1e-6, "{worst}");
    println!("long CP plane {nu}×{nv} in {:?}", t0.elapsed());
}
