//! Times one extraction of a sphere field: `cargo run --release --example iso_timing -- 257`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use resecta_isosurface::{Options, extract};
fn main() {
    let n: usize = std::env::args().nth(1).map_or(257, |s| s.parse().unwrap());
    let c = (n as f32 - 1.0) / 2.0;
    let r = 0.4 * n as f32;
    let mut v = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let d = ((i as f32 - c).powi(2) + (j as f32 - c).powi(2) + (k as f32 - c).powi(2))
                    .sqrt();
                v.push(r - d);
            }
        }
    }
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let m = extract([n, n, n], &v, 0.0, Options::default()).unwrap();
        println!(
            "{} tris in {:.1} ms",
            m.triangles().len(),
            t.elapsed().as_secs_f64() * 1e3
        );
    }
}
