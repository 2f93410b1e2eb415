//! Fuzz target: the .ply mesh reader must return Ok or a typed error, never panic or hang.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = resecta_io::read_mesh_bytes(data, resecta_io::MeshFormat::Ply, "fuzz.ply");
});
