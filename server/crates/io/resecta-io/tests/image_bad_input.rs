//! Every class of bad input gives a typed `IoError` naming the file, never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

mod image_common;

use std::path::Path;

use image_common::{all_types, oblique_grid};
use resecta_geom::{GeomError, VoxelLimit};
use resecta_io::metaimage::{mha_bytes, read_metaimage, read_metaimage_bytes};
use resecta_io::nifti::{nifti_bytes, read_nifti_bytes};
use resecta_io::nrrd::{nrrd_bytes, read_nrrd, read_nrrd_bytes};
use resecta_io::{ErrorKind, Image, IoError, read_image};

const LIMIT: VoxelLimit = VoxelLimit(1 << 30);

fn img() -> Image {
    all_types(&oblique_grid()).swap_remove(3) // i16
}

/// Checks the error names the file, and returns its kind.
fn kind(r: Result<Image, IoError>, name: &str) -> ErrorKind {
    let e = r.unwrap_err();
    assert_eq!(e.path, Path::new(name));
    assert!(e.to_string().starts_with(name), "{e}");
    assert!(e.is_bad_input(), "{e}");
    e.kind
}

fn nii(patch: impl FnOnce(&mut Vec<u8>)) -> ErrorKind {
    let mut b = nifti_bytes(&img(), false).unwrap();
    patch(&mut b);
    kind(read_nifti_bytes(&b, "bad.nii", LIMIT), "bad.nii")
}

fn nrrd_text(header: &str, data: &[u8]) -> ErrorKind {
    let mut b = header.as_bytes().to_vec();
    b.extend_from_slice(data);
    kind(read_nrrd_bytes(&b, "bad.nrrd", LIMIT), "bad.nrrd")
}

fn mha_text(header: &str, data: &[u8]) -> ErrorKind {
    let mut b = header.as_bytes().to_vec();
    b.extend_from_slice(data);
    kind(read_metaimage_bytes(&b, "bad.mha", LIMIT), "bad.mha")
}

const NRRD_OK: &str =
    "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\n\n";
const MHA_OK: &str = "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n";

#[test]
fn well_formed_baselines_read() {
    // The hand-written baselines below are valid, so each failure is due to its one change.
    assert!(read_nrrd_bytes(&[NRRD_OK.as_bytes(), &[0; 16]].concat(), "ok.nrrd", LIMIT).is_ok());
    assert!(read_metaimage_bytes(&[MHA_OK.as_bytes(), &[0; 16]].concat(), "ok.mha", LIMIT).is_ok());
}

#[test]
fn truncated_compressed_data() {
    let gz = nifti_bytes(&img(), true).unwrap();
    for cut in [10, 40, gz.len() / 2, gz.len() - 3] {
        let k = kind(read_nifti_bytes(&gz[..cut], "t.nii.gz", LIMIT), "t.nii.gz");
        assert!(
            matches!(k, ErrorKind::Decompress(_) | ErrorKind::DataSize { .. }),
            "{cut}: {k}"
        );
    }
    let n = nrrd_bytes(&img()).unwrap();
    let k = kind(
        read_nrrd_bytes(&n[..n.len() - 20], "t.nrrd", LIMIT),
        "t.nrrd",
    );
    assert!(
        matches!(k, ErrorKind::Decompress(_) | ErrorKind::DataSize { .. }),
        "{k}"
    );
    let m = mha_bytes(&img(), true).unwrap();
    let k = kind(
        read_metaimage_bytes(&m[..m.len() - 20], "t.mha", LIMIT),
        "t.mha",
    );
    assert!(matches!(k, ErrorKind::DataSize { .. }), "{k}");
}

#[test]
fn corrupt_compressed_data() {
    let mut gz = nifti_bytes(&img(), true).unwrap();
    let mid = gz.len() / 2;
    for b in &mut gz[mid..mid + 8] {
        *b ^= 0x5a;
    }
    let k = kind(read_nifti_bytes(&gz, "c.nii.gz", LIMIT), "c.nii.gz");
    assert!(
        matches!(k, ErrorKind::Decompress(_) | ErrorKind::DataSize { .. }),
        "{k}"
    );
    // A wrong CRC in the gzip trailer is caught too.
    let mut gz = nifti_bytes(&img(), true).unwrap();
    let l = gz.len();
    gz[l - 6] ^= 1;
    assert!(matches!(
        kind(read_nifti_bytes(&gz, "c.nii.gz", LIMIT), "c.nii.gz"),
        ErrorKind::Decompress(_)
    ));
    let mut m = mha_bytes(&img(), true).unwrap();
    let l = m.len();
    m[l - 30..l - 10].fill(0xff);
    assert!(matches!(
        kind(read_metaimage_bytes(&m, "c.mha", LIMIT), "c.mha"),
        ErrorKind::Decompress(_)
    ));
    let k = nrrd_text(
        &NRRD_OK.replace("raw", "gzip"),
        b"\x1f\x8b\x08\x00garbage-not-deflate",
    );
    assert!(matches!(k, ErrorKind::Decompress(_)), "{k}");
}

#[test]
fn wrong_magic() {
    assert!(matches!(
        nii(|b| b[344..348].copy_from_slice(b"abcd")),
        ErrorKind::BadMagic(_)
    ));
    assert!(matches!(
        nii(|b| b[0..4].copy_from_slice(&1234i32.to_le_bytes())),
        ErrorKind::BadMagic(_)
    ));
    assert!(matches!(
        nii(|b| b[0..4].copy_from_slice(&540i32.to_le_bytes())),
        ErrorKind::Unsupported { .. }
    ));
    assert!(matches!(
        nrrd_text("NRRX0004\n", b""),
        ErrorKind::BadMagic(_)
    ));
    assert!(matches!(mha_text("PNG\r\n", b""), ErrorKind::BadMagic(_)));
}

#[test]
fn header_and_data_size_mismatch() {
    assert!(matches!(
        nii(|b| b.truncate(b.len() - 1)),
        ErrorKind::DataSize { .. }
    ));
    assert!(matches!(
        nii(|b| b.truncate(200)),
        ErrorKind::DataSize {
            expected: 348,
            got: 200
        }
    ));
    assert!(matches!(
        nrrd_text(NRRD_OK, &[0; 15]),
        ErrorKind::DataSize {
            expected: 16,
            got: 15
        }
    ));
    assert!(matches!(
        mha_text(MHA_OK, &[0; 9]),
        ErrorKind::DataSize {
            expected: 16,
            got: 9
        }
    ));
    let k = mha_text(
        &MHA_OK.replace(
            "DimSize",
            "CompressedData = True\nCompressedDataSize = 999\nDimSize",
        ),
        &[0; 16],
    );
    assert!(
        matches!(k, ErrorKind::DataSize { expected: 999, .. }),
        "{k}"
    );
}

#[test]
fn overflowing_dims_and_voxel_limit() {
    let too_many =
        |k: &ErrorKind| matches!(k, ErrorKind::Geometry(GeomError::TooManyVoxels { .. }));
    let k = nrrd_text(
        &NRRD_OK.replace("2 2 2", "4294967296 4294967296 4294967296"),
        b"",
    );
    assert!(too_many(&k), "{k}");
    let k = nrrd_text(&NRRD_OK.replace("2 2 2", "18446744073709551615 2 2"), b"");
    assert!(too_many(&k), "{k}");
    let k = mha_text(&MHA_OK.replace("2 2 2", "4294967296 4294967296 2"), b"");
    assert!(too_many(&k), "{k}");
    // NIfTI: 32767³ is over the default limit; refused before reading any data.
    let k = nii(|b| {
        for d in 1..4 {
            b[40 + 2 * d..42 + 2 * d].copy_from_slice(&32767i16.to_le_bytes());
        }
        b.truncate(352);
    });
    assert!(too_many(&k), "{k}");
    // A small limit refuses a normal file.
    let b = nifti_bytes(&img(), false).unwrap();
    let k = kind(read_nifti_bytes(&b, "l.nii", VoxelLimit(10)), "l.nii");
    assert!(too_many(&k), "{k}");
    // Negative (i16) NIfTI dims.
    assert!(matches!(
        nii(|b| b[42..44].copy_from_slice(&(-5i16).to_le_bytes())),
        ErrorKind::Header(_)
    ));
}

#[test]
fn zero_negative_and_nan_spacing() {
    let bad = |k: &ErrorKind| matches!(k, ErrorKind::Geometry(GeomError::BadSpacing(_)));
    for v in [0.0f32, -1.0, f32::NAN, f32::INFINITY] {
        // pixdim[2]
        let k = nii(|b| b[84..88].copy_from_slice(&v.to_le_bytes()));
        assert!(bad(&k), "{v}: {k}");
    }
    for s in ["0 1 1", "1 -2 1", "1 1 nan"] {
        let k = mha_text(
            &MHA_OK.replace("DimSize", &format!("ElementSpacing = {s}\nDimSize")),
            &[0; 16],
        );
        assert!(bad(&k) || matches!(k, ErrorKind::Header(_)), "{s}: {k}");
    }
    for s in ["0 1 1", "1 -2 1", "1 1 nan"] {
        let k = nrrd_text(
            &NRRD_OK.replace("encoding", &format!("spacings: {s}\nencoding")),
            &[0; 16],
        );
        assert!(bad(&k), "{s}: {k}");
    }
    // A zero space direction.
    let k = nrrd_text(
        &NRRD_OK.replace(
            "encoding",
            "space: RAS\nspace directions: (1,0,0) (0,0,0) (0,0,1)\nencoding",
        ),
        &[0; 16],
    );
    assert!(bad(&k), "{k}");
}

#[test]
fn singular_direction() {
    let sing = |k: &ErrorKind| matches!(k, ErrorKind::Geometry(GeomError::SingularDirection));
    // sform with two equal rows' columns: column 1 = column 0.
    let k = nii(|b| {
        for r in 0..3 {
            let c0: [u8; 4] = b[280 + 16 * r..284 + 16 * r].try_into().unwrap();
            b[284 + 16 * r..288 + 16 * r].copy_from_slice(&c0);
        }
    });
    assert!(sing(&k), "{k}");
    let k = nrrd_text(
        &NRRD_OK.replace(
            "encoding",
            "space: LPS\nspace directions: (1,0,0) (2,0,0) (0,0,1)\nencoding",
        ),
        &[0; 16],
    );
    assert!(sing(&k), "{k}");
    let k = mha_text(
        &MHA_OK.replace("DimSize", "TransformMatrix = 1 0 0 1 0 0 0 0 1\nDimSize"),
        &[0; 16],
    );
    assert!(sing(&k), "{k}");
}

#[test]
fn unsupported_data_types() {
    let unsup = |k: &ErrorKind| {
        matches!(
            k,
            ErrorKind::Unsupported { .. } | ErrorKind::UnknownValue { .. }
        )
    };
    for code in [128i16, 32, 1024, 1, 9999] {
        let k = nii(|b| b[70..72].copy_from_slice(&code.to_le_bytes()));
        assert!(unsup(&k), "{code}: {k}");
    }
    for t in ["int64", "block", "unsigned long long"] {
        assert!(
            unsup(&nrrd_text(&NRRD_OK.replace("short", t), &[0; 64])),
            "{t}"
        );
    }
    assert!(unsup(&nrrd_text(
        &NRRD_OK.replace("raw", "bzip2"),
        &[0; 16]
    )));
    assert!(unsup(&mha_text(
        &MHA_OK.replace("MET_SHORT", "MET_LONG_LONG"),
        &[0; 64]
    )));
    assert!(unsup(&mha_text(
        &MHA_OK.replace("NDims = 3", "NDims = 4"),
        &[0; 64]
    )));
    // A real 4D NIfTI (t = 2).
    assert!(unsup(&nii(|b| {
        b[40..42].copy_from_slice(&4i16.to_le_bytes());
        b[48..50].copy_from_slice(&2i16.to_le_bytes());
    })));
}

#[test]
// The error kinds other than the one expected only fail the test; listing them adds nothing.
#[allow(clippy::wildcard_enum_match_arm)]
fn missing_required_fields() {
    let missing = |k: ErrorKind, f: &str| match k {
        ErrorKind::MissingField(m) => assert!(m.eq_ignore_ascii_case(f), "{m} vs {f}"),
        other => panic!("{f}: {other}"),
    };
    for f in ["type", "dimension", "sizes", "encoding", "endian"] {
        let h: String = NRRD_OK
            .lines()
            .filter(|l| !l.starts_with(&format!("{f}:")))
            .map(|l| format!("{l}\n"))
            .collect();
        missing(nrrd_text(&h, &[0; 16]), f);
    }
    for f in ["NDims", "DimSize", "ElementType", "ElementDataFile"] {
        let h: String = MHA_OK
            .lines()
            .filter(|l| !l.starts_with(f))
            .map(|l| format!("{l}\n"))
            .collect();
        let data: &[u8] = if f == "ElementDataFile" {
            b""
        } else {
            &[0; 16]
        };
        missing(mha_text(&h, data), f);
    }
}

#[test]
fn detached_data_paths_cannot_leave_the_header_folder() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(dir.path().join("secret.raw"), [0u8; 16]).unwrap();
    for target in ["../secret.raw", "/etc/passwd", "a/../../secret.raw"] {
        let h = sub.join("x.nhdr");
        std::fs::write(&h, format!("{}\ndata file: {target}\n", NRRD_OK.trim_end())).unwrap();
        let e = read_nrrd(&h, LIMIT).unwrap_err();
        assert_eq!(e.path, h);
        assert!(matches!(e.kind, ErrorKind::UnsafePath(_)), "{target}: {e}");
        let h = sub.join("x.mhd");
        std::fs::write(&h, MHA_OK.replace("LOCAL", target)).unwrap();
        let e = read_metaimage(&h, LIMIT).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::UnsafePath(_)), "{target}: {e}");
    }
    // Inside the folder is fine.
    std::fs::write(sub.join("ok.raw"), [0u8; 16]).unwrap();
    let h = sub.join("ok.nhdr");
    std::fs::write(&h, format!("{}\ndata file: ./ok.raw\n", NRRD_OK.trim_end())).unwrap();
    assert!(read_nrrd(&h, LIMIT).is_ok());
    // A missing data file is an I/O error naming the header and the field, not the file's
    // name (header text, often the patient's name).
    std::fs::write(
        &h,
        format!("{}\ndata file: nothere.raw\n", NRRD_OK.trim_end()),
    )
    .unwrap();
    let e = read_nrrd(&h, LIMIT).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)) && e.path == h, "{e}");
    assert!(e.to_string().contains("`data file`"), "{e}");
    assert!(!e.to_string().contains("nothere"), "{e}");
}

#[test]
fn unknown_extension_and_missing_file() {
    let e = read_image("scan.dcm", LIMIT).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::UnknownFormat(..)), "{e}");
    let e = read_image("/nonexistent/x.nii.gz", LIMIT).unwrap_err();
    assert!(
        matches!(e.kind, ErrorKind::Io(_)) && e.is_bad_input(),
        "{e}"
    );
}
