//! Reading real VTP files (LASC'13 left-atrium surfaces and centrelines) from `shared/test-data`.
//! Expected counts and values were cross-checked with an independent Python reader (xml +
//! base64 + zlib from the standard library).

// Test helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use resecta_io::{ErrorKind, read_mesh};

fn data(rel: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../../../shared/test-data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("SKIP: {} not found", p.display());
        None
    }
}

/// atrium.vtp: inline base64, zlib, UInt32 headers, Float32 points, Int64 cells.
#[test]
fn atrium_vtp_counts_and_topology() {
    let Some(p) = data("heart/vampy-lasc2013-b003/atrium.vtp") else {
        return;
    };
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.vertices().len(), 10_516);
    assert_eq!(m.triangles().len(), 20_576);
    // First point, as f32 widened exactly (Python: 218.14144897460938, 174.40997314453125, ...).
    let v0 = m.vertices()[0];
    assert_eq!(
        [v0.x, v0.y, v0.z],
        [218.14144897460938, 174.40997314453125, 66.55340576171875]
    );
    assert!(
        m.scalars().is_empty(),
        "cell data must not become point scalars"
    );
    let r = m.report();
    // Prepared for CFD: the four pulmonary-vein inlets and the mitral outlet are cut open
    // (Python: 462 boundary edges, Euler characteristic V - E + F = -3, i.e. 5 holes).
    assert!(!r.watertight, "{r:?}");
    assert_eq!(r.boundary_edges, 462, "{r:?}");
    assert_eq!(r.degenerate_triangles, 0, "{r:?}");
    assert_eq!(r.non_manifold_edges, 0, "{r:?}");
    assert_eq!(r.inconsistent_edges, 0, "{r:?}");
    eprintln!("atrium.vtp report: {r:?}");
}

/// gt_*_mesh.vtp: appended base64, zlib, no header_type (UInt32), Float64 point labels.
#[test]
fn lasc_ground_truth_meshes() {
    // (file, points, triangles, label sum, first point, boundary edges); Python found the
    // clipped surface open (663 boundary edges, 6 holes) and the unclipped one closed (χ = 2).
    for (file, nv, nt, label_sum, first, boundary) in [
        (
            "gt_std_mesh.vtp",
            11_355,
            22_055,
            493_066.0,
            [193.31822204589844, 180.2144317626953, 78.07777404785156],
            663,
        ),
        (
            "gt_noclip_mesh.vtp",
            13_354,
            26_704,
            592_930.0,
            [194.17100524902344, 180.77099609375, 77.80989837646484],
            0,
        ),
    ] {
        let Some(p) = data(&format!("heart/lasc2013-b002/{file}")) else {
            return;
        };
        let m = read_mesh(&p).unwrap();
        assert_eq!(m.vertices().len(), nv, "{file}");
        assert_eq!(m.triangles().len(), nt, "{file}");
        let v0 = m.vertices()[0];
        assert_eq!([v0.x, v0.y, v0.z], first, "{file}");
        let labels = &m.scalars()["autolabels"];
        assert_eq!(labels.iter().sum::<f64>(), label_sum, "{file}");
        assert!(labels.iter().all(|&l| (36.0..=79.0).contains(&l)), "{file}");
        let r = m.report();
        eprintln!("{file} report: {r:?}");
        assert_eq!(r.non_manifold_edges, 0, "{file}: {r:?}");
        assert_eq!(r.boundary_edges, boundary, "{file}: {r:?}");
        assert_eq!(r.watertight, boundary == 0, "{file}: {r:?}");
    }
}

/// Centrelines hold one polyline and no polygons: refused with a clear mesh error.
#[test]
fn centrelines_are_refused_as_surfaces() {
    for k in 1..=4 {
        let Some(p) = data(&format!("heart/lasc2013-b002/clvein{k}.vtp")) else {
            return;
        };
        let err = read_mesh(&p).unwrap_err();
        assert!(matches!(err.kind, ErrorKind::Mesh(_)), "{err}");
        let msg = err.to_string();
        assert!(msg.contains(&format!("clvein{k}.vtp")), "{msg}");
        assert!(
            msg.contains("1 line/vertex cell") && msg.contains("centreline"),
            "{msg}"
        );
    }
}
