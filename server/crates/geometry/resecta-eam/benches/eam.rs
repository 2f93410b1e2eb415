//! Paper IV's timings (thesis Sec. 9.3: median 0.60 s per reconstruction with I/O): one PSR
//! reconstruction from 600 points at d = 5, with the reference's and with estimated normals,
//! and the whole 30-condition study with 10 repeats, on the phantom and, where
//! `shared/test-data` is present, on LASC'13 b002.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_eam::{
    StudyAtrium, StudyConfig, StudyNormals, reconstruct_sample, run_sample, run_study,
};
use resecta_geom::VoxelLimit;
use resecta_phantom::{Atrium, AtriumSpec};
use resecta_recon::PoissonSolver;

fn atria() -> Vec<StudyAtrium> {
    let phantom = Atrium::new(&AtriumSpec::standard()).unwrap();
    let mut out = vec![StudyAtrium::from_phantom(&phantom, 1).unwrap()];
    let b002 = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../../../shared/test-data/heart/lasc2013-b002/gt_std.mhd");
    if b002.exists() {
        let labels = resecta_io::read_label_map(&b002, VoxelLimit::default()).unwrap();
        out.push(
            StudyAtrium::from_label_map(
                "b002".into(),
                &labels,
                &[36, 37],
                &[76, 77, 78, 79],
                None,
                1,
            )
            .unwrap(),
        );
    } else {
        eprintln!("SKIP b002: {} not found", b002.display());
    }
    out
}

fn bench(c: &mut Criterion) {
    let cpu = PoissonSolver::cpu();
    for atrium in atria() {
        let config = StudyConfig::default();
        let ui = config
            .upper_fractions
            .iter()
            .position(|&u| u == 0.9)
            .unwrap();
        let sample = run_sample(&atrium, &config, 600, ui, 0, false).unwrap();
        let mut g = c.benchmark_group(format!("eam/{}", atrium.name));
        for normals in [StudyNormals::Reference, StudyNormals::Estimated] {
            g.bench_function(
                format!("reconstruct_600_d5_{normals:?}").to_lowercase(),
                |b| {
                    b.iter(|| {
                        reconstruct_sample(&sample, 5, config.screening, normals, &cpu).unwrap()
                    })
                },
            );
        }
        g.sample_size(10);
        g.bench_function("study_30_conditions_x10_noise", |b| {
            b.iter(|| run_study(&atrium, &config, &cpu, &|_, _| {}).unwrap())
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
