//! Shared fixtures of the image tests.
#![allow(dead_code)]

use std::path::PathBuf;

use resecta_geom::{Grid, Mat3, Mat4, Vec3, VoxelLimit};
use resecta_io::{Image, VoxelData};

/// An oblique, anisotropic grid whose affine entries are dyadic, hence exact in `f32` (NIfTI)
/// as well as `f64`: rotation from (3,4,5) triples, spacing 25/32, 25/16, 25/8 mm.
pub fn oblique_grid() -> Grid {
    let rz = Mat3::new(0.6, -0.8, 0.0, 0.8, 0.6, 0.0, 0.0, 0.0, 1.0);
    let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, 0.6, -0.8, 0.0, 0.8, 0.6);
    let lin = rz * rx * Mat3::from_diagonal(&Vec3::new(25.0 / 32.0, 25.0 / 16.0, 25.0 / 8.0));
    // Round to the dyadic values the products approximate.
    let lin = lin.map(|v| (v * 1024.0).round() / 1024.0);
    let mut a = Mat4::identity();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&lin);
    a.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&Vec3::new(-100.5, 37.25, 12.125));
    Grid::from_affine([7, 5, 4], &a, VoxelLimit::default()).unwrap()
}

/// A general oblique grid (irrational rotation), exact only in `f64` formats.
pub fn general_grid() -> Grid {
    let (a, b, c) = (0.3f64, -0.2f64, 0.7f64);
    let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
    let ry = Mat3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rz = Mat3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
    let r = rz * ry * rx;
    Grid::new([6, 4, 3], [0.7, 0.9, 2.3], Vec3::new(-12.3, 45.6, -7.89), r).unwrap()
}

/// Distinct values of every scalar type on `grid`.
pub fn all_types(grid: &Grid) -> Vec<Image> {
    let n = grid.len();
    let data = [
        VoxelData::U8((0..n).map(|i| (i * 7 % 256) as u8).collect()),
        VoxelData::I8((0..n).map(|i| (i as i64 * 7 % 256 - 128) as i8).collect()),
        VoxelData::U16((0..n).map(|i| (i * 997 % 65536) as u16).collect()),
        VoxelData::I16((0..n).map(|i| (i as i64 * 331 - 20000) as i16).collect()),
        VoxelData::U32(
            (0..n)
                .map(|i| (i as u32).wrapping_mul(40_000_017))
                .collect(),
        ),
        VoxelData::I32((0..n).map(|i| (i as i32 - 50) * 1_000_003).collect()),
        VoxelData::F32((0..n).map(|i| i as f32 * 0.37 - 11.0).collect()),
        VoxelData::F64((0..n).map(|i| (i as f64).sqrt() - 3.1).collect()),
    ];
    data.into_iter()
        .map(|d| Image::new(grid.clone(), d).unwrap())
        .collect()
}

/// Asserts same dims, affine within `tol` mm, and identical data.
pub fn assert_same(a: &Image, b: &Image, tol: f64) {
    assert_eq!(a.grid().dims(), b.grid().dims());
    let d = (a.grid().affine() - b.grid().affine()).abs().max();
    assert!(
        d <= tol,
        "affines differ by {d}:\n{}\n{}",
        a.grid().affine(),
        b.grid().affine()
    );
    assert_eq!(a.data(), b.data());
}

/// `shared/test-data` beside the repository, if present.
pub fn test_data() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../../../shared/test-data");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("SKIP: {} not found", p.display());
        None
    }
}
