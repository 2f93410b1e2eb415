//! Mutated and truncated valid files of every image format: the readers return `Ok` or a typed
//! error, never panic (stable-Rust companion of the `fuzz/` targets; bounded, a few seconds).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

mod image_common;

use std::sync::OnceLock;

use image_common::{all_types, general_grid};
use proptest::prelude::*;
use resecta_geom::VoxelLimit;
use resecta_io::metaimage::{mha_bytes, read_metaimage_bytes};
use resecta_io::nifti::{nifti_bytes, read_nifti_bytes};
use resecta_io::nrrd::{
    Segmentation, nrrd_bytes, read_nrrd_bytes, read_seg_nrrd_bytes, seg_nrrd_bytes,
};

/// Small limit so mutated sizes cannot make the test slow.
const LIMIT: VoxelLimit = VoxelLimit(1 << 16);

/// Valid files: NIfTI raw/gz, NRRD gzip and raw, seg.nrrd, MHA raw/zlib.
fn corpus() -> &'static Vec<(&'static str, Vec<u8>)> {
    static C: OnceLock<Vec<(&'static str, Vec<u8>)>> = OnceLock::new();
    C.get_or_init(|| {
        let imgs = all_types(&general_grid());
        let (i16img, f32img) = (&imgs[3], &imgs[6]);
        let mut raw_nrrd = b"NRRD0004\ntype: short\ndimension: 3\nspace: RAS\nsizes: 2 2 2\n\
space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\nendian: big\nencoding: raw\n\n"
            .to_vec();
        raw_nrrd.extend_from_slice(&[7u8; 16]);
        let labels = i16img.to_volume_f32().map(|v| (v.abs() as u16) % 3);
        vec![
            ("nifti", nifti_bytes(i16img, false).unwrap()),
            ("nifti", nifti_bytes(f32img, true).unwrap()),
            ("nrrd", nrrd_bytes(i16img).unwrap()),
            ("nrrd", raw_nrrd),
            (
                "seg",
                seg_nrrd_bytes(&Segmentation::from_label_map(labels)).unwrap(),
            ),
            ("mha", mha_bytes(i16img, false).unwrap()),
            ("mha", mha_bytes(f32img, true).unwrap()),
        ]
    })
}

/// Runs the reader of `kind`; a panic fails the test, any `Result` passes.
fn read(kind: &str, bytes: &[u8]) {
    match kind {
        "nifti" => drop(read_nifti_bytes(bytes, "m.nii", LIMIT)),
        "nrrd" => drop(read_nrrd_bytes(bytes, "m.nrrd", LIMIT)),
        "seg" => drop(read_seg_nrrd_bytes(bytes, "m.seg.nrrd", LIMIT)),
        _ => drop(read_metaimage_bytes(bytes, "m.mha", LIMIT)),
    }
}

#[test]
fn corpus_is_valid() {
    for (kind, b) in corpus() {
        let ok = match *kind {
            "nifti" => read_nifti_bytes(b, "c", LIMIT).is_ok(),
            "nrrd" => read_nrrd_bytes(b, "c", LIMIT).is_ok(),
            "seg" => read_seg_nrrd_bytes(b, "c", LIMIT).is_ok(),
            _ => read_metaimage_bytes(b, "c", LIMIT).is_ok(),
        };
        assert!(ok, "{kind} fixture must read");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 768, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn truncated_files_never_panic(file in 0usize..7, frac in 0.0f64..1.0) {
        let (kind, b) = &corpus()[file];
        read(kind, &b[..(b.len() as f64 * frac) as usize]);
    }

    #[test]
    fn mutated_files_never_panic(
        file in 0usize..7,
        edits in prop::collection::vec((0.0f64..1.0, any::<u8>(), 0u8..4), 1..8),
    ) {
        let (kind, orig) = &corpus()[file];
        let mut b = orig.clone();
        for (at, byte, op) in edits {
            if b.is_empty() { break; }
            // Bias half the edits towards the header, where the parsing is.
            let span = if op % 2 == 0 { b.len().min(400) } else { b.len() };
            let i = ((span as f64 * at) as usize).min(b.len() - 1);
            match op {
                0 | 1 => b[i] = byte,
                2 => { b.insert(i, byte); }
                _ => { b.remove(i); }
            }
        }
        read(kind, &b);
    }

    #[test]
    fn header_field_values_never_panic(file in 3usize..7, line in 0usize..20, value in "[-0-9a-z .,()e]{0,24}") {
        // Replace the value of one text header line (NRRD / MetaImage) with junk.
        let (kind, orig) = &corpus()[file];
        let text_end = orig.windows(2).position(|w| w == b"\n\n" || w == b"L\n").unwrap_or(orig.len());
        let head = String::from_utf8_lossy(&orig[..text_end]).into_owned();
        let mut lines: Vec<String> = head.lines().map(String::from).collect();
        let n = lines.len();
        let l = &mut lines[line % n];
        if let Some(p) = l.find(": ").map(|p| p + 2).or_else(|| l.find(" = ").map(|p| p + 3)) {
            l.truncate(p);
            l.push_str(&value);
        }
        let mut b = lines.join("\n").into_bytes();
        b.extend_from_slice(&orig[text_end..]);
        read(kind, &b);
    }
}
