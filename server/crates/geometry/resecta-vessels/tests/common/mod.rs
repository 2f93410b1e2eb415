//! Synthetic tube trees and box livers shared by the integration tests.
#![allow(clippy::unwrap_used, dead_code)] // test helpers; each test file uses a part

use resecta_geom::{Grid, Mat3, Vec3, Volume};
use resecta_vessels::{RootChoice, VesselParams, VesselTree, vessel_tree};

pub fn mask(grid: &Grid, f: impl Fn(Vec3) -> bool) -> Volume<bool> {
    let data = (0..grid.len())
        .map(|o| f(grid.voxel_center(grid.ijk(o))))
        .collect();
    Volume::from_vec(grid.clone(), data).unwrap()
}

pub fn seg_dist(p: Vec3, a: Vec3, b: Vec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (a + ab * t - p).norm()
}

/// A grid centred on the world origin with the given half-extent (mm) along each of its axes.
pub fn centred_grid(spacing: [f64; 3], half: f64, direction: Mat3) -> Grid {
    let dims = spacing.map(|s| (2.0 * half / s).ceil() as usize + 1);
    let lin = direction * Mat3::from_diagonal(&Vec3::from(spacing));
    let centre = Vec3::new(
        (dims[0] - 1) as f64 / 2.0,
        (dims[1] - 1) as f64 / 2.0,
        (dims[2] - 1) as f64 / 2.0,
    );
    // Shift by a fraction of a voxel so that no plane of symmetry passes through voxel centres.
    let origin = -(lin * centre) + Vec3::new(0.137, -0.211, 0.093);
    Grid::new(dims, spacing, origin, direction).unwrap()
}

pub fn oblique() -> Mat3 {
    *nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vec3::new(1.0, 2.0, 3.0)),
        0.5,
    )
    .matrix()
}

pub fn diag(grid: &Grid) -> f64 {
    Vec3::from(grid.spacing()).norm()
}

/// A Y in the x–z plane: trunk up the z axis to the junction at the origin, two symmetric
/// branches at ±`angle` from z.
pub struct Y {
    pub trunk: (Vec3, Vec3, f64),
    pub left: (Vec3, Vec3, f64),
    pub right: (Vec3, Vec3, f64),
}

pub fn y_tree(trunk_len: f64, branch_len: f64, angle: f64) -> Y {
    let j = Vec3::zeros();
    let (s, c) = angle.sin_cos();
    Y {
        trunk: (Vec3::new(0.0, 0.0, -trunk_len), j, 3.2),
        left: (j, Vec3::new(-s, 0.0, c) * branch_len, 2.4),
        right: (j, Vec3::new(s, 0.0, c) * branch_len, 2.4),
    }
}

pub fn y_mask(grid: &Grid, y: &Y) -> Volume<bool> {
    mask(grid, |p| {
        [y.trunk, y.left, y.right]
            .iter()
            .any(|&(a, b, r)| seg_dist(p, a, b) <= r)
    })
}

pub fn in_box(p: Vec3, lo: Vec3, hi: Vec3) -> bool {
    (0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a])
}

pub struct YCase {
    pub grid: Grid,
    pub y: Y,
    pub lo: Vec3,
    pub hi: Vec3,
}

pub fn y_cases() -> Vec<YCase> {
    vec![
        YCase {
            grid: centred_grid([0.8, 1.0, 1.2], 26.0, Mat3::identity()),
            y: y_tree(22.0, 24.0, 0.7),
            lo: Vec3::new(-20.0, -9.0, 1.0),
            hi: Vec3::new(20.0, 9.0, 22.0),
        },
        YCase {
            grid: centred_grid([0.9, 1.0, 1.3], 26.0, oblique()),
            y: y_tree(18.0, 22.0, 0.7),
            lo: Vec3::new(-15.0, -8.0, 1.0),
            hi: Vec3::new(15.0, 8.0, 15.0),
        },
    ]
}

impl YCase {
    /// The Y's tree, rooted automatically.
    pub fn tree(&self) -> VesselTree {
        vessel_tree(
            &y_mask(&self.grid, &self.y),
            RootChoice::Auto,
            &VesselParams::default(),
        )
        .unwrap()
    }

    /// The box liver.
    pub fn liver(&self) -> Volume<bool> {
        mask(&self.grid, |p| in_box(p, self.lo, self.hi))
    }
}
