//! The Paper I study on one mask (Sec. 6.4): PSR at several depths and MCSD over a grid of
//! smoothing × decimation, each measured against the same oriented points, scored (σ), with
//! the Pareto front and ∂P_best, ∂C_best, ∂C_sim — and the per-patient choice of depth.

use std::time::Instant;

use resecta_geom::{Real, TriMesh, Volume};
use resecta_meshmetrics::{ModelMethod, ModelRecord, Study, analyse};
use resecta_poisson::{OrientedPoints, PoissonSolver};

use crate::{McsdParams, ReconError, mcsd, measure, psr};

/// The parameter grid. Smoothing values are Paper I's s, mapped onto Slicer's factor as
/// s / 90 (see [`McsdParams::from_paper`]).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StudyConfig {
    pub depths: Vec<u32>,
    pub smoothings: Vec<Real>,
    pub decimations: Vec<Real>,
}

impl Default for StudyConfig {
    /// Sec. 6.4.1: d ∈ {5, 6, 7, 8}, s ∈ {0, 22, 45, 67, 90}, e ∈ {0, 0.1, …, 0.9}.
    fn default() -> Self {
        Self {
            depths: vec![5, 6, 7, 8],
            smoothings: vec![0.0, 22.0, 45.0, 67.0, 90.0],
            decimations: (0..10).map(|e| Real::from(e) / 10.0).collect(),
        }
    }
}

impl StudyConfig {
    /// A small grid for tests: d ∈ {5, 6, 7}, s ∈ {0, 45, 90}, e ∈ {0, 0.5}.
    pub fn quick() -> Self {
        Self {
            depths: vec![5, 6, 7],
            smoothings: vec![0.0, 45.0, 90.0],
            decimations: vec![0.0, 0.5],
        }
    }

    /// Number of models.
    pub fn len(&self) -> usize {
        self.depths.len() + self.smoothings.len() * self.decimations.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A finished study with what it was measured against.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StudyRun {
    pub config: StudyConfig,
    /// Oriented points of the mask: the accuracy reference for every model.
    pub samples: usize,
    /// Volume of the mask, ml.
    pub mask_ml: Real,
    /// Enclosed volume of every model, ml, in the order of `study.models`.
    pub volumes_ml: Vec<Real>,
    pub study: Study,
}

fn ms(since: Instant) -> Real {
    since.elapsed().as_secs_f64() * 1e3
}

fn record(
    label: String,
    method: ModelMethod,
    mesh: &TriMesh,
    points: &OrientedPoints,
    time_ms: Real,
) -> Result<(ModelRecord, Real), ReconError> {
    let q = measure(mesh, &points.positions)?;
    Ok((
        ModelRecord {
            label,
            method,
            polys: q.polys,
            points: q.points,
            mean_mm: q.mean_mm,
            p95_mm: q.p95_mm,
            max_mm: q.max_mm,
            curvature: q.curvature,
            time_ms,
        },
        q.volume_ml,
    ))
}

/// Runs the study; `progress(name)` is called after each model. Times are per model, from the
/// mask: PSR includes the oriented points, MCSD its share of the marching cubes.
pub fn run(
    mask: &Volume<bool>,
    config: &StudyConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<StudyRun, ReconError> {
    let start = Instant::now();
    let points = psr::points(mask)?;
    let points_ms = ms(start);
    let mut records = Vec::with_capacity(config.len());
    let mut volumes = Vec::with_capacity(config.len());
    for &d in &config.depths {
        let t = Instant::now();
        let mesh = psr::surface(&points, d)?;
        let label = format!("PSR d={d}");
        let (r, v) = record(
            label.clone(),
            ModelMethod::Psr { depth: d },
            &mesh,
            &points,
            points_ms + ms(t),
        )?;
        records.push(r);
        volumes.push(v);
        progress(&label);
    }
    let t = Instant::now();
    let (voxel_mesh, affine) = mcsd::marching(mask)?;
    let marching_ms = ms(t);
    for &s in &config.smoothings {
        for &e in &config.decimations {
            let t = Instant::now();
            let mesh = mcsd::filter(&voxel_mesh, &affine, &McsdParams::from_paper(s, e))?;
            let label = format!("MCSD s={s} e={e:.1}");
            let method = ModelMethod::Mcsd {
                smoothing: s,
                decimation: e,
            };
            let (r, v) = record(label.clone(), method, &mesh, &points, marching_ms + ms(t))?;
            records.push(r);
            volumes.push(v);
            progress(&label);
        }
    }
    let mask_ml = mask.data().iter().filter(|&&b| b).count() as Real
        * mask.grid().voxel_volume_mm3()
        / 1000.0;
    Ok(StudyRun {
        config: config.clone(),
        samples: points.positions.len(),
        mask_ml,
        volumes_ml: volumes,
        study: analyse(records)?,
    })
}

/// One candidate of [`auto_depth`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct DepthCandidate {
    pub depth: u32,
    pub polys: usize,
    pub mean_mm: Real,
    pub sigma: Real,
    pub time_ms: Real,
}

/// The σ-optimal depth for one patient.
#[derive(Debug, Clone)]
pub struct AutoDepth {
    pub depth: u32,
    pub mesh: TriMesh,
    pub candidates: Vec<DepthCandidate>,
}

/// Reconstructs at every depth in `depths` and keeps the one with the least σ (Eq. 6.11),
/// normalising over these candidates: the depth with the best accuracy–complexity trade-off
/// for this patient (the thesis found 7 over its six livers).
pub fn auto_depth(points: &OrientedPoints, depths: &[u32]) -> Result<AutoDepth, ReconError> {
    auto_depth_with(points, depths, &PoissonSolver::cpu())
}

/// [`auto_depth`] with every candidate solved by `solver`.
pub fn auto_depth_with(
    points: &OrientedPoints,
    depths: &[u32],
    solver: &PoissonSolver,
) -> Result<AutoDepth, ReconError> {
    let mut meshes = Vec::with_capacity(depths.len());
    let mut records = Vec::with_capacity(depths.len());
    for &d in depths {
        let t = Instant::now();
        let mesh = psr::surface_with(points, d, solver)?;
        let (r, _) = record(
            format!("PSR d={d}"),
            ModelMethod::Psr { depth: d },
            &mesh,
            points,
            ms(t),
        )?;
        records.push(r);
        meshes.push(mesh);
    }
    let study = analyse(records)?;
    let best = study.p_best.ok_or(ReconError::InvalidParameter {
        name: "depths",
        reason: "must list at least one depth",
    })?;
    let candidates = study
        .models
        .iter()
        .zip(depths)
        .map(|(m, &depth)| DepthCandidate {
            depth,
            polys: m.record.polys,
            mean_mm: m.record.mean_mm,
            sigma: m.sigma,
            time_ms: m.record.time_ms,
        })
        .collect();
    Ok(AutoDepth {
        depth: depths[best],
        mesh: meshes.swap_remove(best),
        candidates,
    })
}
