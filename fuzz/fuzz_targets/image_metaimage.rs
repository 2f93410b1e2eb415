//! MetaImage (`.mha`, data LOCAL, raw or zlib) reader on arbitrary bytes: `Ok` or a typed
//! error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use resecta_geom::VoxelLimit;

fuzz_target!(|data: &[u8]| {
    let _ = resecta_io::metaimage::read_metaimage_bytes(data, "fuzz.mha", VoxelLimit(1 << 24));
});
