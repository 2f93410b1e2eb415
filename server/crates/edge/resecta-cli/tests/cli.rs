//! The `resecta` binary's contract: `--json` prints exactly one JSON object on stdout, bad input
//! exits 2 with an error naming what is wrong. (Building this test also builds `target/debug/resecta`,
//! which the Python end-to-end suites run.)
#![allow(clippy::expect_used)] // test helpers

use std::path::Path;
use std::process::{Command, Output};

fn resecta(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_resecta"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("resecta runs")
}

fn one_json_object(out: &Output) -> serde_json::Value {
    let stdout = String::from_utf8(out.stdout.clone()).expect("utf-8 stdout");
    let mut values = serde_json::Deserializer::from_str(&stdout).into_iter::<serde_json::Value>();
    let first = values.next().expect("one JSON value").expect("valid JSON");
    assert!(
        values.next().is_none(),
        "more than one JSON value on stdout: {stdout}"
    );
    assert!(first.is_object(), "stdout is not a JSON object: {stdout}");
    first
}

#[test]
fn phantom_then_info_agree_on_the_label_volumes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = resecta(
        &["phantom", "--preset", "small", "--out", "p", "--json"],
        dir.path(),
    );
    assert!(
        out.status.success(),
        "phantom failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let phantom = one_json_object(&out);
    let roles = phantom["roles"].as_object().expect("roles");
    let ml = |role: &str, key: &str| roles[role][key].as_f64().expect("a number");
    // The voxelised liver is its analytic volume to within the partial voxels of its boundary.
    let (analytic, voxelised) = (
        ml("parenchyma", "analytic_ml"),
        ml("parenchyma", "voxelised_ml"),
    );
    assert!(
        (voxelised - analytic).abs() < 0.01 * analytic,
        "{voxelised} vs {analytic}"
    );

    let labels = phantom["labels_file"].as_str().expect("labels_file");
    let info = one_json_object(&resecta(&["info", labels, "--json"], dir.path()));
    assert_eq!(info["dims"], phantom["dims"]);
    let mut from_info: Vec<f64> = info["labels"]
        .as_array()
        .expect("labels")
        .iter()
        .map(|l| l["ml"].as_f64().expect("ml"))
        .collect();
    let mut from_phantom: Vec<f64> = roles
        .values()
        .map(|r| r["voxelised_ml"].as_f64().expect("ml"))
        .collect();
    from_info.sort_by(f64::total_cmp);
    from_phantom.sort_by(f64::total_cmp);
    assert_eq!(from_info.len(), from_phantom.len());
    for (a, b) in from_info.iter().zip(&from_phantom) {
        // The file stores the grid in f32.
        assert!(
            (a - b).abs() < 1e-6 * b,
            "{from_info:?} vs {from_phantom:?}"
        );
    }
}

#[test]
fn a_file_that_is_not_an_image_is_bad_input() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("junk.nii.gz"), b"not a nifti file").expect("write");
    let out = resecta(&["info", "junk.nii.gz", "--json"], dir.path());
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty(), "nothing on stdout on error");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("resecta: error:") && stderr.contains("junk.nii.gz"),
        "{stderr}"
    );
}
