//! Polylines (vessel centrelines) as VTK XML PolyData `Lines` with point and line arrays.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use resecta_geom::Vec3;
use resecta_io::{PolylineSet, read_mesh, write_polylines};

#[test]
fn polylines_are_written_as_lines_with_their_arrays() {
    let dir = tempfile::tempdir().unwrap();
    let set = PolylineSet {
        lines: vec![
            vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0)],
            vec![
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(2.0, 1.0, 0.0),
                Vec3::new(3.0, 2.5, 0.5),
            ],
        ],
        point_data: vec![("radius".into(), vec![2.0, 1.5, 1.5, 1.0, 0.5])],
        cell_data: vec![("branch".into(), vec![0.0, 1.0])],
    };
    let path = dir.path().join("centrelines.vtp");
    write_polylines(&path, &set).unwrap();
    let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).into_owned();
    assert!(text.contains("NumberOfPoints=\"5\""), "{text}");
    assert!(text.contains("NumberOfLines=\"2\"") && text.contains("NumberOfPolys=\"0\""));
    assert!(text.contains("Name=\"radius\"") && text.contains("Name=\"branch\""));
    assert!(text.contains("<Lines>") && text.contains("SPACE"));
    // A triangle-mesh reader refuses a file of lines only, naming it.
    let e = read_mesh(&path).unwrap_err().to_string();
    assert!(e.contains("centrelines.vtp"), "{e}");

    // Arrays of the wrong length, or another extension, are refused.
    let mut bad = set.clone();
    bad.point_data[0].1.pop();
    let e = write_polylines(dir.path().join("bad.vtp"), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("\"radius\" has 4 values for 5 points"), "{e}");
    let e = write_polylines(dir.path().join("c.stl"), &set)
        .unwrap_err()
        .to_string();
    assert!(e.contains(".vtp"), "{e}");
}
