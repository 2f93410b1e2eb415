//! Every class of bad mesh input gives a typed error naming the file, never a panic.

// Test helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used)]

use resecta_geom::{GeomError, TriMesh, Vec3};
use resecta_io::{
    Encoding, ErrorKind, IoError, MeshFormat, VtpLayout, WriteOptions, mesh_to_bytes, read_mesh,
    read_mesh_bytes, write_mesh,
};

fn quad() -> TriMesh {
    let v = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    TriMesh::new(v, vec![[0, 1, 2], [0, 2, 3]])
        .unwrap()
        .with_scalars("s", vec![1.0, 2.0, 3.0, 4.0])
        .unwrap()
}

fn bytes(f: MeshFormat, enc: Encoding) -> Vec<u8> {
    let opts = WriteOptions {
        encoding: enc,
        ..WriteOptions::default()
    };
    mesh_to_bytes(&quad(), f, &opts, "mem").unwrap()
}

fn err(data: &[u8], f: MeshFormat) -> IoError {
    let name = format!("bad.{}", f.extension());
    let e = read_mesh_bytes(data, f, &name).unwrap_err();
    assert_eq!(e.path.to_str(), Some(name.as_str()));
    assert!(e.to_string().starts_with(&name), "{e}");
    assert!(e.is_bad_input(), "{e}");
    e
}

#[test]
fn wrong_magic() {
    for (f, data) in [
        (MeshFormat::Vtk, b"hello world\n".as_slice()),
        (MeshFormat::Vtp, b"<Foo type=\"PolyData\"/>"),
        (MeshFormat::Vtp, b"\x00\x01binary"),
        (MeshFormat::Stl, b"not an stl"),
        (MeshFormat::Ply, b"plx\nformat ascii 1.0\nend_header\n"),
    ] {
        let e = err(data, f);
        assert!(matches!(e.kind, ErrorKind::BadMagic(_)), "{f:?}: {e}");
    }
}

#[test]
fn truncated_data() {
    for f in [MeshFormat::Vtk, MeshFormat::Stl, MeshFormat::Ply] {
        let b = bytes(f, Encoding::Binary);
        let e = err(&b[..b.len() - 7], f);
        assert!(matches!(e.kind, ErrorKind::DataSize { .. }), "{f:?}: {e}");
    }
    let opts = WriteOptions {
        vtp_layout: VtpLayout::AppendedRaw,
        compress: false,
        ..WriteOptions::default()
    };
    let b = mesh_to_bytes(&quad(), MeshFormat::Vtp, &opts, "m").unwrap();
    let cut = b.len() - "\n  </AppendedData>\n</VTKFile>\n".len() - 20;
    let e = err(&b[..cut], MeshFormat::Vtp);
    assert!(matches!(e.kind, ErrorKind::DataSize { .. }), "{e}");
    // Text formats: the values run out.
    let b = bytes(MeshFormat::Vtk, Encoding::Ascii);
    let text = String::from_utf8(b).unwrap();
    let cut = text.find("POLYGONS").unwrap() - 8;
    let e = err(&text.as_bytes()[..cut], MeshFormat::Vtk);
    assert!(e.to_string().contains("ends after"), "{e}");
}

#[test]
fn counts_that_do_not_match() {
    let cases: [(MeshFormat, &str); 4] = [
        // Cell list size disagrees with the cells.
        (
            MeshFormat::Vtk,
            "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 5\n3 0 1 2 0\n",
        ),
        // POINT_DATA count differs from POINTS.
        (
            MeshFormat::Vtk,
            "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOINT_DATA 4\n",
        ),
        // Fewer ASCII values than NumberOfPoints × 3.
        (
            MeshFormat::Vtp,
            "<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\"><Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1</DataArray></Points><Polys><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray><DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys></Piece></PolyData></VTKFile>",
        ),
        // Two offsets for one polygon.
        (
            MeshFormat::Vtp,
            "<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\"><Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0</DataArray></Points><Polys><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray><DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3 3</DataArray></Polys></Piece></PolyData></VTKFile>",
        ),
    ];
    for (f, text) in cases {
        let e = err(text.as_bytes(), f);
        assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{f:?}: {e}");
    }
    // Binary STL whose facet count promises more than the file holds.
    let mut b = bytes(MeshFormat::Stl, Encoding::Binary);
    b[80..84].copy_from_slice(&3u32.to_le_bytes());
    let e = err(&b, MeshFormat::Stl);
    assert!(
        matches!(
            e.kind,
            ErrorKind::DataSize {
                expected: 234,
                got: 184
            }
        ),
        "{e}"
    );
}

#[test]
fn huge_header_counts_fail_without_allocating() {
    let cases: [(MeshFormat, &[u8]); 5] = [
        (MeshFormat::Vtk, b"# vtk DataFile Version 3.0\nt\nBINARY\nDATASET POLYDATA\nPOINTS 4000000000000 double\n\0\0\0"),
        (MeshFormat::Vtk, b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 4000000000000 double\n1 2 3"),
        (MeshFormat::Vtk, b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 18446744073709551615 double\n1 2 3"),
        (MeshFormat::Ply, b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0"),
        (MeshFormat::Stl, &[0u8; 84 + 49]),
    ];
    for (f, data) in cases {
        let e = err(data, f);
        assert!(
            matches!(
                e.kind,
                ErrorKind::DataSize { .. } | ErrorKind::Mesh(_) | ErrorKind::Header(_)
            ),
            "{f:?}: {e}"
        );
    }
    // A zlib header claiming gigabytes from a few bytes of compressed data.
    let mut hdr = Vec::new();
    for v in [1u32, 1 << 31, 1 << 31, 8] {
        hdr.extend_from_slice(&v.to_le_bytes());
    }
    hdr.extend_from_slice(&[0x78, 0x9c, 3, 0, 0, 0, 0, 1]);
    let mut b = b"<VTKFile type=\"PolyData\" compressor=\"vtkZLibDataCompressor\"><PolyData><Piece NumberOfPoints=\"1\"><Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"appended\" offset=\"0\"/></Points></Piece></PolyData><AppendedData encoding=\"raw\">_".to_vec();
    b.extend_from_slice(&hdr);
    let e = err(&b, MeshFormat::Vtp);
    assert!(matches!(e.kind, ErrorKind::Decompress(_)), "{e}");
}

#[test]
fn out_of_range_and_negative_indices() {
    let head = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0 0 1 0\n";
    let e = err(
        format!("{head}POLYGONS 1 4\n3 0 1 7\n").as_bytes(),
        MeshFormat::Vtk,
    );
    assert!(
        matches!(
            e.kind,
            ErrorKind::Geometry(GeomError::VertexIndexOutOfRange { index: 7, .. })
        ),
        "{e}"
    );
    let e = err(
        format!("{head}POLYGONS 1 4\n3 0 -1 2\n").as_bytes(),
        MeshFormat::Vtk,
    );
    assert!(
        matches!(e.kind, ErrorKind::Mesh(_)) && e.to_string().contains("-1"),
        "{e}"
    );
    for obj in [
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3//2\n",
    ] {
        let e = err(obj.as_bytes(), MeshFormat::Obj);
        assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");
    }
    let e = err(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", MeshFormat::Obj);
    assert!(
        matches!(
            e.kind,
            ErrorKind::Geometry(GeomError::VertexIndexOutOfRange { .. })
        ),
        "{e}"
    );
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
    let e = err(ply.as_bytes(), MeshFormat::Ply);
    assert!(
        matches!(
            e.kind,
            ErrorKind::Geometry(GeomError::VertexIndexOutOfRange { .. })
        ),
        "{e}"
    );
}

#[test]
fn non_finite_coordinates() {
    let vtk = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 double\n0 0 0 nan 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";
    let e = err(vtk.as_bytes(), MeshFormat::Vtk);
    assert!(
        matches!(e.kind, ErrorKind::Geometry(GeomError::NonFiniteVertex(1))),
        "{e}"
    );
    let e = err(b"v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormat::Obj);
    assert!(
        matches!(e.kind, ErrorKind::Geometry(GeomError::NonFiniteVertex(1))),
        "{e}"
    );
    let mut stl = bytes(MeshFormat::Stl, Encoding::Binary);
    stl[84 + 12..84 + 16].copy_from_slice(&f32::INFINITY.to_le_bytes());
    let e = err(&stl, MeshFormat::Stl);
    assert!(
        matches!(e.kind, ErrorKind::Geometry(GeomError::NonFiniteVertex(_))),
        "{e}"
    );
    // Writers refuse what f32 formats cannot hold.
    let big = TriMesh::new(vec![Vec3::new(1e300, 0.0, 0.0); 3], vec![[0, 1, 2]]).unwrap();
    let e = mesh_to_bytes(&big, MeshFormat::Stl, &WriteOptions::default(), "big.stl").unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Unsupported { .. }), "{e}");
}

#[test]
fn corrupt_zlib() {
    let opts = WriteOptions {
        vtp_layout: VtpLayout::AppendedRaw,
        compress: true,
        ..WriteOptions::default()
    };
    let mut b = mesh_to_bytes(&quad(), MeshFormat::Vtp, &opts, "m").unwrap();
    let start = b.windows(4).position(|w| w == b"   _").unwrap();
    let z = start
        + b[start..]
            .windows(2)
            // A zlib header: CMF 0x78 and a check byte making the pair a multiple of 31.
            .position(|w| w[0] == 0x78 && u16::from_be_bytes([w[0], w[1]]) % 31 == 0)
            .unwrap();
    b[z + 3] ^= 0xff;
    b[z + 4] ^= 0x55;
    let e = err(&b, MeshFormat::Vtp);
    assert!(matches!(e.kind, ErrorKind::Decompress(_)), "{e}");
}

#[test]
fn unknown_extension() {
    let e = read_mesh("/nonexistent/model.xyz").unwrap_err();
    assert!(
        matches!(e.kind, ErrorKind::UnknownFormat(ref x, _) if x == "xyz"),
        "{e}"
    );
    assert!(e.to_string().contains("model.xyz"), "{e}");
    let e = write_mesh("model", &quad()).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
    let e = read_mesh("/nonexistent/model.vtk").unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)), "{e}");
}

#[test]
fn reserved_ply_scalar_names_are_refused() {
    let m = quad().with_scalars("nx", vec![0.0; 4]).unwrap();
    let e = mesh_to_bytes(&m, MeshFormat::Ply, &WriteOptions::default(), "x.ply").unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Unsupported { .. }), "{e}");
}

#[test]
fn huge_counts_of_empty_elements_do_not_hang() {
    let ply = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement vertex 18446744073709551615\nelement junk 18446744073709551615\nend_header\n";
    let m = read_mesh_bytes(ply.as_bytes(), MeshFormat::Ply, "e.ply").unwrap();
    assert!(m.vertices().is_empty());
    let vtp = "<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"0\" NumberOfLines=\"18446744073709551615\" NumberOfVerts=\"18446744073709551615\" NumberOfPolys=\"18446744073709551615\"><Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\"></DataArray></Points><Polys><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\"></DataArray><DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\"></DataArray></Polys></Piece></PolyData></VTKFile>";
    let e = err(vtp.as_bytes(), MeshFormat::Vtp);
    assert!(matches!(e.kind, ErrorKind::Mesh(_)), "{e}");
}

/// Found by `cargo fuzz run mesh_vtk`: a line holding only a vertical tab is not blank to the
/// line reader but has no words; it used to index an empty word list.
#[test]
fn vtk_line_of_only_vertical_tab_is_skipped() {
    let data = b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\n\x0b\nPOINTS 3 double\n\
                 0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";
    let m = read_mesh_bytes(data, MeshFormat::Vtk, "vt.vtk").unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2]]);
}
