//! Point clouds: CSV, PLY and VTP round trips, the CSV dialects, the `SPACE=LPS` tag, mesh
//! files read as points, and every class of bad input giving a typed error naming the file.

// Test helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use resecta_geom::{TriMesh, Vec3};
use resecta_io::{
    ErrorKind, IoError, MAX_POINTS, MeshFormat, PointCloud, PointFormat, WriteOptions,
    mesh_to_bytes, points_to_bytes, read_points, read_points_bytes, write_points,
};

/// Coordinates that need every bit of an `f64` (and a negative zero).
fn cloud(normals: bool) -> PointCloud {
    let positions = vec![
        Vec3::new(0.1 + 0.2, -12.345_678_901_234_567, 1e-300),
        Vec3::new(-123_456.789e10, 2.0 / 3.0, -0.0),
        Vec3::new(7.0, 8.5, -9.25),
    ];
    let normals = normals.then(|| {
        vec![
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(1.0 / 3.0, -2.5, 1e-9),
            Vec3::new(-0.6, 0.8, 0.0),
        ]
    });
    PointCloud { positions, normals }
}

fn read(text: &str, f: PointFormat) -> PointCloud {
    read_points_bytes(text.as_bytes(), f, "mem").unwrap()
}

fn csv(text: &str) -> PointCloud {
    read(text, PointFormat::Csv)
}

/// The error reading `data`, checked to name the file, start the message and be bad input.
fn err(data: &[u8], f: PointFormat) -> IoError {
    let name = format!("bad.{}", f.extension());
    let e = read_points_bytes(data, f, &name).unwrap_err();
    assert_eq!(e.path.to_str(), Some(name.as_str()));
    assert!(e.to_string().starts_with(&name), "{e}");
    assert!(e.is_bad_input(), "{e}");
    e
}

/// A `Mesh` error whose message holds `says`.
fn mesh_err(data: &[u8], f: PointFormat, says: &str) {
    let e = err(data, f);
    assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");
    assert!(e.to_string().contains(says), "{e} (expected {says:?})");
}

fn bits(v: &[Vec3]) -> Vec<[u64; 3]> {
    v.iter()
        .map(|p| [p.x, p.y, p.z].map(f64::to_bits))
        .collect()
}

fn same_bits(a: &PointCloud, b: &PointCloud) {
    assert_eq!(bits(&a.positions), bits(&b.positions));
    assert_eq!(
        a.normals.as_deref().map(bits),
        b.normals.as_deref().map(bits)
    );
}

fn p3(x: f64, y: f64, z: f64) -> Vec3 {
    Vec3::new(x, y, z)
}

#[test]
fn csv_ply_and_vtp_round_trip_every_bit() {
    for f in [PointFormat::Csv, PointFormat::Ply, PointFormat::Vtp] {
        assert!(f.is_writable());
        for normals in [false, true] {
            let c = cloud(normals);
            let b = points_to_bytes(&c, f, "mem").unwrap();
            let back = read_points_bytes(&b, f, "mem").unwrap();
            same_bits(&back, &c);
        }
    }
}

#[test]
fn files_round_trip_and_the_extension_picks_the_format() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["a.csv", "b.TXT", "c.xyz", "d.ply", "e.vtp"] {
        let path = dir.path().join(name);
        let c = cloud(true);
        write_points(&path, &c).unwrap();
        same_bits(&read_points(&path).unwrap(), &c);
    }
    let text = std::fs::read_to_string(dir.path().join("a.csv")).unwrap();
    assert!(text.starts_with("# SPACE=RAS\nx,y,z,nx,ny,nz\n"), "{text}");
    let ply = std::fs::read(dir.path().join("d.ply")).unwrap();
    let head = String::from_utf8_lossy(&ply[..200]);
    assert!(head.contains("format binary_little_endian 1.0\ncomment SPACE=RAS\n"));
    assert!(head.contains("property double nx"));
    let vtp = std::fs::read_to_string(dir.path().join("e.vtp")).unwrap();
    assert!(vtp.contains("NumberOfVerts=\"3\""), "{vtp}");
    assert!(vtp.contains("Name=\"Normals\""));
    // The plain CSV header.
    let b = points_to_bytes(&cloud(false), PointFormat::Csv, "mem").unwrap();
    assert!(b.starts_with(b"# SPACE=RAS\nx,y,z\n"));

    let e = read_points(dir.path().join("nothing.csv")).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)), "{e}");
    for bad in ["f.nii", "g", "h.csv.gz"] {
        let e = write_points(dir.path().join(bad), &cloud(false)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
        let e = read_points(dir.path().join(bad)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
    }
    for (ext, f) in [
        ("vtk", PointFormat::Vtk),
        ("STL", PointFormat::Stl),
        ("obj", PointFormat::Obj),
    ] {
        assert_eq!(
            PointFormat::from_path(format!("m.{ext}")).unwrap(),
            f,
            "{ext}"
        );
        assert!(!f.is_writable());
        let e = write_points(dir.path().join(format!("m.{ext}")), &cloud(false)).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
    }
    assert_eq!(PointFormat::ALL.len(), 6);
}

#[test]
fn csv_with_and_without_a_header_and_with_three_or_six_columns() {
    let plain = csv("1,2,3\n4,5,6\n");
    assert_eq!(plain.positions, vec![p3(1.0, 2.0, 3.0), p3(4.0, 5.0, 6.0)]);
    assert_eq!(plain.normals, None);
    assert_eq!(csv("x,y,z\n1,2,3\n4,5,6\n"), plain);
    assert_eq!(csv("X Y Z\n1 2 3\n4 5 6"), plain);

    let with = csv("x,y,z,nx,ny,nz\n1,2,3,0,0,1\n4,5,6,0,-2,0\n");
    assert_eq!(with.positions, plain.positions);
    assert_eq!(
        with.normals,
        Some(vec![p3(0.0, 0.0, 1.0), p3(0.0, -2.0, 0.0)]),
        "normals are returned as stored, not normalised"
    );
    assert_eq!(csv("1,2,3,0,0,1\n4,5,6,0,-2,0"), with);
}

#[test]
fn csv_separators_comments_blank_lines_and_line_ends() {
    let want = csv("1,2,3\n4,5,6\n");
    for text in [
        "1;2;3\n4;5;6\n",
        "1\t2\t3\n4\t5\t6\n",
        "1 2 3\n4  5\t 6\n",
        "1, 2, 3\n 4 ,5 , 6 \n",
        "1 ; 2 ; 3\r\n4;5;6\r\n",
        "# a comment\n\n x;y;z\n\n# another\n1;2;3 # trailing comment\n\n4;5;6\n   \n",
        "\u{feff}x,y,z\r\n1,2,3\r\n4,5,6",
        "+1,2e0,3.\n4,50e-1,0.6e1\n",
    ] {
        assert_eq!(csv(text), want, "{text:?}");
    }
}

#[test]
fn space_lps_negates_x_and_y_of_positions_and_normals() {
    let ras = csv("1,2,3,0.5,0.25,1\n");
    let lps = csv("# SPACE=LPS\nx,y,z,nx,ny,nz\n1,2,3,0.5,0.25,1\n");
    assert_eq!(lps.positions, vec![p3(-1.0, -2.0, 3.0)]);
    assert_eq!(lps.normals, Some(vec![p3(-0.5, -0.25, 1.0)]));
    // In the header line, after the data, or lower-case; SPACE=RAS changes nothing.
    assert_eq!(csv("x y z nx ny nz # space=lps\n1 2 3 0.5 0.25 1\n"), lps);
    assert_eq!(csv("1,2,3,0.5,0.25,1\n# SPACE=LPS\n"), lps);
    assert_eq!(csv("# SPACE=RAS\n1,2,3,0.5,0.25,1\n"), ras);

    // PLY: a comment, as the mesh reader honours.
    let ply = "ply\nformat ascii 1.0\ncomment SPACE=LPS\nelement vertex 1\nproperty float x\n\
               property float y\nproperty float z\nproperty float nx\nproperty float ny\n\
               property float nz\nend_header\n1 2 3 0.5 0.25 1\n";
    assert_eq!(read(ply, PointFormat::Ply), lps);
    // VTP: Slicer's SPACE field array ("LPS" as character codes).
    let vtp = "<VTKFile type=\"PolyData\"><PolyData><FieldData><DataArray type=\"String\" \
               Name=\"SPACE\" format=\"ascii\">76 80 83 0</DataArray></FieldData>\
               <Piece NumberOfPoints=\"1\"><PointData Normals=\"N\"><DataArray type=\"Float32\" \
               Name=\"N\" NumberOfComponents=\"3\" format=\"ascii\">0.5 0.25 1</DataArray>\
               </PointData><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" \
               format=\"ascii\">1 2 3</DataArray></Points></Piece></PolyData></VTKFile>";
    assert_eq!(read(vtp, PointFormat::Vtp), lps);
}

#[test]
fn ply_of_any_numeric_types_and_storage() {
    let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty int x\nproperty uchar y\n\
                 property short z\nproperty double confidence\nend_header\n-1 200 -3 0.5\n\
                 4 5 6 0.25\n";
    let c = read(ascii, PointFormat::Ply);
    assert_eq!(c.positions, vec![p3(-1.0, 200.0, -3.0), p3(4.0, 5.0, 6.0)]);
    assert_eq!(c.normals, None);

    // Big-endian float positions with normals written in another order.
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float nz\n\
                  property float x\nproperty float ny\nproperty float y\nproperty float nx\n\
                  property float z\nend_header\n"
        .to_vec();
    for row in [
        [1.0f32, 1.5, 0.0, 2.5, 0.0, 3.5],
        [0.0, -1.0, 2.0, -2.0, 0.0, -3.0],
    ] {
        for v in row {
            b.extend_from_slice(&v.to_be_bytes());
        }
    }
    let c = read_points_bytes(&b, PointFormat::Ply, "mem").unwrap();
    assert_eq!(c.positions, vec![p3(1.5, 2.5, 3.5), p3(-1.0, -2.0, -3.0)]);
    assert_eq!(c.normals, Some(vec![p3(0.0, 0.0, 1.0), p3(0.0, 2.0, 0.0)]));
    // Two of three normal components: no normals.
    let partial = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                   property float z\nproperty float nx\nproperty float ny\nend_header\n1 2 3 0 0\n";
    assert_eq!(read(partial, PointFormat::Ply).normals, None);
}

#[test]
fn ply_faces_and_other_elements_are_ignored() {
    // Faces after the vertices, with indices no mesh would accept, in ASCII and binary.
    let ascii = "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 3\nproperty float x\n\
                 property float y\nproperty float z\nelement face 2\n\
                 property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n\
                 3 0 1 99\n4 -5 0 1 2\n";
    let c = read(ascii, PointFormat::Ply);
    assert_eq!(c.len(), 3);
    assert_eq!(c.positions[1], p3(1.0, 0.0, 0.0));
    // A face element without vertex_indices (a mesh reader refuses it) and truncated face data.
    let odd = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
               property float z\nelement face 1000\nproperty list uchar int corners\nend_header\n\
               1 2 3\n3 0 0\n";
    assert_eq!(
        read(odd, PointFormat::Ply).positions,
        vec![p3(1.0, 2.0, 3.0)]
    );
    // Elements before the vertices (an edge list, a face) are parsed past.
    let before = "ply\nformat ascii 1.0\nelement camera 1\nproperty float fov\nelement face 1\n\
                  property list uchar int vertex_indices\nelement vertex 2\nproperty float x\n\
                  property float y\nproperty float z\nend_header\n0.7\n3 0 1 1\n1 2 3\n4 5 6\n";
    assert_eq!(
        read(before, PointFormat::Ply).positions,
        vec![p3(1.0, 2.0, 3.0), p3(4.0, 5.0, 6.0)]
    );
    // A mesh written by the mesh writer (binary, float, with faces and scalars).
    let b = mesh_to_bytes(&tet(), MeshFormat::Ply, &WriteOptions::default(), "m").unwrap();
    let c = read_points_bytes(&b, PointFormat::Ply, "m").unwrap();
    assert_eq!(c.len(), 4);
}

fn tet() -> TriMesh {
    let v = vec![
        p3(0.0, 0.0, 0.0),
        p3(10.5, 0.0, 0.0),
        p3(0.0, 7.25, 0.0),
        p3(0.0, 0.0, 3.125),
    ];
    let m = TriMesh::new(v, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).unwrap();
    let n = m.compute_vertex_normals();
    m.with_normals(n)
        .unwrap()
        .with_scalars("d", vec![0.5, 1.5, 2.5, 3.5])
        .unwrap()
}

#[test]
fn mesh_files_give_their_vertices_and_vertex_normals() {
    let m = tet();
    for f in MeshFormat::ALL {
        for opts in [WriteOptions::default(), WriteOptions::ascii()] {
            let b = mesh_to_bytes(&m, f, &opts, "m").unwrap();
            let pf = PointFormat::from_path(format!("m.{}", f.extension())).unwrap();
            let c = read_points_bytes(&b, pf, "m").unwrap();
            assert_eq!(c.len(), 4, "{f:?}");
            // STL merges the facets' corners in the order they come.
            for a in &c.positions {
                let near = m.vertices().iter().any(|b| (a - b).norm() < 1e-6);
                assert!(near, "{f:?}: {a}");
            }
            if f != MeshFormat::Stl {
                for (a, b) in c.positions.iter().zip(m.vertices()) {
                    assert!((a - b).norm() < 1e-6, "{f:?}: {a} vs {b}");
                }
            }
            // STL has facet normals only; the others keep the vertex normals.
            match (f, &c.normals, m.normals()) {
                (MeshFormat::Stl, None, _) => {}
                (MeshFormat::Stl, Some(_), _) => panic!("STL gave vertex normals"),
                (_, Some(n), Some(want)) => {
                    for (a, b) in n.iter().zip(want) {
                        assert!((a - b).norm() < 1e-6, "{f:?}");
                    }
                }
                (_, None, _) | (_, Some(_), None) => panic!("{f:?}: normals lost"),
            }
        }
    }
    // A VTK legacy point set (vertex cells only) is a cloud, though not a mesh.
    let vtk = "# vtk DataFile Version 4.2\npoints SPACE=RAS\nASCII\nDATASET POLYDATA\n\
               POINTS 2 float\n1 2 3 4 5 6\nVERTICES 2 4\n1 0\n1 1\n";
    assert_eq!(
        read(vtk, PointFormat::Vtk).positions,
        vec![p3(1.0, 2.0, 3.0), p3(4.0, 5.0, 6.0)]
    );
    // An OBJ of bare vertices.
    assert_eq!(read("v 1 2 3\nv 4 5 6\n", PointFormat::Obj).len(), 2);
}

#[test]
fn csv_bad_numbers_empty_fields_and_mixed_separators_name_the_line() {
    mesh_err(
        b"x,y,z\n1,2,3\n4,five,6\n",
        PointFormat::Csv,
        "line 3, column 2: not a number",
    );
    mesh_err(
        b"1 2 3\n4 5 6e\n",
        PointFormat::Csv,
        "line 2, column 3: not a number",
    );
    mesh_err(b"1,,3\n", PointFormat::Csv, "line 1, column 2: empty field");
    mesh_err(b"1,2,3\n1,5;2,5;3,5\n", PointFormat::Csv, "line 2 mixes");
    // The first line that is not a header must be all numbers.
    mesh_err(b"1,2,z\n", PointFormat::Csv, "line 1, column 3");
    // A second header line is a bad number.
    mesh_err(
        b"x,y,z\nx,y,z\n1,2,3\n",
        PointFormat::Csv,
        "line 2, column 1",
    );
    mesh_err(
        b"1 2 3\n\xff\xfe 2 3\n",
        PointFormat::Csv,
        "line 2, column 1",
    );
}

#[test]
fn csv_ragged_rows_and_wrong_column_counts_name_the_lines() {
    mesh_err(
        b"x,y,z\n1,2,3\n\n4,5\n",
        PointFormat::Csv,
        "line 4 has 2 columns, but line 2 has 3",
    );
    mesh_err(
        b"1,2,3,0,0,1\n1,2,3\n",
        PointFormat::Csv,
        "line 2 has 3 columns, but line 1 has 6",
    );
    mesh_err(
        b"# c\n1 2 3 4\n",
        PointFormat::Csv,
        "line 2 has 4 columns, expected 3",
    );
    mesh_err(b"1,2,3,\n", PointFormat::Csv, "line 1 has 4 columns");
}

#[test]
fn non_finite_values_and_zero_normals_are_refused() {
    for text in [
        "1,2,NaN\n",
        "1,2,3\ninf,2,3\n",
        "1,2,3,0,-infinity,1\n",
        "1,2,1e400\n",
    ] {
        mesh_err(text.as_bytes(), PointFormat::Csv, "not a finite number");
    }
    mesh_err(
        b"1,2,3,0,0,1\n4,5,6,0,0,-0\n",
        PointFormat::Csv,
        "line 2: normal 1 is zero",
    );

    // Binary PLY: a NaN coordinate, an infinite normal, a zero normal, by point index.
    let ply = |rows: &[[f64; 6]]| {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty double x\n\
             property double y\nproperty double z\nproperty double nx\nproperty double ny\n\
             property double nz\nend_header\n",
            rows.len()
        )
        .into_bytes();
        for v in rows.iter().flatten() {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b
    };
    let ok = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    mesh_err(
        &ply(&[ok, [1.0, f64::NAN, 0.0, 1.0, 0.0, 0.0]]),
        PointFormat::Ply,
        "point 1 is not finite",
    );
    mesh_err(
        &ply(&[ok, ok, [1.0, 2.0, 0.0, f64::INFINITY, 0.0, 0.0]]),
        PointFormat::Ply,
        "normal 2 is not finite",
    );
    mesh_err(
        &ply(&[[1.0, 2.0, 0.0, 0.0, 0.0, 0.0], ok]),
        PointFormat::Ply,
        "normal 0 is zero",
    );
    assert_eq!(
        read_points_bytes(&ply(&[ok]), PointFormat::Ply, "m")
            .unwrap()
            .len(),
        1
    );
}

#[test]
fn clouds_without_points_are_refused() {
    for text in [
        "",
        "\n\n",
        "# only a comment\n",
        "x,y,z\n",
        "x,y,z,nx,ny,nz\n# SPACE=LPS\n",
    ] {
        mesh_err(text.as_bytes(), PointFormat::Csv, "no points");
    }
    let ply = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n\
               property float z\nend_header\n";
    mesh_err(ply.as_bytes(), PointFormat::Ply, "no points");
}

#[test]
fn absurd_ply_counts_are_refused_from_the_header() {
    for (count, binary) in [
        (1_000_000_000_000u64, true),
        (1_000_000_000_000, false),
        (MAX_POINTS as u64 + 1, true),
        (u64::MAX, true),
    ] {
        let format = if binary {
            "binary_little_endian"
        } else {
            "ascii"
        };
        let text = format!(
            "ply\nformat {format} 1.0\nelement vertex {count}\nproperty double x\n\
             property double y\nproperty double z\nend_header\n"
        );
        let e = err(text.as_bytes(), PointFormat::Ply);
        assert!(matches!(e.kind, ErrorKind::Header(_)), "{count}: {e}");
        assert!(e.to_string().contains("vertex"), "{e}");
    }
    // A count within the limit that the data does not hold: refused before allocating for it.
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 9000000\nproperty double x\n\
                property double y\nproperty double z\nend_header\n";
    let e = err(text.as_bytes(), PointFormat::Ply);
    assert!(matches!(e.kind, ErrorKind::DataSize { .. }), "{e}");
}

#[test]
fn truncated_binary_and_broken_structure_are_typed_errors() {
    let b = points_to_bytes(&cloud(true), PointFormat::Ply, "mem").unwrap();
    for cut in [1, 7, 8, 47, 48] {
        let e = err(&b[..b.len() - cut], PointFormat::Ply);
        assert!(matches!(e.kind, ErrorKind::DataSize { .. }), "{cut}: {e}");
    }
    let head = |props: &str| {
        format!("ply\nformat ascii 1.0\nelement vertex 1\n{props}end_header\n1 2 3\n")
    };
    let e = err(
        head("property float x\nproperty float y\nproperty float w\n").as_bytes(),
        PointFormat::Ply,
    );
    assert!(
        matches!(e.kind, ErrorKind::Header(_)) && e.to_string().contains("x, y and z"),
        "{e}"
    );
    let e = err(
        b"ply\nformat ascii 1.0\nelement face 0\nend_header\n",
        PointFormat::Ply,
    );
    assert!(matches!(e.kind, ErrorKind::Header(_)), "{e}");
    let e = err(b"plz\n", PointFormat::Ply);
    assert!(matches!(e.kind, ErrorKind::BadMagic(_)), "{e}");
    let e = err(
        head("property float x\nproperty float y\nproperty float z\n")
            .replace("1 2 3", "1 2 x")
            .as_bytes(),
        PointFormat::Ply,
    );
    assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");

    let v = points_to_bytes(&cloud(true), PointFormat::Vtp, "mem").unwrap();
    let e = err(&v[..v.len() / 2], PointFormat::Vtp);
    assert!(!e.to_string().is_empty());
    let e = err(
        b"<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"2\"><Points>\
                  <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">1 2 3\
                  </DataArray></Points></Piece></PolyData></VTKFile>",
        PointFormat::Vtp,
    );
    assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");
}

#[test]
fn writers_refuse_what_readers_refuse() {
    let refuse = |c: &PointCloud, says: &str| {
        for f in [PointFormat::Csv, PointFormat::Ply, PointFormat::Vtp] {
            let e = points_to_bytes(c, f, "out").unwrap_err();
            assert_eq!(e.path.to_str(), Some("out"));
            assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");
            assert!(e.to_string().contains(says), "{e}");
        }
    };
    refuse(&PointCloud::default(), "no points");
    refuse(
        &PointCloud::new(vec![p3(0.0, f64::NAN, 0.0)]),
        "point 0 is not finite",
    );
    let mut c = cloud(true);
    c.normals.as_mut().unwrap().pop();
    refuse(&c, "2 normals for 3 points");
    let mut c = cloud(true);
    c.normals.as_mut().unwrap()[2] = Vec3::zeros();
    refuse(&c, "normal 2 is zero");
    let mut c = cloud(true);
    c.normals.as_mut().unwrap()[1].y = f64::NEG_INFINITY;
    refuse(&c, "normal 1 is not finite");
    let e = points_to_bytes(&cloud(false), PointFormat::Stl, "out.stl").unwrap_err();
    assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
}

#[test]
fn errors_never_repeat_the_file_text() {
    const MARKER: &str = "PATIENTMARKER";
    for text in [
        format!("# {MARKER}\n{MARKER},y,z\n1,2,{MARKER}\n"),
        format!("x,y,z\n1,2,3\n{MARKER} 2 3\n"),
        format!("x y z\n1 2 3 # {MARKER}\n4 5 6 7 {MARKER}\n"),
    ] {
        let e = read_points_bytes(text.as_bytes(), PointFormat::Csv, "f.csv").unwrap_err();
        for shown in [e.to_string(), format!("{e:?}")] {
            assert!(!shown.contains(MARKER), "{shown}");
        }
    }
}

/// The mutation test of `mesh_robustness.rs`, for the point readers (stable CI cannot run the
/// `points_csv`/`points_ply` fuzz targets).
fn seeds() -> Vec<(PointFormat, Vec<u8>)> {
    let mut out = vec![
        (
            PointFormat::Csv,
            b"# SPACE=LPS\nx;y;z\n1;2;3\n4;5;6 # c\n".to_vec(),
        ),
        (
            PointFormat::Ply,
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
                             property float y\nproperty float z\nelement face 1\n\
                             property list uchar int vertex_indices\nend_header\n\
                             1 2 3\n4 5 6\n3 0 1 1\n"
                .to_vec(),
        ),
    ];
    for f in [PointFormat::Csv, PointFormat::Ply, PointFormat::Vtp] {
        for normals in [false, true] {
            out.push((f, points_to_bytes(&cloud(normals), f, "seed").unwrap()));
        }
    }
    out
}

fn mutate(mut b: Vec<u8>, at: usize, edit: u8, kind: u8, digits: u64) -> Vec<u8> {
    let n = b.len().max(1);
    let at = at % n;
    match kind % 4 {
        0 => b.truncate(at),
        1 => {
            if let Some(c) = b.get_mut(at) {
                *c ^= edit | 1;
            }
        }
        2 => b.insert(at.min(b.len()), edit),
        _ => {
            let s = digits.to_string();
            let end = (at + s.len()).min(b.len());
            b.splice(at.min(b.len())..end, s.bytes());
        }
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 10_000, ..ProptestConfig::default() })]

    #[test]
    fn mutated_point_files_never_panic(
        k in any::<usize>(),
        edits in prop::collection::vec((any::<usize>(), any::<u8>(), any::<u8>(), any::<u64>()), 1..4),
    ) {
        let seeds = seeds();
        let (f, seed) = &seeds[k % seeds.len()];
        let data = edits
            .iter()
            .fold(seed.clone(), |b, &(at, e, kind, d)| mutate(b, at, e, kind, d));
        match read_points_bytes(&data, *f, "fuzzed") {
            Ok(c) => {
                prop_assert!((1..=MAX_POINTS).contains(&c.len()));
                prop_assert!(c.positions.iter().flatten().all(|v| v.is_finite()));
                if let Some(n) = &c.normals {
                    prop_assert_eq!(n.len(), c.len());
                }
            }
            Err(e) => {
                prop_assert_eq!(e.path.to_str(), Some("fuzzed"));
                prop_assert!(!e.to_string().is_empty());
            }
        }
    }
}

#[test]
fn every_prefix_of_every_seed_is_handled() {
    for (f, b) in seeds() {
        read_points_bytes(&b, f, "seed").unwrap();
        for cut in 0..b.len() {
            if let Err(e) = read_points_bytes(&b[..cut], f, "cut") {
                assert_eq!(e.path.to_str(), Some("cut"));
            }
        }
    }
}

#[test]
fn the_fuzz_seeds_read_to_their_points() {
    let seeds = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../../fuzz/seeds");
    let c = read_points(seeds.join("points_csv/normals.csv")).unwrap();
    assert_eq!(c.len(), 2);
    assert_eq!(c.positions[1].x, -1_234_567_890_000_000.0);
    assert_eq!(c.normals.unwrap()[1], p3(0.5, -2.5, 1e-9));
    let c = read_points(seeds.join("points_csv/lps_tabs.csv")).unwrap();
    assert_eq!(
        c.positions,
        vec![p3(-1.0, -2.0, 3.0), p3(-4.5, 5.0, 6.0), p3(-7.0, -8.0, 9.0)]
    );
    assert_eq!(
        read_points(seeds.join("points_csv/plain.csv"))
            .unwrap()
            .len(),
        2
    );
    let c = read_points(seeds.join("points_ply/ascii_faces.ply")).unwrap();
    assert_eq!(c.positions[1], p3(-1.0, -0.0, 0.0));
    assert_eq!(c.normals.unwrap()[1], p3(-0.0, -1.0, 0.0));
    for name in ["binary_le.ply", "binary_be.ply"] {
        let c = read_points(seeds.join("points_ply").join(name)).unwrap();
        assert_eq!(c.positions[1], p3(10.5, 7.25, -3.125), "{name}");
        assert_eq!(c.normals.unwrap()[1], p3(0.6f32.into(), 0.8f32.into(), 0.0));
    }
}
