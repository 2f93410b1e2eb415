//! Margins true to the segmentation: the reported minimum never exceeds the distance from the cut
//! to the nearest tumour voxel centre, and never falls below the distance to the union of the
//! tumour's voxel cubes by more than 0.05 mm — on the analytic sphere of issue #17 and on random
//! tumour masks cut by random planes, on oblique anisotropic grids.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;

use resecta_geom::{LabelMap, Mat3, Real, RoleMap, Vec3};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::{Anatomy, Plan, PlanEvent, Planner, Resection};

/// Below the distance to the voxel cubes by at most this (mm).
const BELOW_CUBES_MM: Real = 0.05;

fn spec(tumours: Vec<SphereSpec>) -> PhantomSpec {
    PhantomSpec {
        grid: GridSpec::centred(
            [130, 110, 36],
            [0.9, 0.9, 2.5],
            [0.0, 0.0, 0.0],
            Orientation::EulerDeg([0.0, 0.0, 20.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.0, 0.0, 0.0],
            radii: [55.0, 45.0, 40.0],
            rotation: Orientation::default(),
        }],
        tumors: tumours,
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    }
}

/// A planar 4×4 resection through `origin` with unit normal `n`, ±`half` mm across.
fn plane(origin: Vec3, n: Vec3, half: Real) -> Resection {
    let a = if n.x.abs() < 0.9 {
        Vec3::x()
    } else {
        Vec3::y()
    };
    let e1 = n.cross(&a).normalize();
    let e2 = n.cross(&e1);
    let pts = (0..16)
        .map(|k| {
            let (s, t) = ((k / 4) as Real / 3.0 - 0.5, (k % 4) as Real / 3.0 - 0.5);
            let p = origin + e1 * (2.0 * half * s) + e2 * (2.0 * half * t);
            [p.x, p.y, p.z]
        })
        .collect();
    let mut r = Resection::new("r", [4, 4], pts);
    r.resolution = [60, 60];
    r
}

struct Case {
    anatomy: Arc<Anatomy>,
    centres: Vec<Vec3>,
    cell: Mat3,
}

fn case(labels: &LabelMap) -> Case {
    let roles = RoleMap::default();
    let g = labels.grid();
    let centres = (0..g.len())
        .filter(|&k| labels.data()[k] == 2)
        .map(|k| g.voxel_center(g.ijk(k)))
        .collect();
    Case {
        anatomy: Arc::new(Anatomy::new(labels, &roles).unwrap()),
        centres,
        cell: g.linear(),
    }
}

/// (reported minimum, its uncertainty, distance to the nearest voxel centre, to the cubes) for
/// the plane at `gap` mm below the nearest tumour voxel centre along `n`.
fn measure(c: &Case, n: Vec3, gap: Real) -> (Real, Real, Real, Real) {
    let nearest = c
        .centres
        .iter()
        .map(|p| n.dot(p))
        .fold(Real::INFINITY, Real::min);
    let offset = nearest - gap;
    let centroid = c.centres.iter().sum::<Vec3>() / c.centres.len() as Real;
    let origin = centroid - n * (n.dot(&centroid) - offset);
    let mut plan = Plan::new(RoleMap::default());
    plan.apply(&PlanEvent::AddResection {
        resection: plane(origin, n, 40.0),
    })
    .unwrap();
    let p = Planner::new(Arc::clone(&c.anatomy), plan).unwrap();
    let v = &p.state("r").unwrap().verdict;
    let h = 0.5 * (0..3).map(|i| n.dot(&c.cell.column(i)).abs()).sum::<Real>();
    (
        v.min_margin_mm.unwrap(),
        v.margin_uncertainty_mm.unwrap(),
        gap,
        gap - h,
    )
}

fn assert_true_to_segmentation(
    what: &str,
    (got, uncertainty, centre, cubes): (Real, Real, Real, Real),
) {
    assert!(
        got <= centre,
        "{what}: reported {got} > nearest voxel centre {centre}"
    );
    assert!(
        got >= cubes - BELOW_CUBES_MM,
        "{what}: reported {got} < voxel cubes {cubes} − {BELOW_CUBES_MM}"
    );
    // What the uncertainty promises: the nearest voxel centre is at most that much farther
    // (along a plane's normal a cube's centre lies half its extent beyond its nearest corner).
    // Where the cut touches the cubes the direction, and so the figure, is undefined.
    assert!(
        got < 0.05 || centre <= got + uncertainty + 0.02,
        "{what}: {got} + uncertainty {uncertainty} < centre {centre}"
    );
}

/// Label map of the liver of [`spec`] with a tumour (label 2) where `inside(p)`.
fn with_tumour(inside: impl Fn(Vec3) -> bool) -> LabelMap {
    let mut labels = generate(&spec(vec![])).unwrap().labels;
    let g = labels.grid().clone();
    for k in 0..g.len() {
        if inside(g.voxel_center(g.ijk(k))) {
            labels.data_mut()[k] = 2;
        }
    }
    labels
}

/// The support function of an analytic tumour: the largest n·x over it.
type Support = Box<dyn Fn(&Vec3) -> Real>;

#[test]
fn analytic_tumours_cut_3_mm_away() {
    // Spheres of several sizes and a rotated ellipsoid on 0.9×0.9×2.5 mm voxels turned 20°
    // (the sphere of radius 12 is issue #17's), flat cuts 3.0 mm from the analytic surface.
    let centre = Vec3::new(10.0, 5.0, 0.0);
    let axes = Mat3::from_diagonal(&Vec3::new(16.0, 9.0, 6.0));
    let turn = Mat3::new(0.8, -0.6, 0.0, 0.6, 0.8, 0.0, 0.0, 0.0, 1.0);
    let shapes: Vec<(String, LabelMap, Support)> = [6.0, 12.0, 20.0]
        .into_iter()
        .map(|r: Real| {
            let labels = with_tumour(|p| (p - centre).norm() <= r);
            let support: Support = Box::new(move |n| n.dot(&centre) + r);
            (format!("sphere r {r}"), labels, support)
        })
        .chain(std::iter::once({
            let m = turn * axes; // columns: the semi-axes
            let inv = m.try_inverse().unwrap();
            let labels = with_tumour(|p| (inv * (p - centre)).norm() <= 1.0);
            let support: Support = Box::new(move |n| n.dot(&centre) + (m.transpose() * n).norm());
            ("ellipsoid 16×9×6".to_owned(), labels, support)
        }))
        .collect();
    for (name, labels, support) in &shapes {
        let c = case(labels);
        for n in [
            -Vec3::x(),
            Vec3::y(),
            Vec3::new(-1.0, -1.0, 0.3).normalize(),
        ] {
            // The tumour lies on the side of -n from the cut: measure along m = -n.
            let m = -n;
            let to_centres = c
                .centres
                .iter()
                .map(|q| m.dot(q))
                .fold(Real::INFINITY, Real::min);
            let analytic_plane = -support(&n) - 3.0; // m·x at the cut
            let gap = to_centres - analytic_plane;
            let r = measure(&c, m, gap);
            let what = format!("{name}, normal {:?}", m.as_slice());
            assert_true_to_segmentation(&what, r);
            let h = r.2 - r.3;
            assert!(
                r.0 >= 3.0 - h - 1e-9 && r.0 <= 3.0 + h,
                "{what}: {} vs 3.0 ± {h}",
                r.0
            );
            println!(
                "{what}: reported {:.3} mm (analytic 3.000, nearest centre {:.3}, ± {:.3})",
                r.0, r.2, r.1
            );
        }
    }
}

/// xorshift: deterministic and dependency-free.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> Real {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as Real / (1u64 << 53) as Real
    }
}

#[test]
fn random_tumour_masks_and_random_cuts() {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let base = generate(&spec(vec![])).unwrap().labels;
    let g = base.grid().clone();
    for mask in 0..6 {
        // A tumour of 1–3 overlapping balls with ragged voxels at its border.
        let mut labels = base.clone();
        let centre = Vec3::new(
            rng.next() * 20.0 - 10.0,
            rng.next() * 16.0 - 8.0,
            rng.next() * 10.0 - 5.0,
        );
        let balls: Vec<(Vec3, Real)> = (0..1 + mask % 3)
            .map(|_| {
                let off = Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5) * 10.0;
                (centre + off, 3.0 + 6.0 * rng.next())
            })
            .collect();
        for k in 0..g.len() {
            let p = g.voxel_center(g.ijk(k));
            let d = balls
                .iter()
                .map(|(c, r)| (p - c).norm() - r)
                .fold(Real::INFINITY, Real::min);
            if d < 0.0 || (d < 1.5 && rng.next() < 0.3) {
                labels.data_mut()[k] = 2;
            }
        }
        let c = case(&labels);
        for cut in 0..6 {
            let n = Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5).normalize();
            let gap = 1.0 + 12.0 * rng.next();
            assert_true_to_segmentation(&format!("mask {mask} cut {cut}"), measure(&c, n, gap));
        }
    }
}
