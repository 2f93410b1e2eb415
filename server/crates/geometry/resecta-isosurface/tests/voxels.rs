//! The voxel boundary against the union of voxel cubes computed directly, on oblique anisotropic
//! grids.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use resecta_geom::{Grid, Mat3, MeshBvh, Vec3, Volume};
use resecta_isosurface::voxel_boundary;

fn oblique_grid(dims: [usize; 3], spacing: [f64; 3]) -> Grid {
    let r = nalgebra_rotation(0.35, -0.2, 0.5);
    Grid::new(dims, spacing, Vec3::new(3.0, -7.0, 11.0), r).unwrap()
}

fn nalgebra_rotation(ax: f64, ay: f64, az: f64) -> Mat3 {
    let rx = Mat3::new(
        1.0,
        0.0,
        0.0,
        0.0,
        ax.cos(),
        -ax.sin(),
        0.0,
        ax.sin(),
        ax.cos(),
    );
    let ry = Mat3::new(
        ay.cos(),
        0.0,
        ay.sin(),
        0.0,
        1.0,
        0.0,
        -ay.sin(),
        0.0,
        ay.cos(),
    );
    let rz = Mat3::new(
        az.cos(),
        -az.sin(),
        0.0,
        az.sin(),
        az.cos(),
        0.0,
        0.0,
        0.0,
        1.0,
    );
    rz * ry * rx
}

/// A small deterministic generator (no dependency): xorshift.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Distance from `p` to the union of the inside voxels' cubes, one box at a time.
fn distance_to_cubes(mask: &Volume<bool>, p: Vec3) -> f64 {
    let g = mask.grid();
    let local = g.world_to_index(p);
    let axes = g.linear();
    let mut best = f64::INFINITY;
    let [nx, ny, _] = g.dims();
    for (k, _) in mask.data().iter().enumerate().filter(|(_, b)| **b) {
        let c = [k % nx, (k / nx) % ny, k / (nx * ny)];
        // Clamp the index-space offset to the cube, then measure in RAS.
        let d = Vec3::from_fn(|a, _| {
            let o = local[a] - c[a] as f64;
            o - o.clamp(-0.5, 0.5)
        });
        best = best.min((axes * d).norm());
    }
    best
}

#[test]
fn one_voxel_and_a_box_are_their_cubes() {
    let spacing = [0.9, 0.7, 2.5];
    let g = oblique_grid([5, 6, 7], spacing);
    let mut one = Volume::filled(g.clone(), false);
    one.set([2, 3, 4], true);
    let m = voxel_boundary(&one).unwrap();
    assert_eq!(m.triangles().len(), 12);
    let v = g.voxel_volume_mm3();
    assert!(
        (m.enclosed_volume() - v).abs() < 1e-9 * v,
        "{}",
        m.enclosed_volume()
    );
    let [a, b, c] = spacing;
    assert!((m.area() - 2.0 * (a * b + b * c + c * a)).abs() < 1e-9);
    let mut block = Volume::filled(g.clone(), false);
    for k in 1..6 {
        for j in 1..5 {
            for i in 1..4 {
                block.set([i, j, k], true);
            }
        }
    }
    let m = voxel_boundary(&block).unwrap();
    assert_eq!(m.triangles().len(), 12, "coplanar faces are merged");
    assert!((m.enclosed_volume() - 60.0 * v).abs() < 1e-9 * v);
}

#[test]
fn random_masks_are_bounded_by_their_cubes_exactly() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for case in 0..12 {
        let dims = [6 + case % 3, 5 + case % 4, 4 + case % 2];
        let g = oblique_grid(dims, [0.9, 1.1, 2.5]);
        let n = dims.iter().product::<usize>();
        let fill = 0.2 + 0.5 * rng.next();
        // Masks touching the lattice border too: the border is outside.
        let data: Vec<bool> = (0..n).map(|_| rng.next() < fill).collect();
        let count = data.iter().filter(|&&b| b).count();
        let mask = Volume::from_vec(g.clone(), data).unwrap();
        let m = voxel_boundary(&mask).unwrap();
        let v = count as f64 * g.voxel_volume_mm3();
        assert!(
            (m.enclosed_volume() - v).abs() < 1e-9 * v.max(1.0),
            "case {case}: volume {} vs {v}",
            m.enclosed_volume()
        );
        let bvh = MeshBvh::new(&m).unwrap();
        let (lo, hi) = g.world_bounds();
        for _ in 0..200 {
            let t = Vec3::from_fn(|_, _| -0.3 + 1.6 * rng.next());
            let p = lo + (hi - lo).component_mul(&t);
            let want = distance_to_cubes(&mask, p);
            if want == 0.0 {
                continue; // inside a cube: the surface distance is the depth, not 0
            }
            let got = bvh.closest_point(&p).unwrap().distance;
            assert!(
                (got - want).abs() < 1e-9,
                "case {case} at {p:?}: {got} vs {want}"
            );
        }
    }
}
