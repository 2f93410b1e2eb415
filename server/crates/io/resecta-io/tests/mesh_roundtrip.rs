//! Round trips through every mesh format and variant, and hand-written files for the read-only
//! forms (VTK 5.1 offsets, strips, quads, OBJ corner forms, PLY list types).
//!
//! Precision: VTK, VTP and OBJ must return every `f64` bit for bit. STL and PLY store `f32`
//! coordinates/normals, so values must equal the input rounded to `f32` (exactly); PLY scalars
//! are `double` and must be exact.

// Test helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used)]

use resecta_geom::{TriMesh, Vec3};
use resecta_io::{
    Encoding, MeshFormat, VtpLayout, WriteOptions, mesh_to_bytes, read_mesh, read_mesh_bytes,
    write_mesh, write_mesh_with,
};

/// A closed box with awkward coordinates, normals and two scalar arrays (one name has a space).
fn fixture() -> TriMesh {
    let (o, s) = (Vec3::new(-120.3, 45.7, 100.0 / 3.0), [2.1, 3.0e-3, 5.5e7]);
    let m = resecta_geom::primitives::cuboid(o, o + Vec3::from(s)).unwrap();
    let n = m.compute_vertex_normals();
    let d: Vec<f64> = (0..8).map(|i| f64::from(i) * 0.1 + 1.0 / 3.0).collect();
    let x: Vec<f64> = m.vertices().iter().map(|p| -p.x * 1e-9).collect();
    m.with_normals(n)
        .unwrap()
        .with_scalars("distance", d)
        .unwrap()
        .with_scalars("margin mm", x)
        .unwrap()
}

fn f32s(v: Vec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

fn assert_exact(a: &TriMesh, b: &TriMesh, scalars: bool, what: &str) {
    assert_eq!(a.vertices(), b.vertices(), "{what}: vertices");
    assert_eq!(a.triangles(), b.triangles(), "{what}: triangles");
    assert_eq!(a.normals(), b.normals(), "{what}: normals");
    if scalars {
        assert_eq!(a.scalars(), b.scalars(), "{what}: scalars");
    }
}

fn roundtrip(m: &TriMesh, format: MeshFormat, opts: &WriteOptions) -> TriMesh {
    let bytes = mesh_to_bytes(m, format, opts, "mem").unwrap();
    read_mesh_bytes(&bytes, format, "mem").unwrap()
}

#[test]
fn vtk_ascii_and_binary_are_exact() {
    let m = fixture();
    for enc in [Encoding::Ascii, Encoding::Binary] {
        let opts = WriteOptions {
            encoding: enc,
            ..WriteOptions::default()
        };
        assert_exact(
            &m,
            &roundtrip(&m, MeshFormat::Vtk, &opts),
            true,
            &format!("vtk {enc:?}"),
        );
    }
}

#[test]
fn vtp_every_layout_compression_and_header_is_exact() {
    let m = fixture();
    let a = roundtrip(&m, MeshFormat::Vtp, &WriteOptions::ascii());
    assert_exact(&m, &a, true, "vtp ascii");
    for layout in [
        VtpLayout::Inline,
        VtpLayout::AppendedRaw,
        VtpLayout::AppendedBase64,
    ] {
        for compress in [false, true] {
            for header_u64 in [false, true] {
                let opts = WriteOptions {
                    encoding: Encoding::Binary,
                    vtp_layout: layout,
                    compress,
                    header_u64,
                };
                let what = format!("vtp {opts:?}");
                let bytes = mesh_to_bytes(&m, MeshFormat::Vtp, &opts, "mem").unwrap();
                let text = String::from_utf8_lossy(&bytes);
                assert_eq!(text.contains("vtkZLibDataCompressor"), compress, "{what}");
                assert!(
                    text.contains(if header_u64 { "UInt64" } else { "UInt32" }),
                    "{what}"
                );
                let back = read_mesh_bytes(&bytes, MeshFormat::Vtp, "mem").unwrap();
                assert_exact(&m, &back, true, &what);
            }
        }
    }
}

#[test]
fn vtp_large_arrays_span_several_zlib_blocks() {
    // 3 × 8 bytes × 5000 points = 120 kB of points: four 32 KiB blocks, last one partial.
    let v: Vec<Vec3> = (0..5000)
        .map(|i| {
            Vec3::new(
                f64::from(i).sin() * 50.0,
                f64::from(i) * 0.01,
                f64::from(i).sqrt(),
            )
        })
        .collect();
    let t: Vec<[u32; 3]> = (0..4998).map(|i| [i, i + 1, i + 2]).collect();
    let m = TriMesh::new(v, t).unwrap();
    let back = roundtrip(&m, MeshFormat::Vtp, &WriteOptions::default());
    assert_exact(&m, &back, true, "vtp multi-block");
}

#[test]
fn obj_is_exact_with_normals_but_no_scalars() {
    let m = fixture();
    let back = roundtrip(&m, MeshFormat::Obj, &WriteOptions::default());
    assert_exact(&m, &back, false, "obj");
    assert!(back.scalars().is_empty());
}

#[test]
fn ply_all_encodings_round_to_f32_with_exact_scalars() {
    let m = fixture();
    for enc in [Encoding::Ascii, Encoding::Binary, Encoding::BinaryBigEndian] {
        let opts = WriteOptions {
            encoding: enc,
            ..WriteOptions::default()
        };
        let back = roundtrip(&m, MeshFormat::Ply, &opts);
        assert_eq!(back.triangles(), m.triangles(), "{enc:?}");
        for (a, b) in m.vertices().iter().zip(back.vertices()) {
            assert_eq!(f32s(*a), f32s(*b), "{enc:?}");
            assert_eq!(b.map(|c| c as f32 as f64), *b, "{enc:?}: stored as f32");
        }
        for (a, b) in m.normals().unwrap().iter().zip(back.normals().unwrap()) {
            assert_eq!(f32s(*a), f32s(*b), "{enc:?}");
        }
        assert_eq!(back.scalars(), m.scalars(), "{enc:?}");
    }
}

#[test]
fn stl_binary_and_ascii_round_to_f32_and_merge_corners() {
    let m = fixture();
    for enc in [Encoding::Ascii, Encoding::Binary] {
        let opts = WriteOptions {
            encoding: enc,
            ..WriteOptions::default()
        };
        let bytes = mesh_to_bytes(&m, MeshFormat::Stl, &opts, "mem").unwrap();
        if enc == Encoding::Binary {
            assert_eq!(bytes.len(), 84 + 50 * 12);
        }
        let back = read_mesh_bytes(&bytes, MeshFormat::Stl, "mem").unwrap();
        // Corners are merged back to 8 shared vertices, so the box is closed again.
        assert_eq!(back.vertices().len(), 8, "{enc:?}");
        assert_eq!(back.triangles().len(), 12, "{enc:?}");
        assert!(back.report().watertight, "{enc:?}");
        for t in 0..12 {
            assert_eq!(
                m.corners(t).map(f32s),
                back.corners(t).map(f32s),
                "{enc:?} t{t}"
            );
        }
        assert!(back.normals().is_none() && back.scalars().is_empty());
    }
}

#[test]
fn files_on_disk_by_extension_and_empty_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let m = fixture();
    // STL and PLY hold f32: their volume is that of the f32-rounded box (the 3 µm side loses
    // ~1e-3 relative precision next to a 46 mm offset).
    let m32 = TriMesh::new(
        m.vertices()
            .iter()
            .map(|v| v.map(|c| f64::from(c as f32)))
            .collect(),
        m.triangles().to_vec(),
    )
    .unwrap();
    for f in MeshFormat::ALL {
        let p = dir
            .path()
            .join(format!("model.{}", f.extension().to_uppercase()));
        write_mesh(&p, &m).unwrap();
        let back = read_mesh(&p).unwrap();
        assert_eq!(back.triangles().len(), 12, "{f:?}");
        assert!(back.report().watertight, "{f:?}");
        let expected = match f {
            MeshFormat::Stl | MeshFormat::Ply => m32.signed_volume(),
            MeshFormat::Vtk | MeshFormat::Vtp | MeshFormat::Obj => m.signed_volume(),
        };
        assert!(
            (back.signed_volume() - expected).abs() <= 1e-12 * expected,
            "{f:?}"
        );
    }
    let empty = TriMesh::new(vec![], vec![]).unwrap();
    for f in [
        MeshFormat::Vtk,
        MeshFormat::Vtp,
        MeshFormat::Ply,
        MeshFormat::Obj,
        MeshFormat::Stl,
    ] {
        let p = dir.path().join(format!("empty.{}", f.extension()));
        write_mesh_with(&p, &empty, &WriteOptions::default()).unwrap();
        let back = read_mesh(&p).unwrap();
        assert!(
            back.vertices().is_empty() && back.triangles().is_empty(),
            "{f:?}"
        );
    }
}

#[test]
fn writers_tag_ras_and_readers_flip_lps() {
    let m = fixture();
    let flip = |v: Vec3| Vec3::new(-v.x, -v.y, v.z);
    for (f, enc, ras, lps) in [
        (
            MeshFormat::Vtk,
            Encoding::Ascii,
            "SPACE=RAS".as_bytes(),
            "SPACE=LPS".as_bytes(),
        ),
        (
            MeshFormat::Vtp,
            Encoding::Ascii,
            b"82 65 83 0",
            b"76 80 83 0",
        ),
        (
            MeshFormat::Ply,
            Encoding::Binary,
            b"SPACE=RAS",
            b"SPACE=LPS",
        ),
        (MeshFormat::Obj, Encoding::Ascii, b"SPACE=RAS", b"SPACE=LPS"),
        (
            MeshFormat::Stl,
            Encoding::Binary,
            b"SPACE=RAS",
            b"SPACE=LPS",
        ),
    ] {
        let opts = WriteOptions {
            encoding: enc,
            ..WriteOptions::default()
        };
        let mut bytes = mesh_to_bytes(&m, f, &opts, "mem").unwrap();
        let at = bytes.windows(ras.len()).position(|w| w == ras).unwrap();
        bytes[at..at + ras.len()].copy_from_slice(lps);
        let back = read_mesh_bytes(&bytes, f, "mem").unwrap();
        for (a, b) in m.vertices().iter().zip(back.vertices()) {
            if f == MeshFormat::Stl {
                break; // vertex order differs after merging; checked by corners below
            }
            assert_eq!(f32s(flip(*a)), f32s(*b), "{f:?}");
        }
        assert_eq!(
            f32s(flip(m.corners(3)[1])),
            f32s(back.corners(3)[1]),
            "{f:?}"
        );
        if let Some(n) = back.normals() {
            assert_eq!(f32s(flip(m.normals().unwrap()[5])), f32s(n[5]), "{f:?}");
        }
    }
}

#[test]
fn vtk_legacy_51_offsets_strips_quads_and_attributes() {
    let text = "# vtk DataFile Version 5.1\nvtk output\nASCII\nDATASET POLYDATA\n\
        FIELD FieldData 1\nTimeValue 1 1 double\n0\n\
        POINTS 6 float\n0 0 0 1 0 0 1 1 0 0 1 0 2 0 0 2 1 0\n\
        METADATA\nINFORMATION 0\n\n\
        LINES 2 2\nOFFSETS vtktypeint64\n0 2\nCONNECTIVITY vtktypeint64\n0 5\n\
        POLYGONS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 1 2 3\n\
        TRIANGLE_STRIPS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n1 4 2 5\n\
        CELL_DATA 3\nSCALARS cellid int 1\nLOOKUP_TABLE default\n7 8 9\n\
        POINT_DATA 6\nSCALARS label%20one float 1\nLOOKUP_TABLE default\n1 2 3 4 5 6\n\
        NORMALS Normals float\n0 0 1 0 0 1 0 0 1 0 0 1 0 0 1 0 0 1\n\
        VECTORS v double\n0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n\
        FIELD FieldData 2\nextra 1 6 double\n.5 .5 .5 .5 .5 .5\nMETADATA\nINFORMATION 0\n\n\
        tc 2 6 float\n0 0 0 0 0 0 0 0 0 0 0 0\n";
    let m = read_mesh_bytes(text.as_bytes(), MeshFormat::Vtk, "t.vtk").unwrap();
    // Quad fan (0,1,2),(0,2,3); strip (1,4,2),(4,5,2) with the second turned to agree.
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3], [1, 4, 2], [2, 4, 5]]);
    assert!(m.report().inconsistent_edges == 0);
    assert_eq!(m.scalars()["label one"], vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    assert_eq!(m.scalars()["extra"], vec![0.5; 6]);
    assert_eq!(
        m.scalars().len(),
        2,
        "cell data and 2-component arrays are dropped"
    );
    assert_eq!(m.normals().unwrap()[4], Vec3::z());
    assert_eq!(m.vertices()[5], Vec3::new(2.0, 1.0, 0.0));
}

#[test]
fn vtk_legacy_binary_float_points_classic_cells() {
    let mut b =
        b"# vtk DataFile Version 3.0\nt\nBINARY\nDATASET POLYDATA\nPOINTS 4 float\n".to_vec();
    for v in [
        0.0f32, 0.0, 0.0, 1.5, 0.0, 0.0, 1.5, 2.25, 0.0, 0.0, 2.25, 0.0,
    ] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nPOLYGONS 1 5\n");
    for i in [4i32, 0, 1, 2, 3] {
        b.extend_from_slice(&i.to_be_bytes());
    }
    b.extend_from_slice(b"\nPOINT_DATA 4\nSCALARS s unsigned_char\nLOOKUP_TABLE default\n");
    b.extend_from_slice(&[10, 20, 30, 255]);
    b.push(b'\n');
    let m = read_mesh_bytes(&b, MeshFormat::Vtk, "b.vtk").unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.vertices()[2], Vec3::new(1.5, 2.25, 0.0));
    assert_eq!(m.scalars()["s"], vec![10.0, 20.0, 30.0, 255.0]);
    assert!((m.area() - 1.5 * 2.25).abs() < 1e-12);
}

#[test]
fn obj_corner_forms_negative_indices_and_quads() {
    let text = "# comment\nmtllib x.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\n\
        vt 0 0\nvn 0 0 1\ng quad\nusemtl m\nf 1/1/1 2/1/1 3//1 4/1/1\nf -4 -2 -1\nl 1 2\n";
    let m = read_mesh_bytes(text.as_bytes(), MeshFormat::Obj, "q.obj").unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
    // The last face has no normals, so per-vertex normals are not all known: dropped.
    assert!(m.normals().is_none());
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 -1\nvn 0 0 1\nf 1//2 2//2 3//-1\n";
    let m = read_mesh_bytes(text.as_bytes(), MeshFormat::Obj, "n.obj").unwrap();
    assert_eq!(m.normals().unwrap(), &[Vec3::z(); 3]);
}

#[test]
fn ply_hand_written_lists_and_extra_properties() {
    let text = "ply\nformat ascii 1.0\ncomment hello\nelement vertex 4\nproperty float x\n\
        property float y\nproperty float z\nproperty uchar red\nproperty double quality\n\
        element face 1\nproperty uchar flags\nproperty list ushort uint vertex_index\n\
        element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n\
        0 0 0 255 0.5\n1 0 0 0 1.5\n1 1 0 0 2.5\n0 1 0 0 3.5\n7 4 0 1 2 3\n0 1\n";
    let m = read_mesh_bytes(text.as_bytes(), MeshFormat::Ply, "a.ply").unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.scalars().keys().collect::<Vec<_>>(), ["quality"]);
    assert_eq!(m.scalars()["quality"], vec![0.5, 1.5, 2.5, 3.5]);
    // The same in binary big-endian with int counts and short indices.
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\n\
        property double y\nproperty double z\nelement face 1\n\
        property list int short vertex_indices\nend_header\n"
        .to_vec();
    for v in [0.0f64, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.2, 0.0] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(&3i32.to_be_bytes());
    for i in [0i16, 1, 2] {
        b.extend_from_slice(&i.to_be_bytes());
    }
    let m = read_mesh_bytes(&b, MeshFormat::Ply, "b.ply").unwrap();
    assert_eq!(m.vertices()[1].x, 0.1, "double properties are exact");
    assert_eq!(m.triangles(), &[[0, 1, 2]]);
}
