//! Golden messages for other decoders (`tests/mesh_wire.py`, spec `docs/wire/mesh-delta.md`):
//! a few deterministic snapshots and deltas. With `RESECTA_DELTA_GOLDEN_DIR=DIR` each message is
//! written to `DIR/<name>` and `DIR/expected.json` lists them with their header, what this crate
//! decodes from them (f32 as bit patterns, so NaN and −0 compare exactly) and the frame they were
//! encoded from; without it the messages are only checked to round-trip here.

use resecta_delta::{
    DecodeLimits, EncodeOptions, Header, QuantBox, Quantise, SurfaceFrame, Topology, apply_delta,
    decode_mesh, encode_delta, encode_mesh, flags, inspect,
};
use serde_json::{Value, json};

const SIDE: usize = 12; // 144 vertices: the bitmap has 5 words, so ≤ 4 changes travel as a list
const NORMAL_BOUND_RAD: f64 = 5e-5;

/// A curved grid in RAS mm with unit normals, margins and classes; `t` moves it.
fn grid(t: f64) -> (Topology, SurfaceFrame) {
    let mut f = SurfaceFrame::default();
    for a in 0..SIDE {
        for b in 0..SIDE {
            let (u, v) = (a as f64 / 11.0, b as f64 / 11.0);
            let h = 8.0 * (3.0 * u + t).sin() * (2.0 * v).cos();
            let p = [100.0 + 80.0 * u, -50.0 + 60.0 * v, 200.0 + h];
            let hu = 24.0 * (3.0 * u + t).cos() * (2.0 * v).cos() / 80.0;
            let hv = -16.0 * (3.0 * u + t).sin() * (2.0 * v).sin() / 60.0;
            let len = (hu * hu + hv * hv + 1.0f64).sqrt();
            let d = ((p[0] - 140.0).powi(2) + (p[1] + 20.0).powi(2) + (p[2] - 215.0).powi(2))
                .sqrt()
                - 10.0;
            f.positions.push(p.map(|x| x as f32));
            f.normals
                .push([-hu / len, -hv / len, 1.0 / len].map(|x| x as f32));
            f.margins.push(d as f32);
            f.classes
                .push(if d < 10.0 { 3 } else { 1 + u8::from(d < 15.0) });
        }
    }
    let mut triangles = Vec::new();
    for a in 0..SIDE as u32 - 1 {
        for b in 0..SIDE as u32 - 1 {
            let k = a * SIDE as u32 + b;
            triangles.push([k, k + SIDE as u32, k + 1]);
            triangles.push([k + 1, k + SIDE as u32, k + SIDE as u32 + 1]);
        }
    }
    (Topology { triangles }, f)
}

/// The base frame, with values that travel as data: NaN, −0, ∞, a zero and a non-unit normal.
fn base() -> (Topology, SurfaceFrame) {
    let (topo, mut f) = grid(0.0);
    f.positions[7] = [f32::NAN, -0.0, 205.5];
    f.normals[5] = [0.0; 3];
    f.normals[6] = [0.0, 0.0, -7.0];
    f.margins[3] = f32::INFINITY;
    (topo, f)
}

fn bits(v: &[[f32; 3]]) -> Vec<[u32; 3]> {
    v.iter().map(|p| p.map(f32::to_bits)).collect()
}

fn frame_json(f: &SurfaceFrame) -> Value {
    json!({
        "positions": bits(&f.positions),
        "normals": bits(&f.normals),
        "margins": f.margins.iter().map(|m| m.to_bits()).collect::<Vec<_>>(),
        "classes": f.classes,
    })
}

fn header_json(h: &Header) -> Value {
    json!({
        "version": h.version, "flags": h.flags, "vertex_count": h.vertex_count,
        "count2": h.count2, "payload_bytes": h.payload_bytes,
    })
}

fn angle(a: &[f32; 3], b: &[f32; 3]) -> f64 {
    let (a, b) = (a.map(f64::from), b.map(f64::from));
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().atan2(d)
}

/// `got` equals `want` bitwise on `rows`, or within half a quantisation step (plus an f32 ulp)
/// and the octahedral bound where the message quantised them. Returns the position steps.
fn check_rows(got: &SurfaceFrame, want: &SurfaceFrame, rows: &[usize], f: u16) -> Option<[f32; 3]> {
    let step = (f & flags::POSITIONS_U16 != 0)
        .then(|| QuantBox::of(rows.iter().map(|&i| &want.positions[i])).step);
    for &i in rows {
        let (g, w) = (got.positions[i], want.positions[i]);
        match step {
            None => assert_eq!(g.map(f32::to_bits), w.map(f32::to_bits), "position {i}"),
            Some(s) => (0..3).for_each(|k| {
                let bound = 0.5 * s[k] + w[k].abs() * f32::EPSILON;
                assert!(
                    (g[k] - w[k]).abs() <= bound || (!w[k].is_finite() && g[k].is_nan()),
                    "position {i}: {g:?} vs {w:?}"
                );
            }),
        }
        let (g, w) = (got.normals[i], want.normals[i]);
        if f & flags::NORMALS_OCT16 == 0 {
            assert_eq!(g.map(f32::to_bits), w.map(f32::to_bits), "normal {i}");
        } else if w == [0.0; 3] {
            assert_eq!(g, [0.0; 3]);
        } else {
            assert!(
                angle(&g, &w) <= NORMAL_BOUND_RAD,
                "normal {i}: {g:?} vs {w:?}"
            );
        }
        assert_eq!(got.margins[i].to_bits(), want.margins[i].to_bits());
        assert_eq!(got.classes[i], want.classes[i]);
    }
    step
}

#[test]
fn golden_messages() {
    let dir = std::env::var_os("RESECTA_DELTA_GOLDEN_DIR").map(std::path::PathBuf::from);
    if let Some(d) = &dir {
        std::fs::create_dir_all(d).unwrap();
    }
    let write = |name: &str, msg: &[u8]| {
        if let Some(d) = &dir {
            std::fs::write(d.join(name), msg).unwrap();
        }
    };
    let limits = DecodeLimits::default();
    let (topo, prev) = base();
    let quant = EncodeOptions::quantised();
    let mut cases = Vec::new();

    // Snapshots: (name, frame, options, whether zstd must win).
    let mut bare = prev.clone();
    bare.normals.clear();
    bare.margins.clear();
    bare.classes.clear();
    let positions_only = EncodeOptions {
        quantise: Some(Quantise {
            positions: true,
            normals: false,
        }),
        zstd_level: None,
    };
    let meshes = [
        ("mesh_exact.rsms", &prev, EncodeOptions::exact(), false),
        ("mesh_quant.rsms", &prev, quant, false),
        (
            "mesh_exact_zstd.rsms",
            &prev,
            EncodeOptions::exact().with_zstd(3),
            true,
        ),
        ("mesh_quant_zstd.rsms", &prev, quant.with_zstd(3), true),
        ("mesh_bare_quant.rsms", &bare, quant, false),
        ("mesh_bare_posq.rsms", &bare, positions_only, false),
    ];
    for (name, frame, opts, zstd) in meshes {
        let msg = encode_mesh(&topo, frame, &opts).unwrap();
        assert_eq!(inspect(&msg).unwrap().has(flags::ZSTD), zstd, "{name}");
        let (t, got) = decode_mesh(&msg, &limits).unwrap();
        assert_eq!(t, topo);
        let n = frame.positions.len();
        let f = inspect(&msg).unwrap().flags;
        let step = if frame.normals.is_empty() {
            assert_eq!(got.positions.len(), n);
            assert!(got.normals.is_empty() && got.margins.is_empty() && got.classes.is_empty());
            (f & flags::POSITIONS_U16 != 0).then(|| QuantBox::of(frame.positions.iter()).step)
        } else {
            check_rows(&got, frame, &(0..n).collect::<Vec<_>>(), f)
        };
        write(name, &msg);
        cases.push(json!({
            "file": name, "kind": "mesh", "header": header_json(&inspect(&msg).unwrap()),
            "triangles": t.triangles, "decoded": frame_json(&got), "source": frame_json(frame),
            "position_step": step, "value_flags": f,
        }));
    }
    let empty = encode_mesh(&Topology::default(), &SurfaceFrame::default(), &quant).unwrap();
    write("mesh_empty.rsms", &empty);
    cases.push(json!({
        "file": "mesh_empty.rsms", "kind": "mesh", "header": header_json(&inspect(&empty).unwrap()),
        "triangles": [], "decoded": frame_json(&SurfaceFrame::default()),
        "source": frame_json(&SurfaceFrame::default()), "position_step": [0.0, 0.0, 0.0],
        "value_flags": inspect(&empty).unwrap().flags,
    }));

    // Deltas against `prev`, applied to the client's copy decoded from `base` (name, next,
    // options, base snapshot, whether the changed set must be an index list).
    let mut few = prev.clone();
    for i in [0usize, 17, 143] {
        few.positions[i][2] += 1.0;
        few.margins[i] -= 0.5;
        few.classes[i] = 2;
    }
    let mut band = prev.clone();
    for i in 40..80 {
        band.margins[i] += 2.0;
        band.classes[i] = 0;
    }
    let (_, moved) = grid(0.3);
    let deltas = [
        (
            "delta_few_exact.rsdl",
            &few,
            EncodeOptions::exact(),
            "mesh_exact.rsms",
            true,
        ),
        ("delta_few_quant.rsdl", &few, quant, "mesh_quant.rsms", true),
        (
            "delta_band_exact_zstd.rsdl",
            &band,
            EncodeOptions::exact().with_zstd(3),
            "mesh_exact.rsms",
            false,
        ),
        (
            "delta_all_quant_zstd.rsdl",
            &moved,
            quant.with_zstd(3),
            "mesh_quant.rsms",
            false,
        ),
        ("delta_none.rsdl", &prev, quant, "mesh_quant.rsms", true),
    ];
    for (name, next, opts, base_name, list) in deltas {
        let msg = encode_delta(&prev, next, &opts).unwrap();
        let h = inspect(&msg).unwrap();
        assert_eq!(h.has(flags::INDEX_LIST), list, "{name}");
        assert_eq!(h.has(flags::ZSTD), opts.zstd_level.is_some(), "{name}");
        let base_opts = if base_name == "mesh_exact.rsms" {
            EncodeOptions::exact()
        } else {
            quant
        };
        let (_, mut got) =
            decode_mesh(&encode_mesh(&topo, &prev, &base_opts).unwrap(), &limits).unwrap();
        let held = got.clone();
        apply_delta(&mut got, &msg, &limits).unwrap();
        let changed: Vec<usize> = (0..prev.positions.len())
            .filter(|&i| frame_json(&single(&prev, i)) != frame_json(&single(next, i)))
            .collect();
        assert_eq!(changed.len(), h.count2 as usize);
        // The rows' values went through the delta's encodings, and for the attributes it does
        // not carry (their values come from the base snapshot) through the base's.
        let base_flags = inspect(&encode_mesh(&topo, &prev, &base_opts).unwrap())
            .unwrap()
            .flags;
        let mut value_flags = h.flags;
        if !h.has(flags::NORMALS) {
            value_flags |= base_flags & flags::NORMALS_OCT16;
        }
        let step = check_rows(&got, next, &changed, value_flags);
        let unchanged: Vec<usize> = (0..prev.positions.len())
            .filter(|i| !changed.contains(i))
            .collect();
        check_rows(&got, &held, &unchanged, 0);
        write(name, &msg);
        cases.push(json!({
            "file": name, "kind": "delta", "base": base_name, "header": header_json(&inspect(&msg).unwrap()),
            "changed": changed, "decoded": frame_json(&got), "source": frame_json(next),
            "position_step": step, "value_flags": value_flags,
        }));
    }

    if let Some(d) = &dir {
        let expected = json!({ "normal_bound_rad": NORMAL_BOUND_RAD, "cases": cases });
        std::fs::write(d.join("expected.json"), expected.to_string()).unwrap();
    }
}

/// Vertex `i` of `f` alone.
fn single(f: &SurfaceFrame, i: usize) -> SurfaceFrame {
    SurfaceFrame {
        positions: vec![f.positions[i]],
        normals: vec![f.normals[i]],
        margins: vec![f.margins[i]],
        classes: vec![f.classes[i]],
    }
}
