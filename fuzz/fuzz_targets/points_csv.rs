//! Fuzz target: the CSV/text point-cloud reader (checks in `common/points.rs`).
#![no_main]

#[path = "common/points.rs"]
mod points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| points::check(
    data,
    resecta_io::PointFormat::Csv,
    "fuzz.csv"
));
