//! Reading the real files of `shared/test-data` (skipped with a message when absent). Expected
//! values were taken with nibabel 5 and SimpleITK 2 (ITK LPS converted to RAS by negating x, y)
//! and hard-coded here; the affines agree with both to the last printed digit.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

mod image_common;

use std::collections::BTreeMap;

use image_common::test_data;
use resecta_geom::{Mat4, VoxelLimit};
use resecta_io::{ScalarType, read_image, read_label_map};

const LIMIT: VoxelLimit = VoxelLimit(1 << 30);

fn diag_affine(s: [f64; 3], o: [f64; 3]) -> Mat4 {
    let mut m = Mat4::identity();
    for k in 0..3 {
        m[(k, k)] = s[k];
        m[(k, 3)] = o[k];
    }
    m
}

fn assert_affine(got: &Mat4, want: &Mat4) {
    let d = (got - want).abs().max();
    assert!(d < 1e-9, "affine off by {d}:\n{got}\n{want}");
}

#[test]
fn totalsegmentator_ct_and_segmentations() {
    let Some(root) = test_data() else { return };
    let dir = root.join("liver/totalsegmentator-example");
    let affine = diag_affine(
        [3.0; 3],
        [-177.95632934570312, 11.319000244140625, 94.3017578125],
    );
    // (file, dims, type, min, max, sum, value at (60,50,20))
    let cases = [
        (
            "example_ct.nii.gz",
            [122, 101, 112],
            ScalarType::I32,
            -1207.0,
            3382.0,
            -496_851_173i64,
            12.0,
        ),
        (
            "example_ct_sm.nii.gz",
            [122, 101, 30],
            ScalarType::I16,
            -1100.0,
            1207.0,
            -130_894_872,
            -40.0,
        ),
        (
            "example_seg_v1_on_ct.nii.gz",
            [122, 101, 112],
            ScalarType::U8,
            0.0,
            104.0,
            20_930_678,
            104.0,
        ),
        // This one has 12,816 bytes of header extensions (vox_offset 13168).
        (
            "example_seg_v2_on_ct_sm.nii.gz",
            [122, 101, 30],
            ScalarType::U8,
            0.0,
            117.0,
            2_734_697,
            0.0,
        ),
        (
            "v1_liver.nii.gz",
            [122, 101, 112],
            ScalarType::U8,
            0.0,
            1.0,
            41_733,
            0.0,
        ),
        (
            "v1_inferior_vena_cava.nii.gz",
            [122, 101, 112],
            ScalarType::U8,
            0.0,
            1.0,
            2_281,
            0.0,
        ),
        (
            "v1_portal_vein_and_splenic_vein.nii.gz",
            [122, 101, 112],
            ScalarType::U8,
            0.0,
            1.0,
            1_129,
            0.0,
        ),
    ];
    for (name, dims, ty, lo, hi, sum, v) in cases {
        let img = read_image(dir.join(name), LIMIT).unwrap();
        assert_eq!(img.grid().dims(), dims, "{name}");
        assert_eq!(img.data().scalar_type(), ty, "{name}");
        assert_affine(&img.grid().affine(), &affine);
        assert_eq!(img.value_range(), Some((lo, hi)), "{name}");
        let total: f64 = img.data().to_f64().iter().sum();
        assert_eq!(total, sum as f64, "{name}");
        let o = img.grid().offset([60, 50, 20]);
        assert_eq!(img.data().get_f64(o), Some(v), "{name}");
        assert_eq!(
            img.data().get_f64(img.grid().offset([1, 2, 3])),
            Some(if ty.is_integral() && lo < 0.0 {
                -1023.0
            } else {
                0.0
            })
        );
    }
    // The CT is not a label map (negative values).
    assert!(read_label_map(dir.join("example_ct.nii.gz"), LIMIT).is_err());
}

#[test]
fn msd_hepatic_vessel_labels_and_liver_predictions() {
    let Some(root) = test_data() else { return };
    let dir = root.join("liver/msd-task08-hepaticvessel");
    // (case, nz, pixdim xy, pixdim z, origin xy, counts of label 1 and 2, liver voxels)
    let cases = [
        (
            "002",
            66,
            0.9511719942092896,
            3.75,
            -486.04888916015625,
            37_167,
            21_068,
            601_655,
        ),
        ("008", 47, 0.84375, 5.0, -431.15625, 23_874, 15_234, 441_650),
        (
            "010",
            49,
            0.8613280057907104,
            4.0,
            -440.13861083984375,
            29_223,
            15_537,
            441_033,
        ),
    ];
    for (case, nz, pxy, pz, o, vessel, tumour, liver) in cases {
        let affine = diag_affine([pxy, pxy, pz], [o, o, 0.0]);
        let label = read_label_map(
            dir.join(format!("hepaticvessel_{case}_label.nii.gz")),
            LIMIT,
        )
        .unwrap();
        assert_eq!(label.grid().dims(), [512, 512, nz]);
        assert_affine(&label.grid().affine(), &affine);
        let n = 512 * 512 * nz as u64;
        let want: BTreeMap<u16, u64> = [(0, n - vessel - tumour), (1, vessel), (2, tumour)].into();
        assert_eq!(label.value_counts(), want, "case {case}");
        let pred = read_label_map(
            dir.join(format!("hepaticvessel_{case}_liver_pred.nii.gz")),
            LIMIT,
        )
        .unwrap();
        assert_affine(&pred.grid().affine(), &affine);
        let want: BTreeMap<u16, u64> = [(0, n - liver), (1, liver)].into();
        assert_eq!(pred.value_counts(), want, "case {case}");
    }
}

#[test]
fn lasc_metaimage_label_map() {
    let Some(root) = test_data() else { return };
    let path = root.join("heart/lasc2013-b002/gt_std.mhd");
    let img = read_image(&path, LIMIT).unwrap();
    assert_eq!(img.data().scalar_type(), ScalarType::U8);
    let g = img.grid();
    assert_eq!(g.dims(), [320, 320, 140]);
    assert_eq!(g.spacing(), [1.25, 1.25, 1.37]);
    // Identity TransformMatrix in ITK's LPS world → RAS x and y negated.
    assert_affine(&g.affine(), &diag_affine([-1.25, -1.25, 1.37], [0.0; 3]));
    let counts = img.to_label_map().unwrap().value_counts();
    let want: BTreeMap<u16, u64> = [
        (0, 14_281_679),
        (36, 50_920),
        (37, 431),
        (76, 898),
        (77, 1_324),
        (78, 305),
        (79, 443),
    ]
    .into();
    assert_eq!(counts, want);
}

#[test]
fn real_files_respect_a_small_voxel_limit() {
    let Some(root) = test_data() else { return };
    let small = VoxelLimit(1_000_000);
    let e = read_image(root.join("heart/lasc2013-b002/gt_std.mhd"), small).unwrap_err();
    assert!(e.to_string().contains("gt_std.mhd"), "{e}");
    assert!(
        read_image(
            root.join("liver/totalsegmentator-example/v1_liver.nii.gz"),
            small
        )
        .is_err()
    );
}
