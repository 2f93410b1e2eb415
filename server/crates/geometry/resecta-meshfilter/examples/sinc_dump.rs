#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Writes test meshes and our windowed-sinc results for the VTK comparison in
//! `docs/bench/meshfilter/compare_vtk.py`: `cargo run --release -p resecta-meshfilter --example
//! sinc_dump -- OUT_DIR`. Files: `mesh_<name>.txt` (`v x y z` / `f a b c` lines),
//! `out_<case>.txt` (`v x y z` lines) and `manifest.txt` (one case per line).

use std::fmt::Write as _;
use std::path::PathBuf;

use resecta_geom::{TriMesh, Vec3, primitives};
use resecta_meshfilter::{SincParams, SincWindow, windowed_sinc};

#[path = "../tests/common/mod.rs"]
mod common;
use common::hash_unit;

fn meshes() -> Vec<(&'static str, TriMesh)> {
    let sphere = primitives::icosphere(Vec3::new(3.0, -7.0, 11.0), 50.0, 5).unwrap();
    let c = Vec3::new(3.0, -7.0, 11.0);
    let noisy: Vec<Vec3> = sphere
        .vertices()
        .iter()
        .enumerate()
        .map(|(i, p)| c + (p - c) * (1.0 + 0.02 * hash_unit(i as u64)))
        .collect();
    let closed = TriMesh::new(noisy.clone(), sphere.triangles().to_vec()).unwrap();
    // Staircase: vertices snapped to a 2.5 mm lattice.
    let snapped = noisy
        .iter()
        .map(|p| (p / 2.5).map(f64::round) * 2.5)
        .collect();
    let stairs = TriMesh::new(snapped, sphere.triangles().to_vec()).unwrap();
    // Open: the noisy sphere without its top cap (a boundary loop).
    let open_tris = sphere
        .triangles()
        .iter()
        .copied()
        .filter(|t| t.iter().map(|&v| noisy[v as usize].z - c.z).sum::<f64>() < 90.0)
        .collect();
    let open = TriMesh::new(noisy, open_tris).unwrap();
    vec![("closed", closed), ("stairs", stairs), ("open", open)]
}

fn cases() -> Vec<(&'static str, SincParams)> {
    let vtk_default = SincParams::default();
    vec![
        ("slicer_0.5", SincParams::slicer(0.5)),
        ("slicer_0.25", SincParams::slicer(0.25)),
        ("slicer_1.0", SincParams::slicer(1.0)),
        ("vtk_default", vtk_default),
        (
            "hamming_raw_no_boundary",
            SincParams {
                window: SincWindow::Hamming,
                boundary_smoothing: false,
                iterations: 30,
                passband: 0.05,
                ..vtk_default
            },
        ),
        (
            "blackman_normalized",
            SincParams {
                window: SincWindow::Blackman,
                normalize_coordinates: true,
                ..vtk_default
            },
        ),
        (
            "hanning_nm_unweighted",
            SincParams {
                window: SincWindow::Hanning,
                non_manifold_smoothing: true,
                weight_non_manifold_edges: false,
                boundary_smoothing: false,
                ..vtk_default
            },
        ),
    ]
}

fn main() {
    let dir = PathBuf::from(std::env::args().nth(1).expect("usage: sinc_dump OUT_DIR"));
    std::fs::create_dir_all(&dir).unwrap();
    let mut manifest = String::new();
    for (name, mesh) in meshes() {
        let mut s = String::new();
        for p in mesh.vertices() {
            writeln!(s, "v {} {} {}", p.x, p.y, p.z).unwrap();
        }
        for t in mesh.triangles() {
            writeln!(s, "f {} {} {}", t[0], t[1], t[2]).unwrap();
        }
        std::fs::write(dir.join(format!("mesh_{name}.txt")), s).unwrap();
        for (case, p) in cases() {
            let out = windowed_sinc(&mesh, &p).unwrap();
            let mut s = String::new();
            for v in out.vertices() {
                writeln!(s, "v {} {} {}", v.x, v.y, v.z).unwrap();
            }
            let file = format!("out_{name}_{case}.txt");
            std::fs::write(dir.join(&file), s).unwrap();
            let window = match p.window {
                SincWindow::Nuttall => 0,
                SincWindow::Blackman => 1,
                SincWindow::Hanning => 2,
                SincWindow::Hamming => 3,
            };
            writeln!(
                manifest,
                "{name} {case} {file} {} {} {} {} {} {} {} {window}",
                p.iterations,
                p.passband,
                u8::from(p.normalize_coordinates),
                u8::from(p.boundary_smoothing),
                u8::from(p.non_manifold_smoothing),
                u8::from(p.weight_non_manifold_edges),
                p.edge_angle_deg,
            )
            .unwrap();
        }
    }
    std::fs::write(dir.join("manifest.txt"), manifest).unwrap();
}
