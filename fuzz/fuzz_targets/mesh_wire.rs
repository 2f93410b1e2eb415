//! Fuzz target: the mesh wire decoders (`resecta-delta`, docs/wire/mesh-delta.md) on arbitrary
//! bytes: `Ok` or a typed `DeltaError`, never a panic or an allocation beyond the limits; a
//! delta that fails leaves the held frame unchanged; a decoded snapshot re-encodes and decodes
//! to the same values.
#![no_main]

use libfuzzer_sys::fuzz_target;
use resecta_delta::{
    DecodeLimits, EncodeOptions, SurfaceFrame, apply_delta, decode_mesh, encode_mesh,
};

/// Bit patterns of every attribute (NaN-safe equality).
fn bits(f: &SurfaceFrame) -> (Vec<[u32; 3]>, Vec<[u32; 3]>, Vec<u32>, Vec<u8>) {
    (
        f.positions.iter().map(|p| p.map(f32::to_bits)).collect(),
        f.normals.iter().map(|p| p.map(f32::to_bits)).collect(),
        f.margins.iter().map(|m| m.to_bits()).collect(),
        f.classes.clone(),
    )
}

/// A frame of 144 vertices with every attribute, the size of the golden messages
/// (`resecta-delta/tests/golden.rs`), so their deltas (the seeds) apply to it.
fn held() -> SurfaceFrame {
    let n = 144;
    SurfaceFrame {
        positions: (0..n).map(|i| [i as f32, 0.5 * i as f32, -1.0]).collect(),
        normals: vec![[0.0, 0.0, 1.0]; n],
        margins: (0..n).map(|i| i as f32 - 7.0).collect(),
        classes: (0..n).map(|i| (i % 4) as u8).collect(),
    }
}

fuzz_target!(|data: &[u8]| {
    let limits = DecodeLimits {
        max_vertices: 1 << 16,
        max_triangles: 1 << 17,
    };
    if let Ok((topology, frame)) = decode_mesh(data, &limits) {
        let again = encode_mesh(&topology, &frame, &EncodeOptions::exact()).expect("re-encodes");
        let (t2, f2) = decode_mesh(&again, &limits).expect("decodes its re-encoding");
        assert_eq!(t2, topology);
        assert_eq!(bits(&f2), bits(&frame));
    }
    let mut frame = held();
    let before = bits(&frame);
    if apply_delta(&mut frame, data, &limits).is_err() {
        assert_eq!(bits(&frame), before, "a failed delta changed the frame");
    }
});
