//! Files written by other tools (the fuzz seeds in `fuzz/seeds/`: NIfTI by nibabel 5, NRRD and
//! MHA by SimpleITK 2 in LPS) read to the geometry and values those tools report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

use std::path::PathBuf;

use resecta_geom::{Vec3, VoxelLimit};
use resecta_io::{VoxelData, read_image};

const LIMIT: VoxelLimit = VoxelLimit(1 << 30);

fn seed(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../../fuzz/seeds")
        .join(p)
}

#[test]
fn nibabel_nifti_oblique_affine_and_values() {
    // nibabel: Nifti1Image(arange(24).reshape(2,3,4), A) with A's rotation from (3,4,5) triples.
    for name in ["i16.nii", "i16.nii.gz", "u8.nii", "f32.nii.gz"] {
        let img = read_image(seed(&format!("image_nifti/{name}")), LIMIT).unwrap();
        assert_eq!(img.grid().dims(), [2, 3, 4]);
        let w = img.grid().index_to_world(Vec3::new(1.0, 1.0, 1.0));
        assert!(
            (w - Vec3::new(9.8, -3.28, 2.04)).norm() < 1e-6,
            "{name}: {w}"
        );
        // value(i, j, k) = 12 i + 4 j + k
        let o = img.grid().offset([1, 2, 3]);
        assert_eq!(img.data().get_f64(o), Some(23.0), "{name}");
        assert_eq!(img.data().get_f64(img.grid().offset([0, 1, 2])), Some(6.0));
    }
}

#[test]
fn simpleitk_nrrd_and_mha_lps_geometry_and_values() {
    // SimpleITK: size (4,3,2), spacing (0.5,0.7,2), origin LPS (1,2,3), direction rows
    // (0,-1,0),(1,0,0),(0,0,1); index (1,1,1) is LPS (0.3,2.5,5) = RAS (-0.3,-2.5,5).
    for name in [
        "image_nrrd/i16.nrrd",
        "image_metaimage/i16.mha",
        "image_metaimage/i16z.mha",
    ] {
        let img = read_image(seed(name), LIMIT).unwrap();
        assert_eq!(img.grid().dims(), [4, 3, 2], "{name}");
        let w = img.grid().index_to_world(Vec3::new(1.0, 1.0, 1.0));
        assert!(
            (w - Vec3::new(-0.3, -2.5, 5.0)).norm() < 1e-12,
            "{name}: {w}"
        );
        // GetImageFromArray(arange(24).reshape(2,3,4)): value(i, j, k) = 12 k + 4 j + i.
        let VoxelData::I16(v) = img.data() else {
            panic!("{name}")
        };
        assert_eq!(v[img.grid().offset([3, 2, 1])], 23);
        assert_eq!(v[img.grid().offset([1, 0, 1])], 13);
    }
}
