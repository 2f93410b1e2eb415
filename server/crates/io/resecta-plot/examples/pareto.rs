//! Renders the Fig. 6.7-style figure of a synthetic study (shaped like the thesis' P₁) to
//! `OUT_DIR/pareto.{png,svg}` (default `/tmp`), plus the study's Markdown tables to stdout.
//!
//! `cargo run -p resecta-plot --example pareto -- /tmp`

use std::error::Error;

use resecta_meshmetrics::{ModelMethod, ModelRecord, analyse};
use resecta_plot::pareto_figure;

fn record(
    label: String,
    method: ModelMethod,
    polys: f64,
    mean: f64,
    curvature: f64,
) -> ModelRecord {
    ModelRecord {
        label,
        method,
        polys: polys as usize,
        points: (polys / 2.0) as usize + 2,
        mean_mm: mean,
        p95_mm: 2.2 * mean,
        max_mm: 5.0 * mean,
        curvature,
        time_ms: 1000.0,
    }
}

fn main() -> Result<(), Box<dyn Error>> {
    let dir = std::env::args().nth(1).unwrap_or_else(|| "/tmp".into());
    let mut records = Vec::new();
    for (d, polys, mean, k) in [
        (5, 4_100.0, 3.7, 4.6e-3),
        (6, 16_500.0, 1.9, 0.29e-3),
        (7, 62_000.0, 1.11, 0.19e-3),
        (8, 250_000.0, 0.82, 0.19e-3),
    ] {
        records.push(record(
            format!("psr-d{d}"),
            ModelMethod::Psr { depth: d },
            polys,
            mean,
            k,
        ));
    }
    for s in [0.0, 22.0, 45.0, 67.0, 90.0] {
        for i in 0..10 {
            let e = i as f64 / 10.0;
            let polys = 700_000.0 * (1.0 - e) * (1.0 - 0.1 * s / 90.0);
            let mean = 0.62 + 0.35 * e * e + 0.25 * s / 90.0 + 0.15 * e * s / 90.0;
            let k = 2e-3 * (1.0 + 40.0 * e) / (1.0 + s / 10.0);
            records.push(record(
                format!("mcsd-s{s}-e{e}"),
                ModelMethod::Mcsd {
                    smoothing: s,
                    decimation: e,
                },
                polys,
                mean,
                k,
            ));
        }
    }
    let study = analyse(records)?;
    let fig = pareto_figure(&study);
    std::fs::write(format!("{dir}/pareto.png"), fig.to_png()?)?;
    std::fs::write(format!("{dir}/pareto.svg"), fig.to_svg()?)?;
    println!("{}", study.markdown());
    Ok(())
}
