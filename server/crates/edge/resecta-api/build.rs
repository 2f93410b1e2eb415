//! Compiles `proto/resecta/v1/*.proto` with protox (pure Rust, no protoc) into a file descriptor
//! set (kept for reflection and the lint test) and generates messages and tonic stubs from it.

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
    std::fs::write(out.join("resecta_v1.fds.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .compile_fds(fds)?;
    Ok(())
}
