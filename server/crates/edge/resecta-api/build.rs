//! Compiles `proto/resecta/v1/*.proto` with protox (pure Rust, no protoc) into a file descriptor
//! set (kept for reflection and the lint test) and generates messages, tonic stubs and the
//! messages' serde impls in the proto JSON mapping (pbjson) from it.

use std::error::Error;
use std::path::PathBuf;

use prost::Message;

fn main() -> Result<(), Box<dyn Error>> {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?).join("../../../../proto");
    let root = root.canonicalize()?;
    let dir = root.join("resecta/v1");
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut files = Vec::new();
    for entry in std::fs::read_dir(&dir)? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "proto") {
            // Import-relative names, as `protoc -I proto` sees them.
            files.push(path.strip_prefix(&root)?.to_path_buf());
        }
    }
    files.sort();
    let fds = protox::Compiler::new([&root])?
        .include_imports(true)
        .include_source_info(true)
        .open_files(&files)?
        .file_descriptor_set();
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    let encoded = fds.encode_to_vec();
    std::fs::write(out.join("resecta_v1.fds.bin"), &encoded)?;
    // serde impls in the canonical proto JSON mapping (lowerCamelCase names, enums by name,
    // 64-bit integers as strings, bytes as base64), beside the prost messages.
    pbjson_build::Builder::new()
        .register_descriptors(&encoded)?
        .out_dir(&out)
        .build(&[".resecta.v1"])?;
    // `prost::Name` on every message: the HTTP face finds a message's descriptor by its name.
    let mut config = prost_build::Config::new();
    config.enable_type_names();
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .compile_fds_with_config(fds, config)?;
    Ok(())
}
