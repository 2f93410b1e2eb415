//! NIfTI-1 reader (raw and gzip) on arbitrary bytes: `Ok` or a typed error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use resecta_geom::VoxelLimit;

fuzz_target!(|data: &[u8]| {
    let _ = resecta_io::nifti::read_nifti_bytes(data, "fuzz.nii", VoxelLimit(1 << 24));
});
