#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Oriented points and a depth-7 solve on real liver masks (skipped when the data is absent).

mod common;

use std::path::PathBuf;

use resecta_geom::{Volume, VoxelLimit};
use resecta_poisson::{PoissonParams, oriented_points, solve};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../../../shared/test-data/liver")
}

#[test]
fn real_livers_at_depth_7() {
    let files = [
        "totalsegmentator-example/v1_liver.nii.gz",
        "msd-task08-hepaticvessel/hepaticvessel_002_liver_pred.nii.gz",
    ];
    for name in files {
        let path = data_dir().join(name);
        if !path.exists() {
            eprintln!("SKIP: {} not found", path.display());
            continue;
        }
        let labels = resecta_io::read_label_map(&path, VoxelLimit::default()).unwrap();
        let mask: Volume<bool> = labels.map(|l| l != 0);
        let pts = oriented_points(&mask).unwrap();
        let params = PoissonParams::default();
        let f = solve(&pts, &params).unwrap();
        let vol = common::enclosed_volume(&f, 2);
        let rel = vol / common::mask_volume(&mask) - 1.0;
        eprintln!(
            "{name}: {} points, residuals {:?}, volume error {:+.2} %",
            pts.len(),
            f.report.residuals,
            100.0 * rel
        );
        assert!(pts.len() > 5_000);
        assert!(*f.report.residuals.last().unwrap() <= params.tolerance);
        assert!(f.values.iter().all(|v| v.is_finite()));
        // Every sample is near the iso-surface: |χ(p) − iso| well below the jump of 1.
        let off = pts
            .positions
            .iter()
            .map(|p| (f.value_at(*p).unwrap() - f.iso).abs())
            .sum::<f32>()
            / pts.len() as f32;
        assert!(off < 0.15, "mean |χ − iso| at samples {off}");
        assert!(rel.abs() < 0.02, "volume error {rel}");
    }
}
