//! Mutated and truncated mesh files of every format and variant: readers return `Ok` or a typed
//! error naming the file, and never panic.

// Test helpers outside #[test] functions may unwrap too.
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use resecta_geom::{TriMesh, Vec3};
use resecta_io::{Encoding, MeshFormat, VtpLayout, WriteOptions, mesh_to_bytes, read_mesh_bytes};

fn sample() -> TriMesh {
    let v = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(10.5, 0.0, 0.0),
        Vec3::new(0.0, 7.25, 0.0),
        Vec3::new(0.0, 0.0, 3.125),
    ];
    let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let m = TriMesh::new(v, t).unwrap();
    let n = m.compute_vertex_normals();
    m.with_normals(n)
        .unwrap()
        .with_scalars("d", vec![0.5, 1.5, 2.5, 3.5])
        .unwrap()
}

/// One valid file per format and variant (built once).
fn corpus() -> &'static [(MeshFormat, Vec<u8>)] {
    static CORPUS: std::sync::OnceLock<Vec<(MeshFormat, Vec<u8>)>> = std::sync::OnceLock::new();
    CORPUS.get_or_init(build_corpus)
}

fn build_corpus() -> Vec<(MeshFormat, Vec<u8>)> {
    let m = sample();
    let mut opts = vec![];
    for encoding in [Encoding::Ascii, Encoding::Binary, Encoding::BinaryBigEndian] {
        opts.push(WriteOptions {
            encoding,
            ..WriteOptions::default()
        });
    }
    for vtp_layout in [
        VtpLayout::Inline,
        VtpLayout::AppendedRaw,
        VtpLayout::AppendedBase64,
    ] {
        for compress in [false, true] {
            opts.push(WriteOptions {
                encoding: Encoding::Binary,
                vtp_layout,
                compress,
                header_u64: compress,
            });
        }
    }
    let mut out = vec![];
    for f in MeshFormat::ALL {
        for o in &opts {
            let b = mesh_to_bytes(&m, f, o, "seed").unwrap();
            if !out.iter().any(|(g, c)| *g == f && *c == b) {
                out.push((f, b));
            }
        }
    }
    out
}

#[derive(Debug, Clone)]
enum Mutation {
    Truncate(usize),
    Flip(Vec<(usize, u8)>),
    Insert(usize, Vec<u8>),
    Digits(usize, u64),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<usize>().prop_map(Mutation::Truncate),
        prop::collection::vec((any::<usize>(), any::<u8>()), 1..8).prop_map(Mutation::Flip),
        (any::<usize>(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(at, b)| Mutation::Insert(at, b)),
        (any::<usize>(), any::<u64>()).prop_map(|(at, v)| Mutation::Digits(at, v)),
    ]
}

fn apply(mut b: Vec<u8>, m: &Mutation) -> Vec<u8> {
    let n = b.len().max(1);
    match m {
        Mutation::Truncate(at) => b.truncate(at % n),
        Mutation::Flip(edits) => {
            for &(at, x) in edits {
                if let Some(c) = b.get_mut(at % n) {
                    *c ^= x | 1;
                }
            }
        }
        Mutation::Insert(at, bytes) => {
            let at = at % n;
            b.splice(at.min(b.len())..at.min(b.len()), bytes.iter().copied());
        }
        Mutation::Digits(at, v) => {
            // Overwrite with a big decimal number: attacks counts in text headers.
            let at = (at % n).min(b.len());
            let s = v.to_string();
            let end = (at + s.len()).min(b.len());
            b.splice(at..end, s.bytes());
        }
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20_000, ..ProptestConfig::default() })]

    #[test]
    fn mutated_files_never_panic(k in any::<usize>(), m in mutation()) {
        let corpus = corpus();
        let (format, seed) = &corpus[k % corpus.len()];
        let data = apply(seed.clone(), &m);
        match read_mesh_bytes(&data, *format, "fuzzed") {
            Ok(mesh) => {
                let n = mesh.vertices().len();
                prop_assert!(mesh.triangles().iter().flatten().all(|&i| (i as usize) < n));
            }
            Err(e) => {
                prop_assert_eq!(e.path.to_str(), Some("fuzzed"));
                prop_assert!(!e.to_string().is_empty());
            }
        }
    }
}

#[test]
fn every_seed_reads_back_and_every_prefix_is_handled() {
    let corpus = corpus();
    assert!(corpus.len() >= 14, "{} seeds", corpus.len());
    for (f, b) in corpus {
        let m = read_mesh_bytes(b, *f, "seed").unwrap();
        assert_eq!(m.triangles().len(), 4, "{f:?}");
        // Every truncation of every seed (the files are small).
        for cut in 0..b.len() {
            let r = read_mesh_bytes(&b[..cut], *f, "cut");
            if let Err(e) = r {
                assert_eq!(e.path.to_str(), Some("cut"));
            }
        }
    }
}
