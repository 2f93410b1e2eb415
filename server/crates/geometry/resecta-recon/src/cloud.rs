//! Surfaces from point clouds (thesis ch. 9: the points a mapping catheter collects), with or
//! without normals: normals estimated where missing ([`resecta_pointcloud`]: local PCA and a
//! consistent outward orientation), every point weighted by the area its neighbourhood
//! stands for, then the screened Poisson solve and marching cubes as for label maps.

use std::time::Instant;

use resecta_geom::{Real, TriMesh, Vec3};
pub use resecta_pointcloud::{
    DEFAULT_NEIGHBOURS as DEFAULT_CLOUD_NEIGHBOURS, MAX_NEIGHBOURS as MAX_CLOUD_NEIGHBOURS,
    MIN_NEIGHBOURS as MIN_CLOUD_NEIGHBOURS, MIN_POINTS as MIN_CLOUD_POINTS,
};
use resecta_pointcloud::{DEFAULT_NEIGHBOURS, NormalParams, estimate_normals, point_areas};
use resecta_poisson::{OrientedPoints, PoissonParams, PoissonSolver};
use serde::Serialize;

use crate::ReconError;
use crate::psr::{field, field_surface};

/// Default depth for catheter clouds: the thesis' choice for 100–600 points (d > 4 changed
/// its errors negligibly, Sec. 9.3).
pub const DEFAULT_CLOUD_DEPTH: u32 = 5;

/// Options of [`reconstruct_cloud`].
#[derive(Debug, Clone, PartialEq)]
pub struct CloudOptions {
    /// PSR depth (`2^depth` cells across the points' bounding cube).
    pub depth: u32,
    /// Neighbours per point for normals and areas.
    pub neighbours: usize,
}

impl Default for CloudOptions {
    fn default() -> Self {
        Self {
            depth: DEFAULT_CLOUD_DEPTH,
            neighbours: DEFAULT_NEIGHBOURS,
        }
    }
}

/// Where the normals came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NormalSource {
    /// Given with the points (normalised here).
    Given,
    /// Estimated: local PCA, oriented over the neighbour graph's spanning forest.
    Estimated,
}

/// How the cloud was read and solved.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CloudReport {
    pub points: usize,
    /// Distinct positions (exact duplicates merged for the neighbourhoods).
    pub distinct: usize,
    pub normals: NormalSource,
    /// Components of the neighbour graph (estimated normals only; each oriented separately).
    pub components: Option<usize>,
    /// Points with a collinear neighbourhood that took their neighbour's normal.
    pub degenerate: Option<usize>,
    /// Median distance to the nearest other point, mm.
    pub spacing_mm: Option<Real>,
    /// Sum of the point areas, mm² (an estimate of the surface's area).
    pub sampled_area_mm2: Real,
    pub depth: u32,
    /// Finest cell of the Poisson grid, mm.
    pub cell_mm: Real,
    pub normals_s: Real,
    pub solve_s: Real,
    pub surface_s: Real,
}

/// A closed surface of a cloud with its oriented samples.
#[derive(Debug, Clone)]
pub struct CloudModel {
    pub mesh: TriMesh,
    pub points: OrientedPoints,
    pub report: CloudReport,
}

/// Oriented points of a cloud: `normals` normalised when given, estimated otherwise; areas
/// from the local density either way.
pub fn orient_cloud(
    positions: &[Vec3],
    normals: Option<&[Vec3]>,
    neighbours: usize,
) -> Result<(OrientedPoints, CloudReport), ReconError> {
    let mut report = CloudReport {
        points: positions.len(),
        distinct: 0,
        normals: NormalSource::Given,
        components: None,
        degenerate: None,
        spacing_mm: None,
        sampled_area_mm2: 0.0,
        depth: 0,
        cell_mm: 0.0,
        normals_s: 0.0,
        solve_s: 0.0,
        surface_s: 0.0,
    };
    let t = Instant::now();
    let points = match normals {
        Some(given) => {
            if given.len() != positions.len() {
                return Err(ReconError::NormalCount {
                    points: positions.len(),
                    normals: given.len(),
                });
            }
            let mut unit = Vec::with_capacity(given.len());
            for (index, n) in given.iter().enumerate() {
                let len = n.norm();
                if !(len.is_finite() && len > 1e-12) {
                    return Err(ReconError::BadNormal { index });
                }
                unit.push(n / len);
            }
            let (areas, distinct) = point_areas(positions, neighbours)?;
            report.distinct = distinct;
            OrientedPoints {
                positions: positions.to_vec(),
                normals: unit,
                areas,
            }
        }
        None => {
            let est = estimate_normals(positions, &NormalParams { neighbours })?;
            report.normals = NormalSource::Estimated;
            report.distinct = est.distinct;
            report.components = Some(est.components);
            report.degenerate = Some(est.degenerate);
            report.spacing_mm = Some(est.spacing_mm);
            OrientedPoints {
                positions: positions.to_vec(),
                normals: est.normals,
                areas: est.areas,
            }
        }
    };
    report.sampled_area_mm2 = points.areas.iter().sum();
    report.normals_s = t.elapsed().as_secs_f64();
    Ok((points, report))
}

/// The closed PSR surface of a cloud (RAS, vertex normals), solved by `solver`. Runs on a
/// rayon worker: a catheter cloud's small grid (33³ at d = 5) has many short parallel loops,
/// and each one started from outside the pool waits for it to wake (4× the time at d = 5).
pub fn reconstruct_cloud(
    positions: &[Vec3],
    normals: Option<&[Vec3]>,
    options: &CloudOptions,
    solver: &PoissonSolver,
) -> Result<CloudModel, ReconError> {
    rayon::scope(|_| {
        let (points, mut report) = orient_cloud(positions, normals, options.neighbours)?;
        let params = PoissonParams {
            depth: options.depth,
            ..PoissonParams::default()
        };
        let t = Instant::now();
        let f = field(&points, &params, solver)?;
        report.solve_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mesh = field_surface(&f, solver)?;
        report.surface_s = t.elapsed().as_secs_f64();
        report.depth = options.depth;
        report.cell_mm = f.cell;
        Ok(CloudModel {
            mesh,
            points,
            report,
        })
    })
}
