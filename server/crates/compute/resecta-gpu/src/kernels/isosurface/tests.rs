//! [`GpuClassifier`] against `CpuClassifier`: identical classes and row states on lattices with
//! and without a closed border, across slabs, with non-finite values flagged; meshes extracted
//! with either are identical.

use resecta_isosurface::{CpuClassifier, NodeClassifier, Options, extract, extract_with};

use super::GpuClassifier;
use crate::device::testing::context;

/// A wavy blob with values exactly at the iso-value here and there.
fn lattice(dims: [usize; 3]) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    (0..nx * ny * nz)
        .map(|n| {
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            let p = [i, j, k].map(|x| x as f32);
            let c = [nx, ny, nz].map(|d| d as f32 / 2.0);
            let r2: f32 = (0..3).map(|a| ((p[a] - c[a]) / c[a]).powi(2)).sum();
            if n % 97 == 0 {
                0.5
            } else {
                1.0 - r2 + 0.1 * (p[0] * 0.7).sin()
            }
        })
        .collect()
}

#[test]
fn classes_and_meshes_equal_the_cpu() {
    let Some(ctx) = context() else { return };
    let gpu = GpuClassifier::new(&ctx);
    for dims in [[2, 2, 2], [17, 9, 5], [61, 47, 33]] {
        let values = lattice(dims);
        for close_border in [false, true] {
            let o = Options { close_border };
            let want = CpuClassifier.classify(dims, &values, 0.5, o).unwrap();
            let got = gpu.classes(dims, &values, 0.5, o).unwrap();
            assert_eq!(got, want, "{dims:?} close {close_border}");
            let a = extract(dims, &values, 0.5, o).unwrap();
            let b = extract_with(dims, &values, 0.5, o, &gpu).unwrap();
            assert_eq!(a.vertices(), b.vertices());
            assert_eq!(a.triangles(), b.triangles());
        }
    }
}

#[test]
fn slabs_and_non_finite_values_equal_the_cpu() {
    let Some(ctx) = context() else { return };
    let dims = [33, 21, 40];
    let mut values = lattice(dims);
    values[5 + 33 * (3 + 21 * 31)] = f32::NAN;
    values[7 + 33 * (20 + 21 * 2)] = f32::INFINITY;
    // Slabs of 3 planes (the last one shorter).
    let gpu = GpuClassifier::new(&ctx).with_slab_bytes(3 * 33 * 21 * 4 + 5);
    let o = Options::default();
    let want = CpuClassifier.classify(dims, &values, 0.5, o).unwrap();
    assert_eq!(gpu.classes(dims, &values, 0.5, o).unwrap(), want);
    assert_eq!(want.rows.iter().filter(|&&s| s & 4 != 0).count(), 2);
    // The non-finite value is refused naming it, whichever classifies.
    let (a, b) = (
        extract(dims, &values, 0.5, o).unwrap_err(),
        extract_with(dims, &values, 0.5, o, &gpu).unwrap_err(),
    );
    assert_eq!(a, b);
}
