//! The sampling study (thesis Sec. 9.2): conditions, draws, noise, reconstruction, error.

use std::f64::consts::PI;
use std::time::Instant;

use rand::seq::index::sample_weighted;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use resecta_geom::{MeshBvh, Real, TriMesh, Vec3};
use resecta_pointcloud::DEFAULT_NEIGHBOURS;
use resecta_poisson::{OrientedPoints, PoissonParams, PoissonSolver};
use resecta_recon::{orient_cloud, psr};
use serde::Serialize;

use crate::EamError;
use crate::atrium::StudyAtrium;
use crate::split::Split;

/// Electromagnetic tracking error (thesis: NDI Aurora, mean 0.76 mm, s.d. 0.67 mm). Each point
/// moves by `|m|`, `m ~ N(mean, sd)`, in a uniformly random direction; normals are kept.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NoiseModel {
    pub mean_mm: Real,
    pub sd_mm: Real,
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self {
            mean_mm: 0.76,
            sd_mm: 0.67,
        }
    }
}

/// The normals PSR gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StudyNormals {
    /// The reference's (the thesis: gradient of the label map; mesh or exact normals).
    Reference,
    /// None given: estimated from the drawn points as for real catheter points
    /// ([`resecta_recon::orient_cloud`]); areas from the local density.
    Estimated,
}

/// The conditions of a study.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudyConfig {
    /// Points per reconstruction (thesis: 100, 200, …, 600).
    pub counts: Vec<usize>,
    /// Fractions drawn from the upper part (thesis: 0.5, 0.6, …, 0.9).
    pub upper_fractions: Vec<Real>,
    /// With a model, every draw is also reconstructed with this noise added (paired).
    pub noise: Option<NoiseModel>,
    /// Draws per condition.
    pub repeats: usize,
    pub depth: u32,
    /// PSR's screening weight α (resecta-poisson's default 4; near 0 approaches the unscreened
    /// PSR of 2006 the thesis used).
    pub screening: Real,
    pub normals: StudyNormals,
    pub seed: u64,
}

impl Default for StudyConfig {
    fn default() -> Self {
        Self {
            counts: vec![100, 200, 300, 400, 500, 600],
            upper_fractions: vec![0.5, 0.6, 0.7, 0.8, 0.9],
            noise: Some(NoiseModel::default()),
            repeats: 10,
            depth: 5,
            screening: PoissonParams::default().screening,
            normals: StudyNormals::Reference,
            seed: 2018,
        }
    }
}

/// One reconstruction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunResult {
    pub n: usize,
    pub u: Real,
    pub noise: bool,
    pub repeat: usize,
    /// Median distance from the reference points to the reconstruction, mm.
    pub median_error_mm: Real,
    /// Normals (if estimated), Poisson solve and marching cubes, s.
    pub time_s: Real,
    pub triangles: usize,
}

/// One condition over its repeats.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConditionResult {
    pub n: usize,
    pub u: Real,
    pub noise: bool,
    /// Median over the repeats of each reconstruction's median error, mm.
    pub median_error_mm: Real,
    /// Quartiles of the same, mm.
    pub q1_error_mm: Real,
    pub q3_error_mm: Real,
    pub median_time_s: Real,
    pub repeats: usize,
}

/// A whole study on one atrium.
#[derive(Debug, Clone, Serialize)]
pub struct StudyResults {
    pub atrium: String,
    pub config: StudyConfig,
    pub split: Split,
    pub upper_area_mm2: Real,
    pub lower_area_mm2: Real,
    pub pool_points: usize,
    pub reference_points: usize,
    pub conditions: Vec<ConditionResult>,
    pub runs: Vec<RunResult>,
    /// Wall clock of all runs, s.
    pub wall_s: Real,
}

impl StudyConfig {
    fn check(&self) -> Result<(), EamError> {
        let bad = |name, reason: &str| {
            Err(EamError::InvalidParameter {
                name,
                reason: reason.into(),
            })
        };
        if self.counts.is_empty() || self.counts.iter().any(|&n| !(4..=100_000).contains(&n)) {
            return bad("n", "needs values in 4..=100000");
        }
        if self.upper_fractions.is_empty()
            || self
                .upper_fractions
                .iter()
                .any(|u| !(0.0..=1.0).contains(u))
        {
            return bad("u", "needs values in [0, 1]");
        }
        if !(1..=1000).contains(&self.repeats) {
            return bad("repeats", "must lie in 1..=1000");
        }
        if !(1..=resecta_poisson::MAX_DEPTH).contains(&self.depth) {
            return bad("depth", "must lie in 1..=10");
        }
        if !(self.screening.is_finite() && self.screening > 0.0) {
            return bad("screening", "must be a finite number > 0");
        }
        if let Some(m) = self.noise
            && !(m.mean_mm.is_finite() && m.sd_mm.is_finite() && m.sd_mm >= 0.0)
        {
            return bad("noise", "needs a finite mean and a finite s.d. ≥ 0");
        }
        Ok(())
    }
}

/// A seeded stream per (seed, n, u index, repeat, purpose) (SplitMix64 mixing).
fn stream(seed: u64, parts: [u64; 4]) -> ChaCha8Rng {
    let mut x = seed;
    for p in parts {
        x = x.wrapping_add(p).wrapping_add(0x9E37_79B9_7F4A_7C15);
        x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        x ^= x >> 31;
    }
    ChaCha8Rng::seed_from_u64(x)
}

/// round(n·u) points from the upper part and the rest from the lower, each part drawn by area
/// without replacement; every point weighted by its part's area over its part's count.
pub fn draw(
    atrium: &StudyAtrium,
    n: usize,
    u: Real,
    rng: &mut impl Rng,
) -> Result<OrientedPoints, EamError> {
    let nu = (n as Real * u).round() as usize;
    let parts = [
        (true, nu, atrium.upper_area_mm2),
        (false, n - nu, atrium.lower_area_mm2),
    ];
    let mut out = OrientedPoints::default();
    for (upper, count, area) in parts {
        if count == 0 {
            continue;
        }
        let members: Vec<usize> = (0..atrium.upper.len())
            .filter(|&i| atrium.upper[i] == upper)
            .collect();
        if count > members.len() {
            return Err(EamError::InvalidParameter {
                name: "n",
                reason: format!(
                    "asks {count} points of the {} part, which has {}",
                    if upper { "upper" } else { "lower" },
                    members.len()
                ),
            });
        }
        let areas = &atrium.pool.areas;
        let picked =
            sample_weighted(rng, members.len(), |i| areas[members[i]], count).map_err(|e| {
                EamError::InvalidParameter {
                    name: "pool areas",
                    reason: e.to_string(),
                }
            })?;
        for i in picked.into_iter() {
            let p = members[i];
            out.positions.push(atrium.pool.positions[p]);
            out.normals.push(atrium.pool.normals[p]);
            out.areas.push(area / count as Real);
        }
    }
    Ok(out)
}

/// Moves every point as [`NoiseModel`] says.
pub fn add_noise(points: &mut OrientedPoints, model: &NoiseModel, rng: &mut impl Rng) {
    let Ok(normal) = Normal::new(model.mean_mm, model.sd_mm) else {
        return;
    };
    for p in &mut points.positions {
        let m: Real = normal.sample(rng);
        let z: Real = rng.random_range(-1.0..=1.0);
        let phi: Real = rng.random_range(0.0..2.0 * PI);
        let r = (1.0 - z * z).max(0.0).sqrt();
        *p += Vec3::new(r * phi.cos(), r * phi.sin(), z) * m.abs();
    }
}

/// The PSR surface of a drawn sample at `depth` and `screening`, and the seconds it took.
pub fn reconstruct_sample(
    sample: &OrientedPoints,
    depth: u32,
    screening: Real,
    normals: StudyNormals,
    solver: &PoissonSolver,
) -> Result<(TriMesh, Real), EamError> {
    // On a worker thread, as resecta_recon::reconstruct_cloud: the small grid's many short
    // parallel loops then do not wake the pool from outside each time.
    rayon::scope(|_| {
        let t = Instant::now();
        let estimated;
        let points = match normals {
            StudyNormals::Reference => sample,
            StudyNormals::Estimated => {
                estimated = orient_cloud(&sample.positions, None, DEFAULT_NEIGHBOURS)?.0;
                &estimated
            }
        };
        let params = PoissonParams {
            depth,
            screening,
            ..PoissonParams::default()
        };
        let field = psr::field(points, &params, solver)?;
        let mesh = psr::field_surface(&field, solver)?;
        Ok((mesh, t.elapsed().as_secs_f64()))
    })
}

/// Median distance from `reference` to `mesh`, mm.
pub fn median_error(reference: &[Vec3], mesh: &TriMesh) -> Result<Real, EamError> {
    let bvh = MeshBvh::new(mesh)?;
    let mut d: Vec<Real> = reference
        .par_iter()
        .map(|p| bvh.closest_point(p).map_or(Real::INFINITY, |c| c.distance))
        .collect();
    d.sort_unstable_by(Real::total_cmp);
    Ok(quantile(&d, 0.5))
}

/// Linear-interpolation quantile of sorted values (NaN if empty).
fn quantile(sorted: &[Real], q: Real) -> Real {
    if sorted.is_empty() {
        return Real::NAN;
    }
    let x = q * (sorted.len() - 1) as Real;
    let (i, f) = (x.floor() as usize, x.fract());
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] * (1.0 - f) + sorted[j] * f
}

/// The sample of run (`n`, `config.upper_fractions[ui]`, `repeat`), with the configured noise
/// if `noisy`: the one [`run_study`] reconstructs (noisy runs move the clean run's points).
pub fn run_sample(
    atrium: &StudyAtrium,
    config: &StudyConfig,
    n: usize,
    ui: usize,
    repeat: usize,
    noisy: bool,
) -> Result<OrientedPoints, EamError> {
    let u = *config
        .upper_fractions
        .get(ui)
        .ok_or_else(|| EamError::InvalidParameter {
            name: "u",
            reason: format!("has no index {ui}"),
        })?;
    let key = [n as u64, ui as u64, repeat as u64];
    let mut sample = draw(
        atrium,
        n,
        u,
        &mut stream(config.seed, [key[0], key[1], key[2], 0]),
    )?;
    if let (true, Some(model)) = (noisy, config.noise) {
        let mut rng = stream(config.seed, [key[0], key[1], key[2], 1]);
        add_noise(&mut sample, &model, &mut rng);
    }
    Ok(sample)
}

/// Runs every condition and repeat (in parallel; results do not depend on the thread
/// count), calling `progress(done, total)` after each reconstruction.
pub fn run_study(
    atrium: &StudyAtrium,
    config: &StudyConfig,
    solver: &PoissonSolver,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<StudyResults, EamError> {
    config.check()?;
    let mut jobs = Vec::new();
    for &n in &config.counts {
        for (ui, &u) in config.upper_fractions.iter().enumerate() {
            for r in 0..config.repeats {
                jobs.push((n, ui, u, r));
            }
        }
    }
    let per_draw = if config.noise.is_some() { 2 } else { 1 };
    let total = jobs.len() * per_draw;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let start = Instant::now();
    let runs: Vec<Vec<RunResult>> = jobs
        .par_iter()
        .map(|&(n, ui, u, r)| {
            let key = [n as u64, ui as u64, r as u64];
            let clean = draw(
                atrium,
                n,
                u,
                &mut stream(config.seed, [key[0], key[1], key[2], 0]),
            )?;
            let mut samples = vec![(false, clean)];
            if let Some(model) = config.noise {
                let mut noisy = samples[0].1.clone();
                let mut rng = stream(config.seed, [key[0], key[1], key[2], 1]);
                add_noise(&mut noisy, &model, &mut rng);
                samples.push((true, noisy));
            }
            samples
                .into_iter()
                .map(|(noise, sample)| {
                    let (mesh, time_s) = reconstruct_sample(
                        &sample,
                        config.depth,
                        config.screening,
                        config.normals,
                        solver,
                    )?;
                    let median_error_mm = median_error(&atrium.reference, &mesh)?;
                    let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                    progress(k, total);
                    Ok(RunResult {
                        n,
                        u,
                        noise,
                        repeat: r,
                        median_error_mm,
                        time_s,
                        triangles: mesh.triangles().len(),
                    })
                })
                .collect()
        })
        .collect::<Result<_, EamError>>()?;
    let runs: Vec<RunResult> = runs.into_iter().flatten().collect();
    let wall_s = start.elapsed().as_secs_f64();
    let mut conditions = Vec::new();
    for &n in &config.counts {
        for &u in &config.upper_fractions {
            for noise in [false, true].into_iter().take(per_draw) {
                let of = |f: fn(&RunResult) -> Real| {
                    let mut v: Vec<Real> = runs
                        .iter()
                        .filter(|x| x.n == n && x.u == u && x.noise == noise)
                        .map(f)
                        .collect();
                    v.sort_unstable_by(Real::total_cmp);
                    v
                };
                let errors = of(|x| x.median_error_mm);
                let times = of(|x| x.time_s);
                conditions.push(ConditionResult {
                    n,
                    u,
                    noise,
                    median_error_mm: quantile(&errors, 0.5),
                    q1_error_mm: quantile(&errors, 0.25),
                    q3_error_mm: quantile(&errors, 0.75),
                    median_time_s: quantile(&times, 0.5),
                    repeats: errors.len(),
                });
            }
        }
    }
    Ok(StudyResults {
        atrium: atrium.name.clone(),
        config: config.clone(),
        split: atrium.split.clone(),
        upper_area_mm2: atrium.upper_area_mm2,
        lower_area_mm2: atrium.lower_area_mm2,
        pool_points: atrium.pool.len(),
        reference_points: atrium.reference.len(),
        conditions,
        runs,
        wall_s,
    })
}
