//! Snapshot and delta round trips (exact, quantised, zstd), delta sizes, robustness against
//! corrupted input, and the replay ring.

use proptest::prelude::*;
use resecta_delta::{
    DecodeLimits, DeltaError, DeltaStats, EncodeOptions, HEADER_BYTES, Kind, Quantise, ReplayRing,
    Since, SurfaceFrame, Topology, VERSION, apply_delta, decode_mesh, encode_delta, encode_mesh,
    flags, inspect, oct_decode, oct_encode,
};

/// A curved r×r grid surface around (140, −20, 205) RAS mm with analytic unit normals, margins
/// (distance to a point tumour centre minus its radius) and classes from them; `t` moves it.
fn grid_frame(r: usize, t: f64) -> (Topology, SurfaceFrame) {
    let mut f = SurfaceFrame::default();
    for a in 0..r {
        for b in 0..r {
            let (u, v) = (a as f64 / (r - 1) as f64, b as f64 / (r - 1) as f64);
            let h = 8.0 * (3.0 * u + t).sin() * (2.0 * v).cos();
            let p = [100.0 + 80.0 * u, -50.0 + 60.0 * v, 200.0 + h];
            // ∂p/∂u × ∂p/∂v with ∂h/∂u, ∂h/∂v.
            let hu = 24.0 * (3.0 * u + t).cos() * (2.0 * v).cos();
            let hv = -16.0 * (3.0 * u + t).sin() * (2.0 * v).sin();
            let n = [-hu * 60.0, -hv * 80.0, 80.0 * 60.0];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let d = ((p[0] - 140.0).powi(2) + (p[1] + 20.0).powi(2) + (p[2] - 215.0).powi(2))
                .sqrt()
                - 10.0;
            f.positions.push(p.map(|x| x as f32));
            f.normals.push(n.map(|x| (x / len) as f32));
            f.margins.push(d as f32);
            f.classes.push(if d < 10.0 {
                3
            } else if d < 15.0 {
                2
            } else {
                1
            });
        }
    }
    let mut triangles = Vec::new();
    for a in 0..r - 1 {
        for b in 0..r - 1 {
            let k = (a * r + b) as u32;
            let r = r as u32;
            triangles.push([k, k + r, k + 1]);
            triangles.push([k + 1, k + r, k + r + 1]);
        }
    }
    (Topology { triangles }, f)
}

/// Positions, normals, margins (as bits) and classes.
type FrameBits = (Vec<[u32; 3]>, Vec<[u32; 3]>, Vec<u32>, Vec<u8>);

fn bits(f: &SurfaceFrame) -> FrameBits {
    (
        f.positions.iter().map(|p| p.map(f32::to_bits)).collect(),
        f.normals.iter().map(|p| p.map(f32::to_bits)).collect(),
        f.margins.iter().map(|m| m.to_bits()).collect(),
        f.classes.clone(),
    )
}

fn limits() -> DecodeLimits {
    DecodeLimits::default()
}

fn all_options() -> Vec<EncodeOptions> {
    vec![
        EncodeOptions::exact(),
        EncodeOptions::exact().with_zstd(1),
        EncodeOptions::quantised(),
        EncodeOptions::quantised().with_zstd(3),
    ]
}

fn angle(a: &[f32; 3], b: &[f32; 3]) -> f64 {
    let a = a.map(f64::from);
    let b = b.map(f64::from);
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let c = (cross[0].powi(2) + cross[1].powi(2) + cross[2].powi(2)).sqrt();
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    c.atan2(d)
}

/// Stated position bound: per coordinate ≤ extent/131068 (half a u16 step over the box of the
/// sent vertices) + half an f32 ulp of the coordinate; below extent/65535 + one ulp.
fn position_bound(extent: f32, v: f32) -> f64 {
    f64::from(extent) / 131_068.0 + f64::from(v.abs()) * f64::from(f32::EPSILON)
}

/// Stated normal bound: octahedral snorm16 with the best of the four neighbouring codes
/// (measured worst 4.31e-5 rad over 5 M Fibonacci-sphere directions, near the face centres).
const NORMAL_BOUND_RAD: f64 = 5e-5;

fn extent(points: &[[f32; 3]]) -> [f32; 3] {
    std::array::from_fn(|k| {
        let lo = points.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min);
        let hi = points
            .iter()
            .map(|p| p[k])
            .fold(f32::NEG_INFINITY, f32::max);
        hi - lo
    })
}

fn assert_quantised_close(got: &SurfaceFrame, want: &SurfaceFrame, ext: [f32; 3]) {
    assert_eq!(got.positions.len(), want.positions.len());
    for (g, w) in got.positions.iter().zip(&want.positions) {
        for k in 0..3 {
            let err = f64::from((g[k] - w[k]).abs());
            assert!(
                err <= position_bound(ext[k], w[k]),
                "axis {k}: {} vs {}, error {err}, extent {}",
                g[k],
                w[k],
                ext[k]
            );
            assert!(err <= f64::from(ext[k]) / 65535.0 + f64::from(w[k].abs()) * 1.2e-7);
        }
    }
    for (g, w) in got.normals.iter().zip(&want.normals) {
        let a = angle(g, w);
        assert!(a <= NORMAL_BOUND_RAD, "normal {g:?} vs {w:?}: {a} rad");
        let len = g.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((len - 1.0).abs() < 1e-6, "decoded normal length {len}");
    }
    assert_eq!(
        bits(got).2,
        bits(want).2,
        "margins are exact even when quantised"
    );
    assert_eq!(got.classes, want.classes);
}

// ---------------------------------------------------------------- snapshots

#[test]
fn mesh_round_trip_is_bitwise_exact_with_and_without_zstd() {
    let (topo, mut frame) = grid_frame(40, 0.3);
    // Special values travel as data.
    frame.positions[7] = [f32::NAN, -0.0, f32::INFINITY];
    frame.margins[3] = f32::NEG_INFINITY;
    frame.normals[5] = [0.0; 3];
    for opts in [EncodeOptions::exact(), EncodeOptions::exact().with_zstd(1)] {
        let bytes = encode_mesh(&topo, &frame, &opts).unwrap();
        let h = inspect(&bytes).unwrap();
        assert_eq!(h.kind, Kind::Mesh);
        assert_eq!(h.has(flags::ZSTD), opts.zstd_level.is_some());
        let (t2, f2) = decode_mesh(&bytes, &limits()).unwrap();
        assert_eq!(t2, topo);
        assert_eq!(bits(&f2), bits(&frame));
    }
}

#[test]
fn exact_mesh_size_is_header_plus_sections() {
    let (topo, frame) = grid_frame(40, 0.0);
    let bytes = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap();
    let (n, t) = (1600, topo.triangles.len());
    assert_eq!(bytes.len(), HEADER_BYTES + 12 * t + n * (12 + 12 + 4 + 1));
    let q = encode_mesh(&topo, &frame, &EncodeOptions::quantised()).unwrap();
    assert_eq!(
        q.len(),
        HEADER_BYTES + 12 * t + 24 + 6 * n + 4 * n + 4 * n + n
    );
}

#[test]
fn mesh_without_optional_attributes_round_trips() {
    let (topo, mut frame) = grid_frame(5, 0.0);
    frame.normals.clear();
    frame.margins.clear();
    frame.classes.clear();
    for opts in all_options() {
        let bytes = encode_mesh(&topo, &frame, &opts).unwrap();
        let h = inspect(&bytes).unwrap();
        assert_eq!(h.flags & 0b1111, flags::POSITIONS);
        let (t2, f2) = decode_mesh(&bytes, &limits()).unwrap();
        assert_eq!(t2, topo);
        assert!(f2.normals.is_empty() && f2.margins.is_empty() && f2.classes.is_empty());
        assert_eq!(f2.positions.len(), 25);
    }
    // Empty mesh.
    let empty = encode_mesh(
        &Topology::default(),
        &SurfaceFrame::default(),
        &EncodeOptions::quantised().with_zstd(1),
    )
    .unwrap();
    let (t, f) = decode_mesh(&empty, &limits()).unwrap();
    assert!(t.triangles.is_empty() && f.positions.is_empty());
}

#[test]
fn quantised_mesh_is_within_the_stated_bounds() {
    let (topo, frame) = grid_frame(60, 1.1);
    let ext = extent(&frame.positions);
    for opts in [
        EncodeOptions::quantised(),
        EncodeOptions::quantised().with_zstd(1),
    ] {
        let bytes = encode_mesh(&topo, &frame, &opts).unwrap();
        let (t2, f2) = decode_mesh(&bytes, &limits()).unwrap();
        assert_eq!(t2, topo);
        assert_quantised_close(&f2, &frame, ext);
    }
}

#[test]
fn quantise_positions_only_keeps_normals_exact() {
    let (topo, frame) = grid_frame(10, 0.0);
    let opts = EncodeOptions {
        quantise: Some(Quantise {
            positions: true,
            normals: false,
        }),
        zstd_level: None,
    };
    let (_, f2) = decode_mesh(&encode_mesh(&topo, &frame, &opts).unwrap(), &limits()).unwrap();
    assert_eq!(bits(&f2).1, bits(&frame).1);
    assert_quantised_close(&f2, &frame, extent(&frame.positions));
}

#[test]
fn quantised_non_finite_and_degenerate_values() {
    let (topo, mut frame) = grid_frame(4, 0.0);
    frame.positions[2] = [f32::NAN, 1.0e3, f32::NEG_INFINITY];
    frame.normals[1] = [0.0; 3];
    frame.normals[2] = [f32::NAN, 0.0, 1.0];
    frame.normals[3] = [0.0, 0.0, -7.0]; // not unit: sent as its direction
    let (_, f2) = decode_mesh(
        &encode_mesh(&topo, &frame, &EncodeOptions::quantised()).unwrap(),
        &limits(),
    )
    .unwrap();
    assert!(f2.positions[2][0].is_nan() && f2.positions[2][2].is_nan());
    assert_eq!(f2.normals[1], [0.0; 3]);
    assert_eq!(f2.normals[2], [0.0; 3]);
    assert!(angle(&f2.normals[3], &[0.0, 0.0, -1.0]) <= NORMAL_BOUND_RAD);
    // A flat axis (zero extent) decodes exactly.
    let (topo, mut flat) = grid_frame(4, 0.0);
    for p in &mut flat.positions {
        p[2] = 212.25;
    }
    let (_, f3) = decode_mesh(
        &encode_mesh(&topo, &flat, &EncodeOptions::quantised()).unwrap(),
        &limits(),
    )
    .unwrap();
    assert!(f3.positions.iter().all(|p| p[2] == 212.25));
}

#[test]
fn octahedral_normals_error_is_below_the_bound_on_all_directions() {
    // A dense Fibonacci sphere plus the axes, the octant diagonals and near-fold directions.
    let mut dirs: Vec<[f32; 3]> = Vec::new();
    let count = 200_000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..count {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / count as f64;
        let r = (1.0 - z * z).sqrt();
        let a = golden * i as f64;
        dirs.push([(r * a.cos()) as f32, (r * a.sin()) as f32, z as f32]);
    }
    const H: f32 = std::f32::consts::FRAC_1_SQRT_2;
    for s in [-1.0f32, 1.0] {
        dirs.extend([[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]]);
        dirs.push([s * 0.577_350_3, 0.577_350_3, -0.577_350_3]);
        dirs.push([s * H, -H, 1e-7]);
        dirs.push([1e-7, s * H, -H]);
    }
    let mut worst = 0.0f64;
    for d in &dirs {
        let e = angle(&oct_decode(oct_encode(d)), d);
        worst = worst.max(e);
    }
    eprintln!("worst normal error {worst} rad");
    assert!(worst <= NORMAL_BOUND_RAD, "worst normal error {worst} rad");
    assert!(worst > 1e-6, "worst {worst}: suspiciously exact");
}

#[test]
fn mesh_triangles_must_index_existing_vertices() {
    let (mut topo, frame) = grid_frame(3, 0.0);
    topo.triangles[2] = [0, 1, 9];
    let err = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap_err();
    assert!(matches!(
        err,
        DeltaError::TriangleIndex {
            triangle: 2,
            index: 9,
            vertices: 9
        }
    ));
    // A crafted message with a bad index: patch a valid one.
    topo.triangles[2] = [0, 1, 8];
    let mut bytes = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap();
    let at = HEADER_BYTES + 2 * 12 + 8;
    bytes[at..at + 4].copy_from_slice(&9u32.to_le_bytes());
    let err = decode_mesh(&bytes, &limits()).unwrap_err();
    assert!(
        matches!(err, DeltaError::TriangleIndex { index: 9, .. }),
        "{err}"
    );
}

#[test]
fn frames_with_inconsistent_attributes_are_refused() {
    let (topo, mut frame) = grid_frame(3, 0.0);
    frame.margins.pop();
    let err = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap_err();
    assert!(matches!(
        err,
        DeltaError::AttributeLength {
            what: "margins",
            len: 8,
            expected: 9
        }
    ));
    let (_, a) = grid_frame(3, 0.0);
    let mut b = a.clone();
    b.classes.clear();
    assert!(matches!(
        encode_delta(&a, &b, &EncodeOptions::exact()),
        Err(DeltaError::AttributeMismatch {
            what: "classes",
            ..
        })
    ));
    let (_, c) = grid_frame(4, 0.0);
    assert!(matches!(
        encode_delta(&a, &c, &EncodeOptions::exact()),
        Err(DeltaError::VertexCount { left: 9, right: 16 })
    ));
}

#[test]
fn decode_limits_are_enforced_before_decoding() {
    let (topo, frame) = grid_frame(20, 0.0);
    let bytes = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap();
    let small = DecodeLimits {
        max_vertices: 399,
        max_triangles: 10_000,
    };
    assert!(matches!(
        decode_mesh(&bytes, &small),
        Err(DeltaError::TooLarge {
            what: "vertex",
            count: 400,
            limit: 399
        })
    ));
    let small = DecodeLimits {
        max_vertices: 400,
        max_triangles: 721,
    };
    assert!(matches!(
        decode_mesh(&bytes, &small),
        Err(DeltaError::TooLarge {
            what: "triangle",
            count: 722,
            ..
        })
    ));
    // Huge declared counts in a short message: refused by the size check, nothing allocated.
    let mut huge = bytes.clone();
    huge[8..12].copy_from_slice(&(8u32 << 20).to_le_bytes());
    assert!(matches!(
        decode_mesh(&huge, &limits()),
        Err(DeltaError::PayloadSize { .. })
    ));
    let mut huge = bytes;
    huge[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        decode_mesh(&huge, &limits()),
        Err(DeltaError::TooLarge { .. })
    ));
}

#[test]
fn header_errors_name_the_problem() {
    let (topo, frame) = grid_frame(3, 0.0);
    let good = encode_mesh(&topo, &frame, &EncodeOptions::exact()).unwrap();
    let mut b = good.clone();
    b[0] = b'X';
    assert!(matches!(
        decode_mesh(&b, &limits()),
        Err(DeltaError::BadMagic { .. })
    ));
    for old_or_new in [1u8, 3] {
        let mut b = good.clone();
        b[4] = old_or_new;
        assert!(matches!(
            decode_mesh(&b, &limits()),
            Err(DeltaError::UnsupportedVersion { found, supported: VERSION })
                if found == u16::from(old_or_new)
        ));
    }
    let mut b = good.clone();
    b[7] |= 0x80;
    assert!(matches!(
        decode_mesh(&b, &limits()),
        Err(DeltaError::BadFlags { .. })
    ));
    let mut b = good.clone();
    b.push(0);
    assert!(matches!(
        decode_mesh(&b, &limits()),
        Err(DeltaError::TrailingBytes { count: 1 })
    ));
    assert!(matches!(
        decode_mesh(&good[..good.len() - 4], &limits()),
        Err(DeltaError::Truncated { .. })
    ));
    assert!(matches!(
        decode_mesh(&good[..10], &limits()),
        Err(DeltaError::Truncated { what: "header", .. })
    ));
    let mut f = frame.clone();
    assert!(matches!(
        apply_delta(&mut f, &good, &limits()),
        Err(DeltaError::WrongKind {
            found: Kind::Mesh,
            expected: Kind::Delta
        })
    ));
    assert!(
        DeltaError::TooLarge {
            what: "vertex",
            count: 9,
            limit: 8
        }
        .to_string()
        .contains("vertex count 9 exceeds the limit 8")
    );
}

/// The zstd frame of a compressed message (the bytes after the header).
fn zstd_frame(msg: &[u8]) -> &[u8] {
    assert!(matches!(inspect(msg), Ok(h) if h.has(flags::ZSTD)));
    &msg[HEADER_BYTES..]
}

/// The message with its payload replaced by `body` (the header kept).
fn with_body(msg: &[u8], body: &[u8]) -> Vec<u8> {
    [&msg[..HEADER_BYTES], body].concat()
}

#[test]
fn zstd_frames_carry_a_checksum_that_every_decode_verifies() {
    let (topo, prev) = grid_frame(40, 0.0);
    let (_, next) = grid_frame(40, 0.2);
    let opts = EncodeOptions::quantised().with_zstd(3);
    let mesh = encode_mesh(&topo, &prev, &opts).unwrap();
    let delta = encode_delta(&prev, &next, &opts).unwrap();
    for msg in [&mesh, &delta] {
        let frame = zstd_frame(msg);
        // Frame header descriptor: Content_Checksum_flag (bit 2) and a content size.
        assert_eq!(frame[..4], [0x28, 0xB5, 0x2F, 0xFD]);
        assert_ne!(frame[4] & 0x04, 0, "no checksum flag");
        let payload = zstd::bulk::decompress(frame, 1 << 24).unwrap();
        assert_eq!(payload.len(), inspect(msg).unwrap().payload_bytes as usize);
        assert_eq!(
            zstd::zstd_safe::get_frame_content_size(frame).unwrap(),
            Some(payload.len() as u64)
        );
    }
    let decode = |msg: &[u8]| -> Result<(), DeltaError> {
        if inspect(msg)?.kind == Kind::Mesh {
            decode_mesh(msg, &limits()).map(|_| ())
        } else {
            let mut f = decode_mesh(&mesh, &limits()).unwrap().1;
            let held = bits(&f);
            let r = apply_delta(&mut f, msg, &limits());
            assert!(
                r.is_ok() || bits(&f) == held,
                "a failed delta changed the frame"
            );
            r
        }
    };
    for msg in [&mesh, &delta] {
        decode(msg).unwrap();
        // The checksum (last 4 bytes) itself corrupted.
        let mut bad = msg.clone();
        *bad.last_mut().unwrap() ^= 0x5A;
        assert!(matches!(decode(&bad), Err(DeltaError::ChecksumMismatch)));
        // The same payload in a frame without a checksum: refused before decompressing.
        let payload = zstd::bulk::decompress(zstd_frame(msg), 1 << 24).unwrap();
        let plain = zstd::bulk::compress(&payload, 3).unwrap();
        assert_eq!(plain[4] & 0x04, 0);
        assert!(matches!(
            decode(&with_body(msg, &plain)),
            Err(DeltaError::ZstdNoChecksum)
        ));
        // Two frames, or an empty body: not one frame.
        let twice = [zstd_frame(msg), zstd_frame(msg)].concat();
        assert!(matches!(
            decode(&with_body(msg, &twice)),
            Err(DeltaError::TrailingBytes { count }) if count as usize == zstd_frame(msg).len()
        ));
        assert!(matches!(
            decode(&with_body(msg, &[])),
            Err(DeltaError::Zstd(_))
        ));
    }
    // Wherever a byte of the frame is flipped, the decode fails with a typed error or yields
    // exactly the original frame (never different data of the right length).
    let (_, want) = decode_mesh(&mesh, &limits()).unwrap();
    for at in HEADER_BYTES..mesh.len() {
        let mut bad = mesh.clone();
        bad[at] ^= 0x01;
        if let Ok((_, got)) = decode_mesh(&bad, &limits()) {
            assert_eq!(bits(&got), bits(&want), "byte {at} flipped went unnoticed");
        }
    }
}

#[test]
fn encoding_flags_only_with_their_section() {
    let (topo, mut frame) = grid_frame(5, 0.0);
    let mut bare = frame.clone();
    bare.normals.clear();
    let quant = EncodeOptions::quantised();
    let f = inspect(&encode_mesh(&topo, &bare, &quant).unwrap())
        .unwrap()
        .flags;
    assert_eq!(
        f,
        flags::POSITIONS | flags::POSITIONS_U16 | flags::MARGINS | flags::CLASSES
    );
    // A quantised delta that changes only margins has no encoding flag at all (25 vertices:
    // one bitmap word, so the bitmap).
    let prev = frame.clone();
    frame.margins[3] += 1.0;
    let d = encode_delta(&prev, &frame, &quant).unwrap();
    assert_eq!(inspect(&d).unwrap().flags, flags::MARGINS);
    assert_eq!(
        inspect(&encode_delta(&prev, &prev, &quant).unwrap())
            .unwrap()
            .flags,
        flags::INDEX_LIST
    );
    // Decoders refuse an encoding flag without its section.
    let mesh = encode_mesh(&topo, &bare, &quant).unwrap();
    let mut b = mesh.clone();
    b[6] |= flags::NORMALS_OCT16 as u8;
    assert!(matches!(
        decode_mesh(&b, &limits()),
        Err(DeltaError::BadFlags { reason, .. }) if reason.contains("NORMALS_OCT16")
    ));
    let mut b = d.clone();
    b[6] |= flags::POSITIONS_U16 as u8;
    let mut held = prev.clone();
    assert!(matches!(
        apply_delta(&mut held, &b, &limits()),
        Err(DeltaError::BadFlags { reason, .. }) if reason.contains("POSITIONS_U16")
    ));
}

// ---------------------------------------------------------------- deltas

#[test]
fn delta_of_identical_frames_is_a_bare_header() {
    let (_, frame) = grid_frame(40, 0.0);
    for opts in all_options() {
        let d = encode_delta(&frame, &frame, &opts).unwrap();
        assert_eq!(d.len(), HEADER_BYTES, "{opts:?}");
        let s = DeltaStats::of(&d).unwrap();
        assert_eq!((s.vertices, s.changed_vertices), (1600, 0));
        let mut f = frame.clone();
        apply_delta(&mut f, &d, &limits()).unwrap();
        assert_eq!(bits(&f), bits(&frame));
    }
}

#[test]
fn partial_change_carries_only_the_changed_vertices() {
    let (_, prev) = grid_frame(40, 0.0);
    let mut next = prev.clone();
    // Few changed: an index list; positions only.
    for i in [3usize, 500, 1599] {
        next.positions[i][1] += 0.5;
    }
    let d = encode_delta(&prev, &next, &EncodeOptions::exact()).unwrap();
    let h = inspect(&d).unwrap();
    assert_eq!(h.flags & 0b1111, flags::POSITIONS);
    assert!(h.has(flags::INDEX_LIST));
    assert_eq!(d.len(), HEADER_BYTES + 3 * 4 + 3 * 12);
    let s = DeltaStats::of(&d).unwrap();
    assert_eq!(s.changed_vertices, 3);
    assert!(s.index_list && !s.compressed);
    let mut f = prev.clone();
    apply_delta(&mut f, &d, &limits()).unwrap();
    assert_eq!(bits(&f), bits(&next));

    // Many changed: a bitmap of 50 words; margins and classes changed on a band of 200.
    let mut next = prev.clone();
    for i in 100..300 {
        next.margins[i] -= 1.0;
        next.classes[i] = 3;
    }
    let d = encode_delta(&prev, &next, &EncodeOptions::exact()).unwrap();
    let h = inspect(&d).unwrap();
    assert_eq!(h.flags & 0b1111, flags::MARGINS | flags::CLASSES);
    assert!(!h.has(flags::INDEX_LIST));
    assert_eq!(d.len(), HEADER_BYTES + 50 * 4 + 200 * 4 + 200);
    let mut f = prev.clone();
    apply_delta(&mut f, &d, &limits()).unwrap();
    assert_eq!(bits(&f), bits(&next));
}

#[test]
fn changed_set_encoding_is_the_smaller_one() {
    let (_, prev) = grid_frame(40, 0.0); // 1600 vertices: bitmap 50 words
    for m in [49usize, 50] {
        let mut next = prev.clone();
        for i in 0..m {
            next.margins[i * 7] += 1.0;
        }
        let s =
            DeltaStats::of(&encode_delta(&prev, &next, &EncodeOptions::exact()).unwrap()).unwrap();
        assert_eq!(s.index_list, m < 50, "m = {m}");
        assert_eq!(s.payload_bytes as usize, 4 * m.min(50) + 4 * m);
    }
}

#[test]
fn every_vertex_moving_round_trips_for_every_option() {
    let (_, prev) = grid_frame(40, 0.0);
    let (_, next) = grid_frame(40, 0.2);
    for opts in all_options() {
        let d = encode_delta(&prev, &next, &opts).unwrap();
        let mut f = prev.clone();
        apply_delta(&mut f, &d, &limits()).unwrap();
        if opts.quantise.is_some() {
            assert_quantised_close(&f, &next, extent(&next.positions));
        } else {
            assert_eq!(bits(&f), bits(&next), "{opts:?}");
        }
    }
}

#[test]
fn quantised_deltas_do_not_accumulate_error() {
    // A client applying quantised deltas stays within one quantisation of the exact state:
    // every changed vertex is sent afresh against the exact previous frame.
    let (topo, mut exact) = grid_frame(30, 0.0);
    let opts = EncodeOptions::quantised();
    let (_, mut client) =
        decode_mesh(&encode_mesh(&topo, &exact, &opts).unwrap(), &limits()).unwrap();
    for step in 1..=8 {
        let (_, mut next) = grid_frame(30, 0.05 * f64::from(step));
        // Leave half the surface where it was.
        for i in 0..450 {
            next.positions[i] = exact.positions[i];
            next.normals[i] = exact.normals[i];
            next.margins[i] = exact.margins[i];
            next.classes[i] = exact.classes[i];
        }
        let d = encode_delta(&exact, &next, &opts).unwrap();
        assert_eq!(DeltaStats::of(&d).unwrap().changed_vertices, 450);
        apply_delta(&mut client, &d, &limits()).unwrap();
        exact = next;
        // Unchanged vertices keep the snapshot's box, changed ones the delta's: both within
        // the extent of the whole surface.
        let ext = [80.0f32, 60.0, 16.0];
        assert_quantised_close(&client, &exact, ext);
    }
}

#[test]
fn delta_errors_leave_the_frame_unchanged() {
    let (_, prev) = grid_frame(10, 0.0);
    let (_, next) = grid_frame(10, 0.5);
    let d = encode_delta(&prev, &next, &EncodeOptions::exact()).unwrap();
    // Wrong vertex count.
    let (_, mut other) = grid_frame(9, 0.0);
    let before = bits(&other);
    assert!(matches!(
        apply_delta(&mut other, &d, &limits()),
        Err(DeltaError::VertexCount {
            left: 100,
            right: 81
        })
    ));
    assert_eq!(bits(&other), before);
    // The delta carries margins the frame does not have.
    let mut bare = prev.clone();
    bare.margins.clear();
    let before = bits(&bare);
    assert!(matches!(
        apply_delta(&mut bare, &d, &limits()),
        Err(DeltaError::AttributeMismatch {
            what: "margins",
            ..
        })
    ));
    assert_eq!(bits(&bare), before);
    // A bitmap bit beyond the vertex count (100 vertices: word 3 has bits 96..=99 valid).
    let mut d2 = d.clone();
    let w3 = HEADER_BYTES + 12;
    d2[w3 + 3] |= 0x80;
    let mut f = prev.clone();
    let err = apply_delta(&mut f, &d2, &limits()).unwrap_err();
    assert!(matches!(err, DeltaError::ChangedSet(_)), "{err}");
    assert_eq!(bits(&f), bits(&prev));
    // A non-ascending index list.
    let mut n2 = prev.clone();
    n2.margins[5] = 0.0;
    n2.margins[9] = 0.0;
    let mut d3 = encode_delta(&prev, &n2, &EncodeOptions::exact()).unwrap();
    assert!(inspect(&d3).unwrap().has(flags::INDEX_LIST));
    d3[HEADER_BYTES + 4..HEADER_BYTES + 8].copy_from_slice(&5u32.to_le_bytes());
    let mut f = prev.clone();
    assert!(matches!(
        apply_delta(&mut f, &d3, &limits()),
        Err(DeltaError::ChangedSet(_))
    ));
    assert_eq!(bits(&f), bits(&prev));
}

// ---------------------------------------------------------------- properties

fn frame_strategy() -> impl Strategy<Value = (SurfaceFrame, Vec<u8>, [bool; 3])> {
    (1usize..120, any::<[bool; 3]>()).prop_flat_map(|(n, has)| {
        (
            proptest::collection::vec(any::<[f32; 3]>(), n),
            proptest::collection::vec(any::<[f32; 3]>(), n),
            proptest::collection::vec(any::<f32>(), n),
            proptest::collection::vec(any::<u8>(), n),
            proptest::collection::vec(0u8..16, n),
            Just(has),
        )
            .prop_map(|(p, nr, m, c, change, has)| {
                let frame = SurfaceFrame {
                    positions: p,
                    normals: if has[0] { nr } else { Vec::new() },
                    margins: if has[1] { m } else { Vec::new() },
                    classes: if has[2] { c } else { Vec::new() },
                };
                (frame, change, has)
            })
    })
}

/// `next` differs from `prev` where `change[i]`'s bits say (position, normal, margin, class).
fn changed(prev: &SurfaceFrame, change: &[u8], salt: f32) -> SurfaceFrame {
    let mut next = prev.clone();
    for (i, c) in change.iter().enumerate() {
        let bump = |x: f32| f32::from_bits(x.to_bits() ^ 1) + salt;
        if c & 1 != 0 {
            next.positions[i][i % 3] = bump(next.positions[i][i % 3]);
        }
        if c & 2 != 0 && !next.normals.is_empty() {
            next.normals[i][(i + 1) % 3] = bump(next.normals[i][(i + 1) % 3]);
        }
        if c & 4 != 0 && !next.margins.is_empty() {
            next.margins[i] = bump(next.margins[i]);
        }
        if c & 8 != 0 && !next.classes.is_empty() {
            next.classes[i] = next.classes[i].wrapping_add(1);
        }
    }
    next
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn exact_delta_reproduces_next_bitwise(
        (prev, change, _) in frame_strategy(),
        salt in prop_oneof![Just(0.0f32), -1.0f32..1.0],
        zstd in any::<bool>(),
    ) {
        let next = changed(&prev, &change, salt);
        let opts = if zstd { EncodeOptions::exact().with_zstd(1) } else { EncodeOptions::exact() };
        let d = encode_delta(&prev, &next, &opts).unwrap();
        let mut f = prev.clone();
        apply_delta(&mut f, &d, &limits()).unwrap();
        prop_assert_eq!(bits(&f), bits(&next));
        // The header counts exactly the vertices that differ bitwise.
        let (bp, bn) = (bits(&prev), bits(&next));
        let differing = (0..prev.positions.len())
            .filter(|&i| bp.0[i] != bn.0[i]
                || bp.1.get(i) != bn.1.get(i)
                || bp.2.get(i) != bn.2.get(i)
                || bp.3.get(i) != bn.3.get(i))
            .count();
        prop_assert_eq!(DeltaStats::of(&d).unwrap().changed_vertices as usize, differing);
        // Snapshot round trip too.
        let (_, g) = decode_mesh(&encode_mesh(&Topology::default(), &next, &opts).unwrap(), &limits()).unwrap();
        prop_assert_eq!(bits(&g), bits(&next));
    }

    #[test]
    fn quantised_delta_is_within_bounds_on_finite_frames(
        pts in proptest::collection::vec(proptest::array::uniform3(-1000.0f32..1000.0), 1..200),
        dirs in proptest::collection::vec(proptest::array::uniform3(-1.0f32..1.0), 200),
        zstd in any::<bool>(),
    ) {
        let n = pts.len();
        let normals: Vec<[f32; 3]> = dirs[..n].iter().map(|d| {
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if l < 1e-3 { [0.0, 0.0, 1.0] } else { d.map(|x| x / l) }
        }).collect();
        let next = SurfaceFrame { positions: pts.clone(), normals: normals.clone(), margins: vec![1.5; n], classes: vec![1; n] };
        let prev = SurfaceFrame {
            positions: pts.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect(),
            normals, margins: vec![1.5; n], classes: vec![1; n],
        };
        let mut opts = EncodeOptions::quantised();
        if zstd { opts = opts.with_zstd(1); }
        let mut f = prev.clone();
        apply_delta(&mut f, &encode_delta(&prev, &next, &opts).unwrap(), &limits()).unwrap();
        let ext = extent(&next.positions);
        for (g, w) in f.positions.iter().zip(&next.positions) {
            for k in 0..3 {
                prop_assert!(f64::from((g[k] - w[k]).abs()) <= position_bound(ext[k], w[k]));
            }
        }
        // Unchanged normals were not sent: still exact.
        prop_assert_eq!(bits(&f).1, bits(&next).1);
    }

    #[test]
    fn corrupted_snapshots_fail_cleanly(
        (frame, _, _) in frame_strategy(),
        opts_i in 0usize..4,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        mode in 0u8..4,
    ) {
        let n = frame.positions.len() as u32;
        let topo = Topology { triangles: (0..n / 3).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect() };
        let mut bytes = encode_mesh(&topo, &frame, &all_options()[opts_i]).unwrap();
        match mode {
            0 => for (at, v) in &edits { let i = at.index(bytes.len()); bytes[i] ^= v | 1; },
            1 => bytes.truncate(cut.index(bytes.len())),
            2 => { // inflate a count
                let field = [8usize, 12, 16][edits[0].1 as usize % 3];
                let v = u32::from_le_bytes(bytes[field..field + 4].try_into().unwrap());
                let big = v.saturating_mul(1 + u32::from(edits[0].1)).saturating_add(1);
                bytes[field..field + 4].copy_from_slice(&big.to_le_bytes());
            }
            _ => { let i = cut.index(bytes.len()); bytes.insert(i, edits[0].1); }
        }
        // Ok (a flip inside the data) or a typed error; never a panic.
        if let Ok((t, f)) = decode_mesh(&bytes, &limits()) {
            prop_assert!(t.triangles.iter().flatten().all(|&i| (i as usize) < f.positions.len()));
            prop_assert!(f.validate().is_ok());
        }
    }

    #[test]
    fn corrupted_deltas_fail_cleanly_and_leave_the_frame_alone(
        (prev, change, _) in frame_strategy(),
        opts_i in 0usize..4,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        mode in 0u8..4,
    ) {
        let next = changed(&prev, &change, 0.25);
        let mut bytes = encode_delta(&prev, &next, &all_options()[opts_i]).unwrap();
        match mode {
            0 => for (at, v) in &edits { let i = at.index(bytes.len()); bytes[i] ^= v | 1; },
            1 => bytes.truncate(cut.index(bytes.len())),
            2 => {
                let field = [8usize, 12, 16][edits[0].1 as usize % 3];
                let v = u32::from_le_bytes(bytes[field..field + 4].try_into().unwrap());
                let big = v.saturating_mul(1 + u32::from(edits[0].1)).saturating_add(1);
                bytes[field..field + 4].copy_from_slice(&big.to_le_bytes());
            }
            _ => { let i = cut.index(bytes.len()); bytes.insert(i, edits[0].1); }
        }
        let mut f = prev.clone();
        if apply_delta(&mut f, &bytes, &limits()).is_err() {
            prop_assert_eq!(bits(&f), bits(&prev));
        } else {
            prop_assert!(f.validate().is_ok());
        }
    }
}

// ---------------------------------------------------------------- replay ring

fn items(s: Since<u32>) -> Option<Vec<u64>> {
    match s {
        Since::Items(v) => Some(v.into_iter().map(|(s, _)| s).collect()),
        Since::Gap => None,
    }
}

#[test]
fn ring_is_bounded_by_count() {
    let mut r = ReplayRing::new(3, usize::MAX);
    for s in 1..=5u64 {
        r.push(s, s as u32 * 10, 1).unwrap();
    }
    assert_eq!(
        (r.len(), r.first_seq(), r.last_seq()),
        (3, Some(3), Some(5))
    );
    assert_eq!(items(r.since(2)), Some(vec![3, 4, 5])); // at the edge: has 2, gets 3..
    assert_eq!(items(r.since(4)), Some(vec![5])); // inside
    assert_eq!(items(r.since(5)), Some(vec![])); // up to date
    assert_eq!(items(r.since(1)), None); // needs 2, evicted
    assert_eq!(items(r.since(6)), None); // future
    match r.since(3) {
        Since::Items(v) => assert_eq!(v, vec![(4, 40), (5, 50)]),
        Since::Gap => panic!("expected items"),
    }
}

#[test]
fn ring_is_bounded_by_bytes() {
    let mut r = ReplayRing::new(100, 1000);
    r.push(10, 0u32, 400).unwrap();
    r.push(11, 1, 400).unwrap();
    assert_eq!((r.len(), r.bytes()), (2, 800));
    r.push(12, 2, 300).unwrap(); // 1100 > 1000: drop 10
    assert_eq!((r.len(), r.bytes(), r.first_seq()), (2, 700, Some(11)));
    assert_eq!(items(r.since(10)), Some(vec![11, 12]));
    assert_eq!(items(r.since(9)), None);
    // An item bigger than the whole budget is not kept; only clients at its seq are current.
    r.push(13, 3, 5000).unwrap();
    assert_eq!((r.len(), r.bytes(), r.last_seq()), (0, 0, Some(13)));
    assert_eq!(items(r.since(13)), Some(vec![]));
    assert_eq!(items(r.since(12)), None);
    r.push(14, 4, 10).unwrap();
    assert_eq!(items(r.since(13)), Some(vec![14]));
}

#[test]
fn ring_horizon_before_the_first_item_and_after_reset() {
    let mut r: ReplayRing<u32> = ReplayRing::new(10, 10_000);
    assert_eq!(items(r.since(0)), None); // knows nothing yet
    r.push(7, 0, 1).unwrap();
    assert_eq!(items(r.since(6)), Some(vec![7])); // made against 6
    assert_eq!(items(r.since(5)), None);
    // Sequence numbers may skip but never go back.
    r.push(20, 1, 1).unwrap();
    assert_eq!(items(r.since(7)), Some(vec![20]));
    assert_eq!(items(r.since(12)), Some(vec![20]));
    assert!(matches!(
        r.push(20, 2, 1),
        Err(DeltaError::SeqOrder { seq: 20, last: 20 })
    ));
    r.reset(30);
    assert_eq!(items(r.since(30)), Some(vec![]));
    assert_eq!(items(r.since(20)), None);
    r.push(31, 3, 1).unwrap();
    assert_eq!(items(r.since(30)), Some(vec![31]));
    // A ring that keeps nothing still tracks where clients stand.
    let mut z: ReplayRing<u32> = ReplayRing::new(0, 0);
    z.push(1, 0, 1).unwrap();
    assert_eq!((items(z.since(1)), items(z.since(0))), (Some(vec![]), None));
}

proptest! {
    #[test]
    fn ring_serves_exactly_the_missed_items_or_a_gap(
        sizes in proptest::collection::vec(1usize..50, 1..60),
        max_items in 0usize..20,
        max_bytes in 0usize..400,
        client in 0u64..70,
    ) {
        let mut r = ReplayRing::new(max_items, max_bytes);
        for (k, &b) in sizes.iter().enumerate() {
            r.push(k as u64 + 1, k as u32, b).unwrap();
            prop_assert!(r.len() <= max_items && r.bytes() <= max_bytes);
        }
        let last = sizes.len() as u64;
        match r.since(client) {
            Since::Items(v) => {
                // Contiguous from client + 1 to the last: nothing missed.
                let want: Vec<u64> = (client + 1..=last).collect();
                prop_assert_eq!(v.iter().map(|(s, _)| *s).collect::<Vec<_>>(), want);
            }
            Since::Gap => {
                let first = r.first_seq().unwrap_or(last + 1);
                prop_assert!(client > last || client + 1 < first);
            }
        }
    }
}
