//! No error repeats text of the file it is about (issue #19: errors never carry client-supplied
//! text). Every reader gets files whose every free-text field, name, key and comment carries
//! [`MARKER`] (a stand-in for a patient's name) and that are broken in one way each, so that
//! each error path runs; the error's `Display` and `Debug` must not contain the marker, and the
//! message must still name what is wrong (the key, line or element).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

use std::io::Write;

use flate2::Compression;
use flate2::write::GzEncoder;
use resecta_geom::{Grid, Mat3, Vec3, VoxelLimit};
use resecta_io::metaimage::{read_metaimage, read_metaimage_bytes};
use resecta_io::nifti::{nifti_bytes, read_nifti, read_nifti_bytes};
use resecta_io::nrrd::{
    Segment, Segmentation, read_nrrd, read_nrrd_bytes, read_seg_nrrd, read_seg_nrrd_bytes,
    seg_nrrd_bytes,
};
use resecta_io::{Image, IoError, MeshFormat, VoxelData, read_mesh, read_mesh_bytes};

/// What a patient's name would be; 13 characters, so that partial copies are caught too.
const MARKER: &str = "PATIENTMARKER";
const LIMIT: VoxelLimit = VoxelLimit(1 << 24);

/// Whether `text` holds the marker or its first 10 characters (fixed-width NIfTI fields cut it),
/// in any case (some readers lower-case what they quote).
fn leaks(text: &str) -> bool {
    text.to_ascii_lowercase()
        .contains(&MARKER[..10].to_ascii_lowercase())
}

/// The error of `r`, checked: neither its `Display` nor its `Debug` holds the marker, and its
/// message contains `names` (what is wrong, in the reader's words).
fn refused<T: std::fmt::Debug>(case: &str, r: Result<T, IoError>, names: &str) {
    let e = match r {
        Ok(v) => panic!("{case}: read without an error: {v:?}"),
        Err(e) => e,
    };
    let (shown, debug) = (e.to_string(), format!("{e:?}"));
    assert!(
        !leaks(&shown),
        "{case}: the message repeats the file's text: {shown}"
    );
    assert!(
        !leaks(&debug),
        "{case}: the error's Debug repeats the file's text: {debug}"
    );
    assert!(
        shown.contains(names),
        "{case}: the message does not say {names:?}: {shown}"
    );
}

fn with_data(header: &str, data: &[u8]) -> Vec<u8> {
    [header.as_bytes(), data].concat()
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::default());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

// ---- NRRD ------------------------------------------------------------------------------------

/// A valid 2×2×2 `short` NRRD header with the marker in every free-text place: a comment, the
/// free fields (`content`, `units`, labels), and a key/value pair whose key and value are both
/// the marker. Each of `changes` sets a field (added if absent; an empty value drops it).
fn nrrd_header(changes: &[(&str, &str)]) -> String {
    let mut fields = vec![
        ("type", "short".to_owned()),
        ("dimension", "3".to_owned()),
        ("space", "left-posterior-superior".to_owned()),
        ("sizes", "2 2 2".to_owned()),
        ("space directions", "(1,0,0) (0,1,0) (0,0,1)".to_owned()),
        ("space origin", "(0,0,0)".to_owned()),
        ("endian", "little".to_owned()),
        ("encoding", "raw".to_owned()),
        ("content", format!("{MARKER} liver")),
        ("labels", format!("\"{MARKER}\" \"{MARKER}\" \"{MARKER}\"")),
        ("space units", format!("\"{MARKER}\" \"mm\" \"mm\"")),
    ];
    for (k, v) in changes {
        match fields.iter_mut().find(|(f, _)| f == k) {
            Some(f) => f.1 = (*v).to_owned(),
            None => fields.push((k, (*v).to_owned())),
        }
    }
    let mut h = format!("NRRD0004\n# {MARKER} scanned 2024\n");
    for (k, v) in fields.iter().filter(|(_, v)| !v.is_empty()) {
        h.push_str(&format!("{k}: {v}\n"));
    }
    h.push_str(&format!("{MARKER}:={MARKER}\nPatientName:={MARKER}\n"));
    h
}

fn nrrd(changes: &[(&str, &str)]) -> Vec<u8> {
    with_data(&format!("{}\n", nrrd_header(changes)), &[0; 16])
}

#[test]
fn nrrd_errors_name_the_field_not_its_value() {
    let m = MARKER;
    // The baseline is valid: each failure below is due to its one change.
    read_nrrd_bytes(&nrrd(&[]), "upload", LIMIT).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("type", nrrd(&[("type", m)]), "`type`"),
        ("dimension", nrrd(&[("dimension", m)]), "dimension"),
        ("sizes", nrrd(&[("sizes", &format!("2 2 {m}"))]), "sizes"),
        ("encoding", nrrd(&[("encoding", m)]), "`encoding`"),
        ("endian", nrrd(&[("endian", m)]), "`endian`"),
        ("space", nrrd(&[("space", m)]), "`space`"),
        (
            "space directions",
            nrrd(&[("space directions", &format!("({m},0,0) (0,1,0) (0,0,1)"))]),
            "space directions",
        ),
        (
            "space origin",
            nrrd(&[("space origin", &format!("({m})"))]),
            "space origin",
        ),
        (
            "spacings",
            nrrd(&[("space directions", ""), ("spacings", &format!("1 1 {m}"))]),
            "spacings",
        ),
        ("line skip", nrrd(&[("line skip", m)]), "line skip"),
        ("byte skip", nrrd(&[("byte skip", m)]), "byte skip"),
        // The report of issue #19: a detached data file named after the patient, uploaded.
        (
            "data file in memory",
            nrrd(&[("data file", &format!("{m}.raw"))]),
            "data file",
        ),
        (
            "datafile in memory",
            nrrd(&[("datafile", &format!("{m}.raw.gz"))]),
            "data file",
        ),
        (
            "data file list",
            nrrd(&[("data file", &format!("LIST {m}"))]),
            "data file",
        ),
        (
            "data file pattern",
            nrrd(&[("data file", &format!("{m}%03d.raw 1 3 1"))]),
            "data file",
        ),
        (
            "unparsable line",
            with_data(&format!("{}{m} {m}\n\n", nrrd_header(&[])), &[0; 16]),
            "line 16",
        ),
        (
            "short data",
            with_data(&format!("{}\n", nrrd_header(&[])), &[0; 5]),
            "bytes",
        ),
        (
            "corrupt gzip",
            with_data(
                &format!("{}\n", nrrd_header(&[("encoding", "gzip")])),
                m.as_bytes(),
            ),
            "compressed",
        ),
        (
            "4D image",
            with_data(
                &format!(
                    "{}\n",
                    nrrd_header(&[
                        ("dimension", "4"),
                        ("sizes", "2 2 2 2"),
                        ("space directions", "none (1,0,0) (0,1,0) (0,0,1)"),
                    ])
                ),
                &[0; 32],
            ),
            "segmentation",
        ),
    ];
    for (case, bytes, names) in cases {
        refused(case, read_nrrd_bytes(&bytes, "upload", LIMIT), names);
    }
}

#[test]
fn nhdr_data_file_errors_name_the_field_not_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(sub.join(format!("{MARKER}.raw")), [0u8; 3]).unwrap();
    let m = MARKER;
    let cases = [
        ("escaping", format!("../{m}.raw"), "`data file`"),
        ("absolute", format!("/tmp/{m}/{m}.raw"), "`data file`"),
        ("missing", format!("{m}_missing.raw"), "`data file`"),
        ("short", format!("{m}.raw"), "bytes"),
    ];
    for (case, name, names) in cases {
        let h = sub.join("scan.nhdr");
        std::fs::write(&h, nrrd_header(&[("data file", &name)])).unwrap();
        refused(case, read_nrrd(&h, LIMIT), names);
    }
}

/// A valid one-layer `.seg.nrrd` whose segment and segmentation keys carry the marker, with
/// `segment` keys changed or added.
fn seg(segment: &[(&str, &str)]) -> Vec<u8> {
    let mut keys: Vec<(String, String)> = vec![
        ("Segment0_ID".into(), format!("{MARKER}_id")),
        ("Segment0_Name".into(), format!("{MARKER} tumour")),
        ("Segment0_Tags".into(), format!("patient:{MARKER}|")),
        ("Segment0_Layer".into(), "0".into()),
        ("Segment0_LabelValue".into(), "1".into()),
        ("Segment0_Color".into(), "1 0 0".into()),
        ("Segment0_Extent".into(), "0 1 0 1 0 1".into()),
        ("Segment0_NameAutoGenerated".into(), MARKER.into()),
        ("Segmentation_ReferenceImageGeometry".into(), MARKER.into()),
        (format!("Segmentation_{MARKER}"), MARKER.into()),
    ];
    for (k, v) in segment {
        let k = format!("Segment0_{k}");
        match keys.iter_mut().find(|(f, _)| *f == k) {
            Some(f) => f.1 = (*v).to_owned(),
            None => keys.push((k, (*v).to_owned())),
        }
    }
    let mut h = nrrd_header(&[("type", "uchar"), ("endian", "")]);
    for (k, v) in keys {
        h.push_str(&format!("{k}:={v}\n"));
    }
    with_data(&format!("{h}\n"), &[0, 1, 0, 1, 0, 0, 0, 1])
}

#[test]
fn seg_nrrd_errors_name_the_segment_key_not_its_value() {
    let ok = read_seg_nrrd_bytes(&seg(&[]), "upload", LIMIT).unwrap();
    assert!(
        ok.segments[0].name.contains(MARKER),
        "the fixture carries the marker"
    );
    let m = MARKER;
    for (case, bytes, names) in [
        ("layer", seg(&[("Layer", m)]), "Segment0_Layer"),
        ("layer range", seg(&[("Layer", "3")]), "Segment0_Layer"),
        (
            "label value",
            seg(&[("LabelValue", m)]),
            "Segment0_LabelValue",
        ),
        (
            "color",
            seg(&[("Color", &format!("1 0 {m}"))]),
            "Segment0_Color",
        ),
        (
            "extent",
            seg(&[("Extent", &format!("0 1 0 1 0 {m}"))]),
            "Segment0_Extent",
        ),
    ] {
        refused(case, read_seg_nrrd_bytes(&bytes, "upload", LIMIT), names);
    }
    // The same through the file reader.
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("x.seg.nrrd");
    std::fs::write(&f, seg(&[("LabelValue", m)])).unwrap();
    refused("file", read_seg_nrrd(&f, LIMIT), "Segment0_LabelValue");
}

#[test]
fn segmentation_errors_number_the_segment_not_its_name() {
    let grid = Grid::new([2, 2, 2], [1.0; 3], Vec3::zeros(), Mat3::identity()).unwrap();
    let layer = resecta_geom::Volume::from_vec(grid.clone(), vec![0, 1, 0, 0, 0, 0, 0, 0]).unwrap();
    let segment = |layer, label_value| Segment {
        id: format!("{MARKER}_id"),
        name: format!("{MARKER} tumour"),
        label_value,
        layer,
        color: [1.0, 0.0, 0.0],
        extent: None,
        extra: [(MARKER.to_owned(), MARKER.to_owned())].into(),
    };
    let bad = Segmentation {
        grid: grid.clone(),
        layers: vec![layer.clone()],
        segments: vec![segment(0, 1), segment(4, 0)],
        metadata: [(MARKER.to_owned(), MARKER.to_owned())].into(),
    };
    let e = seg_nrrd_bytes(&bad).unwrap_err();
    let (shown, debug) = (e.to_string(), format!("{e:?}"));
    assert!(!leaks(&shown) && !leaks(&debug), "{shown} / {debug}");
    assert!(shown.contains("segment 1"), "{shown}");
    // Overlapping layers.
    let two = Segmentation {
        grid,
        layers: vec![layer.clone(), layer],
        segments: vec![segment(0, 1), segment(1, 2)],
        metadata: Default::default(),
    };
    let e = two.to_label_map().unwrap_err();
    assert!(!leaks(&e.to_string()) && !leaks(&format!("{e:?}")), "{e}");
}

// ---- MetaImage -------------------------------------------------------------------------------

/// A valid `.mha` header with the marker in its free text (`Comment`, `AnatomicalOrientation`,
/// unknown keys), with `changes` applied (an empty value drops the key); `ElementDataFile` last.
fn mha_header(changes: &[(&str, &str)]) -> String {
    let mut fields = vec![
        ("ObjectType", "Image".to_owned()),
        ("NDims", "3".to_owned()),
        ("Comment", format!("{MARKER} scanned 2024")),
        ("BinaryData", "True".to_owned()),
        ("BinaryDataByteOrderMSB", "False".to_owned()),
        ("CompressedData", "False".to_owned()),
        ("TransformMatrix", "1 0 0 0 1 0 0 0 1".to_owned()),
        ("Offset", "0 0 0".to_owned()),
        ("ElementSpacing", "1 1 1".to_owned()),
        ("DimSize", "2 2 2".to_owned()),
        ("AnatomicalOrientation", MARKER.to_owned()),
        (MARKER, MARKER.to_owned()),
        ("ElementType", "MET_SHORT".to_owned()),
    ];
    for (k, v) in changes {
        match fields.iter_mut().find(|(f, _)| f == k) {
            Some(f) => f.1 = (*v).to_owned(),
            None => fields.push((k, (*v).to_owned())),
        }
    }
    let data_file = fields
        .iter()
        .find(|(k, _)| *k == "ElementDataFile")
        .map_or("LOCAL".to_owned(), |(_, v)| v.clone());
    let mut h = String::new();
    for (k, v) in fields
        .iter()
        .filter(|(k, v)| !v.is_empty() && *k != "ElementDataFile")
    {
        h.push_str(&format!("{k} = {v}\n"));
    }
    h.push_str(&format!("ElementDataFile = {data_file}\n"));
    h
}

fn mha(changes: &[(&str, &str)]) -> Vec<u8> {
    with_data(&mha_header(changes), &[0; 16])
}

#[test]
fn metaimage_errors_name_the_key_not_its_value() {
    read_metaimage_bytes(&mha(&[]), "upload", LIMIT).unwrap();
    let m = MARKER;
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("ObjectType", mha(&[("ObjectType", m)]), "ObjectType"),
        ("NDims", mha(&[("NDims", m)]), "NDims"),
        (
            "DimSize",
            mha(&[("DimSize", &format!("2 2 {m}"))]),
            "DimSize",
        ),
        ("ElementType", mha(&[("ElementType", m)]), "ElementType"),
        (
            "ElementNumberOfChannels",
            mha(&[("ElementNumberOfChannels", m)]),
            "ElementNumberOfChannels",
        ),
        ("BinaryData", mha(&[("BinaryData", m)]), "BinaryData"),
        (
            "BinaryDataByteOrderMSB",
            mha(&[("BinaryDataByteOrderMSB", m)]),
            "binarydatabyteordermsb",
        ),
        (
            "CompressedData",
            mha(&[("CompressedData", m)]),
            "CompressedData",
        ),
        (
            "CompressedDataSize",
            mha(&[("CompressedData", "True"), ("CompressedDataSize", m)]),
            "CompressedDataSize",
        ),
        ("HeaderSize", mha(&[("HeaderSize", m)]), "HeaderSize"),
        (
            "ElementSpacing",
            mha(&[("ElementSpacing", &format!("1 1 {m}"))]),
            "ElementSpacing",
        ),
        ("Offset", mha(&[("Offset", &format!("0 0 {m}"))]), "offset"),
        (
            "TransformMatrix",
            mha(&[("TransformMatrix", &format!("1 0 0 0 1 0 0 0 {m}"))]),
            "transformmatrix",
        ),
        // A detached header uploaded: its data file is named after the patient.
        (
            "ElementDataFile in memory",
            mha(&[("ElementDataFile", &format!("{m}.raw"))]),
            "ElementDataFile",
        ),
        (
            "ElementDataFile list",
            mha(&[("ElementDataFile", &format!("LIST {m}"))]),
            "ElementDataFile",
        ),
        (
            "unparsable line",
            with_data(
                &format!("ObjectType = Image\n{m}\n{}", mha_header(&[])),
                &[0; 16],
            ),
            "line 2",
        ),
        ("short data", with_data(&mha_header(&[]), &[0; 3]), "bytes"),
        (
            "corrupt zlib",
            with_data(&mha_header(&[("CompressedData", "True")]), m.as_bytes()),
            "compressed",
        ),
    ];
    for (case, bytes, names) in cases {
        refused(case, read_metaimage_bytes(&bytes, "upload", LIMIT), names);
    }
}

#[test]
fn mhd_data_file_errors_name_the_key_not_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(sub.join(format!("{MARKER}.raw")), [0u8; 3]).unwrap();
    let m = MARKER;
    for (case, name, names) in [
        ("escaping", format!("../{m}.raw"), "ElementDataFile"),
        ("absolute", format!("/tmp/{m}.raw"), "ElementDataFile"),
        ("missing", format!("{m}_missing.raw"), "ElementDataFile"),
        ("short", format!("{m}.raw"), "bytes"),
    ] {
        let h = sub.join("scan.mhd");
        std::fs::write(&h, mha_header(&[("ElementDataFile", &name)])).unwrap();
        refused(case, read_metaimage(&h, LIMIT), names);
    }
}

// ---- NIfTI -----------------------------------------------------------------------------------

/// Writes `text` (cut to `len` bytes) at `at`.
fn put(b: &mut [u8], at: usize, len: usize, text: &str) {
    let t = text.as_bytes();
    let n = t.len().min(len);
    b[at..at + n].copy_from_slice(&t[..n]);
}

/// A valid NIfTI-1 with the marker in every text field (`data_type`, `db_name`, `descrip`,
/// `aux_file`, `intent_name`) and in a header extension, then `patch`ed.
fn nii(patch: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let grid = Grid::new([2, 2, 2], [1.0; 3], Vec3::zeros(), Mat3::identity()).unwrap();
    let image = Image::new(grid, VoxelData::I16(vec![0, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    let plain = nifti_bytes(&image, false).unwrap();
    let mut b = plain[..348].to_vec();
    put(&mut b, 4, 10, MARKER);
    put(&mut b, 14, 18, MARKER);
    put(&mut b, 148, 80, &format!("{MARKER} liver CT"));
    put(&mut b, 228, 24, MARKER);
    put(&mut b, 328, 16, MARKER);
    // An extension (code 6: comment) holding the marker; the data then starts at 352 + 32.
    let mut ext = 32i32.to_le_bytes().to_vec();
    ext.extend_from_slice(&6i32.to_le_bytes());
    let mut text = [0u8; 24];
    text[..MARKER.len()].copy_from_slice(MARKER.as_bytes());
    ext.extend_from_slice(&text);
    b.extend_from_slice(&[1, 0, 0, 0]);
    b.extend_from_slice(&ext);
    b[108..112].copy_from_slice(&384f32.to_le_bytes());
    b.extend_from_slice(&plain[352..]);
    patch(&mut b);
    b
}

#[test]
fn nifti_errors_never_quote_its_text_fields() {
    let ok = nii(|_| {});
    read_nifti_bytes(&ok, "upload", LIMIT).unwrap();
    assert!(
        leaks(&String::from_utf8_lossy(&ok)),
        "the fixture carries the marker"
    );
    let i16 = |v: i16| v.to_le_bytes();
    let f32 = |v: f32| v.to_le_bytes();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "datatype",
            nii(|b| b[70..72].copy_from_slice(&i16(9999))),
            "datatype",
        ),
        (
            "dim[1]",
            nii(|b| b[42..44].copy_from_slice(&i16(-3))),
            "dim[1]",
        ),
        (
            "dim[2]",
            nii(|b| b[44..46].copy_from_slice(&i16(0))),
            "dim[2]",
        ),
        (
            "vox_offset",
            nii(|b| b[108..112].copy_from_slice(&f32(1.5))),
            "vox_offset",
        ),
        (
            "pixdim",
            nii(|b| b[80..84].copy_from_slice(&f32(-1.0))),
            "spacing",
        ),
        (
            "sform",
            nii(|b| {
                b[254..256].copy_from_slice(&i16(1));
                b[280..284].copy_from_slice(&f32(f32::NAN));
            }),
            "sform",
        ),
        (
            "NIfTI pair",
            nii(|b| b[344..348].copy_from_slice(b"ni1\0")),
            "pair",
        ),
        (
            "magic",
            nii(|b| b[344..348].copy_from_slice(b"xx1\0")),
            "magic",
        ),
        ("short data", nii(|b| b.truncate(b.len() - 3)), "bytes"),
        ("short header", nii(|b| b.truncate(300)), "bytes"),
    ];
    for (case, bytes, names) in cases {
        refused(case, read_nifti_bytes(&bytes, "upload", LIMIT), names);
        let gz = gzip(&bytes);
        refused(case, read_nifti_bytes(&gz, "upload", LIMIT), names);
    }
    let gz = gzip(&ok);
    refused(
        "truncated gzip",
        read_nifti_bytes(&gz[..gz.len() - 9], "upload", LIMIT),
        "",
    );
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("x.nii");
    std::fs::write(&f, nii(|b| b[70..72].copy_from_slice(&i16(9999)))).unwrap();
    refused("file", read_nifti(&f, LIMIT), "datatype");
}

// ---- meshes ----------------------------------------------------------------------------------

fn mesh_refused(case: &str, f: MeshFormat, text: &str, names: &str) {
    refused(case, read_mesh_bytes(text.as_bytes(), f, "upload"), names);
}

const VTK_POINTS: &str = "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";

#[test]
fn vtk_legacy_errors_never_quote_names_or_words() {
    let m = MARKER;
    let head = format!("# vtk DataFile Version 3.0\n{m} liver model\nASCII\nDATASET POLYDATA\n");
    let ok = format!(
        "{head}{VTK_POINTS}POINT_DATA 3\nSCALARS {m} float 1\nLOOKUP_TABLE {m}\n1 2 3\n\
         FIELD {m} 1\n{m} 1 3 float\n1 2 3\n"
    );
    let mesh = read_mesh_bytes(ok.as_bytes(), MeshFormat::Vtk, "ok").unwrap();
    assert!(
        mesh.scalars().keys().any(|k| k.contains(m)),
        "the fixture names an array"
    );
    let cases = [
        (
            "encoding",
            format!("# vtk DataFile Version 3.0\n{m}\n{m}\n"),
            "encoding",
        ),
        (
            "dataset",
            format!("# vtk DataFile Version 3.0\n{m}\nASCII\nDATASET {m}\n"),
            "DATASET",
        ),
        ("keyword", format!("{head}{VTK_POINTS}{m} 3\n"), "keyword"),
        (
            "type",
            format!("{head}POINTS 3 {m}\n0 0 0 1 0 0 0 1 0\n"),
            "type",
        ),
        ("count", format!("{head}POINTS {m} float\n"), "POINTS"),
        (
            "number",
            format!("{head}POINTS 3 float\n0 0 0 1 0 0 0 1 {m}\n"),
            "POINTS",
        ),
        (
            "scalars",
            format!(
                "{head}{VTK_POINTS}POINT_DATA 3\nSCALARS {m} float 1\nLOOKUP_TABLE x\n1 {m} 3\n"
            ),
            "SCALARS",
        ),
        (
            "scalar type",
            format!("{head}{VTK_POINTS}POINT_DATA 3\nSCALARS {m} {m} 1\n1 2 3\n"),
            "type",
        ),
        (
            "field",
            format!("{head}{VTK_POINTS}POINT_DATA 3\nFIELD f 1\n{m} {m} 3 float\n1 2 3\n"),
            "FIELD",
        ),
        (
            "cells",
            format!("{head}{VTK_POINTS}POLYGONS 1 {m}\n"),
            "POLYGONS",
        ),
    ];
    for (case, text, names) in cases {
        mesh_refused(case, MeshFormat::Vtk, &text, names);
    }
}

#[test]
fn vtp_errors_never_quote_names_or_markup() {
    let m = MARKER;
    let vtp = |root: &str, points: &str, extra: &str| {
        format!(
            "<?xml version=\"1.0\"?>\n<!-- {m} -->\n<VTKFile type=\"PolyData\" {root}>\
             <PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\">\
             <PointData Scalars=\"{m}\"><DataArray type=\"Float32\" Name=\"{m}\" format=\"ascii\">1 2 3</DataArray></PointData>\
             <Points><DataArray type=\"Float32\" Name=\"{m}\" NumberOfComponents=\"3\" {points}</DataArray></Points>\
             <Polys><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray>\
             <DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys>\
             {extra}</Piece></PolyData></VTKFile>\n"
        )
    };
    let good = "format=\"ascii\">0 0 0 1 0 0 0 1 0";
    let mesh = read_mesh_bytes(vtp("", good, "").as_bytes(), MeshFormat::Vtp, "ok").unwrap();
    assert!(mesh.scalars().contains_key(m), "the fixture names an array");
    let cases = [
        (
            "file type",
            vtp("", good, "").replace("\"PolyData\"", &format!("\"{m}\"")),
            "type",
        ),
        (
            "byte order",
            vtp(&format!("byte_order=\"{m}\""), good, ""),
            "byte_order",
        ),
        (
            "header type",
            vtp(&format!("header_type=\"{m}\""), good, ""),
            "header_type",
        ),
        (
            "compressor",
            vtp(&format!("compressor=\"{m}\""), good, ""),
            "compressor",
        ),
        (
            "data type",
            vtp("", good, "").replace("Float32", m),
            "DataArray type",
        ),
        (
            "format",
            vtp("", &format!("format=\"{m}\">0 0 0 1 0 0 0 1 0"), ""),
            "format",
        ),
        (
            "number",
            vtp("", &format!("format=\"ascii\">0 0 0 1 0 0 0 1 {m}"), ""),
            "DataArray 1",
        ),
        (
            "too many",
            vtp("", &format!("{good} 5 {m}"), ""),
            "DataArray 1",
        ),
        (
            "count",
            vtp("", good, "").replace("NumberOfPoints=\"3\"", &format!("NumberOfPoints=\"{m}\"")),
            "NumberOfPoints",
        ),
        ("end tag", vtp("", good, &format!("<{m}></{m}x>")), "XML"),
        (
            "entity",
            vtp("", good, "").replace("NumberOfPolys=\"1\"", &format!("NumberOfPolys=\"&{m};\"")),
            "XML",
        ),
        (
            "entity in a value",
            vtp("", good, "").replace("Name=\"connectivity\"", &format!("Name=\"&{m};\"")),
            "XML",
        ),
        (
            "string points",
            vtp("", good, "").replacen("type=\"Float32\" Name", "type=\"String\" Name", 2),
            "string",
        ),
        (
            "base64",
            vtp("", &format!("format=\"binary\">{m}!!"), ""),
            "base64",
        ),
        (
            "appended",
            vtp("", "format=\"appended\" offset=\"0\">", ""),
            "AppendedData",
        ),
        (
            "appended encoding",
            vtp("", "format=\"appended\" offset=\"0\">", "").replace(
                "</VTKFile>",
                &format!("<AppendedData encoding=\"{m}\">_{m}</AppendedData></VTKFile>"),
            ),
            "encoding",
        ),
    ];
    for (case, text, names) in cases {
        mesh_refused(case, MeshFormat::Vtp, &text, names);
    }
}

#[test]
fn ply_errors_never_quote_names_or_comments() {
    let m = MARKER;
    let head = |format: &str, vertex_extra: &str| {
        format!(
            "ply\nformat {format} 1.0\ncomment {m} liver\nobj_info {m}\nelement vertex 3\n\
             property float x\nproperty float y\nproperty float z\n{vertex_extra}\
             element face 1\nproperty list uchar int vertex_indices\n\
             element {m} 0\nproperty float {m}\nend_header\n"
        )
    };
    let body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    read_mesh_bytes(
        format!("{}{body}", head("ascii", "")).as_bytes(),
        MeshFormat::Ply,
        "ok",
    )
    .unwrap();
    let cases = [
        ("format", format!("{}{body}", head(m, "")), "PLY format"),
        (
            "type",
            format!("{}{body}", head("ascii", &format!("property {m} w\n"))),
            "property type",
        ),
        (
            "line",
            format!("{}{body}", head("ascii", &format!("{m}\n"))),
            "line 9",
        ),
        (
            "list count",
            format!(
                "{}{body}",
                head("ascii", &format!("property list float int {m}\n"))
            ),
            "line 9",
        ),
        (
            "count",
            head("ascii", "").replace("vertex 3", &format!("vertex {m}")),
            "element",
        ),
        (
            "number",
            format!("{}0 0 0\n1 0 0\n0 1 {m}\n3 0 1 2\n", head("ascii", "")),
            "",
        ),
    ];
    for (case, text, names) in cases {
        mesh_refused(case, MeshFormat::Ply, &text, names);
    }
}

#[test]
fn obj_and_stl_errors_never_quote_names_or_words() {
    let m = MARKER;
    let obj = format!(
        "# {m} liver\nmtllib {m}.mtl\no {m}\ng {m}\nusemtl {m}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\n"
    );
    read_mesh_bytes(format!("{obj}f 1 2 3\n").as_bytes(), MeshFormat::Obj, "ok").unwrap();
    for (case, text, names) in [
        ("vertex", format!("{obj}v 1 {m} 0\nf 1 2 3\n"), "line 10"),
        ("index", format!("{obj}f 1 {m} 3\n"), "line 10"),
        (
            "normal index",
            format!("{obj}f 1//{m} 2//1 3//1\n"),
            "line 10",
        ),
        ("face", format!("{obj}f 1 2\n"), "line 10"),
    ] {
        mesh_refused(case, MeshFormat::Obj, &text, names);
    }
    let facet = "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n";
    read_mesh_bytes(
        format!("solid {m}\n{facet}endsolid {m}\n").as_bytes(),
        MeshFormat::Stl,
        "ok",
    )
    .unwrap();
    for (case, text, names) in [
        (
            "word",
            format!("solid {m}\n{facet}{m}\nendsolid {m}\n"),
            "unexpected word",
        ),
        (
            "vertex",
            format!(
                "solid {m}\n{}endsolid {m}\n",
                facet.replace("vertex 1 0 0", &format!("vertex 1 {m} 0"))
            ),
            "vertex",
        ),
        (
            "normal",
            format!(
                "solid {m}\n{}endsolid {m}\n",
                facet.replace("normal 0 0 1", &format!("normal 0 {m} 1"))
            ),
            "normal",
        ),
    ] {
        mesh_refused(case, MeshFormat::Stl, &text, names);
    }
    // A binary STL: the 80-byte header is free text.
    let mut bin = [0u8; 84].to_vec();
    put(&mut bin, 0, 80, &format!("{m} liver model"));
    bin[80..84].copy_from_slice(&2u32.to_le_bytes());
    bin.extend_from_slice(&[0u8; 50]);
    refused(
        "binary",
        read_mesh_bytes(&bin, MeshFormat::Stl, "upload"),
        "bytes",
    );
}

#[test]
fn the_caller_s_path_is_the_only_name_shown() {
    // Reading from a path shows the path the caller gave (the CLI user's own argument), and
    // nothing the file says.
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("model.vtk");
    std::fs::write(
        &f,
        format!("# vtk DataFile Version 3.0\n{MARKER}\nASCII\nDATASET POLYDATA\n{MARKER} 1\n"),
    )
    .unwrap();
    let e = read_mesh(&f).unwrap_err();
    assert!(e.to_string().starts_with(&f.display().to_string()), "{e}");
    assert!(!leaks(&e.to_string()), "{e}");
}
