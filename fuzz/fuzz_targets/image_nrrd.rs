//! NRRD and `.seg.nrrd` readers on arbitrary bytes: `Ok` or a typed error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use resecta_geom::VoxelLimit;

fuzz_target!(|data: &[u8]| {
    let limit = VoxelLimit(1 << 24);
    let _ = resecta_io::nrrd::read_nrrd_bytes(data, "fuzz.nrrd", limit);
    if let Ok(seg) = resecta_io::nrrd::read_seg_nrrd_bytes(data, "fuzz.seg.nrrd", limit) {
        let _ = seg.to_label_map();
    }
});
