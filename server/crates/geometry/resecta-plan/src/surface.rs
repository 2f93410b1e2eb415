//! The resection surface sampled for display and analysis: points and unit normals on the
//! resection's ru×rv grid — a Bézier surface by its engine's evaluator (only what an edit
//! invalidates is recomputed), a DS or CP surface on the CPU —, the triangulated mesh, and
//! slice projections (thesis Sec. 7.3.4).

use std::sync::Arc;

use resecta_bezier::{
    BezierError, ControlNet, Outputs, P3, Resolution, SurfaceEngine, SurfaceEvaluator, SurfaceGrid,
    cpu_evaluator, grid_triangles,
};
use resecta_geom::{CutSurface, Plane, Polyline, Real, TriMesh, Vec3, slice};
use serde::{Deserialize, Serialize};

use crate::error::PlanError;
use crate::probe::SampleProbe;
use crate::resection::{Resection, ResectionKind};

/// What a surface is evaluated with.
#[derive(Debug)]
enum Shape {
    /// A Bézier surface's evaluator (its engine's, or the CPU's).
    Bezier(Box<dyn SurfaceEvaluator>),
    /// A DS or CP surface, sampled on the CPU.
    Traced(Arc<dyn CutSurface>),
}

/// A resection surface kept up to date across edits. A Bézier surface is evaluated by its
/// engine's evaluator; when that evaluator's device fails, the surface moves to the CPU
/// evaluator and evaluates again (the edit succeeds) and counts it
/// ([`LiveSurface::device_fallbacks`]).
#[derive(Debug)]
pub struct LiveSurface {
    shape: Shape,
    grid: SurfaceGrid<Real>,
    fallbacks: u32,
    device_error: Option<BezierError>,
}

fn to_vec3(p: &P3<Real>) -> Vec3 {
    Vec3::new(p[0], p[1], p[2])
}

impl LiveSurface {
    /// Evaluates the resection's surface on the CPU.
    pub fn new(r: &Resection) -> Result<Self, PlanError> {
        Self::with_engine(r, &SurfaceEngine::cpu())
    }

    /// Evaluates the resection's surface with an evaluator of `engine` (the CPU's when the
    /// engine's device fails).
    pub fn with_engine(r: &Resection, engine: &SurfaceEngine) -> Result<Self, PlanError> {
        let mut surface = Self::unevaluated(r, engine)?;
        surface.evaluate()?;
        Ok(surface)
    }

    /// The evaluator of `engine` for the resection, nothing evaluated yet.
    pub(crate) fn unevaluated(r: &Resection, engine: &SurfaceEngine) -> Result<Self, PlanError> {
        if r.kind != ResectionKind::Bezier {
            let (shape, [ru, rv]) = r.sampled_shape()?;
            return Ok(Self {
                shape: Shape::Traced(shape),
                grid: SurfaceGrid::zeroed(Resolution::new(ru, rv)?, Outputs::Normals),
                fallbacks: 0,
                device_error: None,
            });
        }
        let res = Resolution::new(r.resolution[0], r.resolution[1])?;
        let net = r.net()?;
        let mut surface = Self {
            shape: Shape::Bezier(cpu_evaluator(net.clone(), res)),
            grid: SurfaceGrid::zeroed(res, Outputs::Normals),
            fallbacks: 0,
            device_error: None,
        };
        match engine.make(net, res) {
            Ok(e) => surface.shape = Shape::Bezier(e),
            Err(e) if e.is_device() => surface.fall_back(e),
            Err(e) => return Err(e.into()),
        }
        Ok(surface)
    }

    /// Re-evaluates after an edit; reuses buffers and the basis tables when the grid size and
    /// resolution are unchanged.
    pub fn update(&mut self, r: &Resection) -> Result<(), PlanError> {
        self.set(r)?;
        self.evaluate()
    }

    /// Whether the surface is of `r`'s kind (else it is made anew).
    pub(crate) fn fits(&self, r: &Resection) -> bool {
        matches!(self.shape, Shape::Bezier(_)) == (r.kind == ResectionKind::Bezier)
    }

    /// Hands the resection's net and resolution to the evaluator (a DS or CP surface is built
    /// anew), evaluating nothing.
    pub(crate) fn set(&mut self, r: &Resection) -> Result<(), PlanError> {
        let evaluator = match &mut self.shape {
            Shape::Bezier(e) => e,
            Shape::Traced(_) => {
                let (shape, [ru, rv]) = r.sampled_shape()?;
                self.shape = Shape::Traced(shape);
                let res = Resolution::new(ru, rv)?;
                if self.grid.resolution() != res {
                    self.grid = SurfaceGrid::zeroed(res, Outputs::Normals);
                }
                return Ok(());
            }
        };
        let res = Resolution::new(r.resolution[0], r.resolution[1])?;
        if evaluator.net().dims() != (r.grid[0], r.grid[1]) {
            evaluator.set_net(r.net()?);
        } else {
            let (old, new) = (evaluator.net().points(), &r.control_points);
            let moved: Vec<usize> = if old.len() == new.len() {
                (0..old.len()).filter(|&k| old[k] != new[k]).collect()
            } else {
                vec![usize::MAX] // refused by set_control_points
            };
            // A drag moves one point: hand over only that one (a GPU uploads only it).
            match moved[..] {
                [] => {}
                [k] if k < new.len() => {
                    let n = r.grid[1];
                    evaluator.set_control_point(k / n, k % n, new[k])?;
                }
                _ => evaluator.set_control_points(new)?,
            }
        }
        if evaluator.resolution() != res {
            evaluator.set_resolution(res);
            self.grid = SurfaceGrid::zeroed(res, Outputs::Normals);
        }
        Ok(())
    }

    /// Moves the surface to the CPU evaluator after a device failure.
    pub(crate) fn fall_back(&mut self, error: BezierError) {
        if let Shape::Bezier(e) = &self.shape {
            self.shape = Shape::Bezier(cpu_evaluator(e.net().clone(), e.resolution()));
        }
        self.fallbacks += 1;
        self.device_error = Some(error);
    }

    /// Evaluates through `probe`, which also measures the samples' inside levels and tumour
    /// distances: `Ok(true)`. When its device fails the surface moves to the CPU and is
    /// evaluated there, the samples unmeasured: `Ok(false)`, as for a DS or CP surface (probes
    /// measure Bézier surfaces).
    pub(crate) fn evaluate_probed(
        &mut self,
        probe: &mut dyn SampleProbe,
        inside: &mut Vec<Real>,
        distance: &mut Vec<Real>,
    ) -> Result<bool, PlanError> {
        let Shape::Bezier(evaluator) = &mut self.shape else {
            self.evaluate()?;
            return Ok(false);
        };
        match probe.measure(evaluator.as_mut(), &mut self.grid, inside, distance) {
            Ok(()) => Ok(true),
            Err(e) if e.is_device() => {
                self.fall_back(e);
                self.evaluate()?;
                Ok(false)
            }
            Err(e) => Err(e.into()),
        }
    }

    pub(crate) fn evaluate(&mut self) -> Result<(), PlanError> {
        let evaluator = match &mut self.shape {
            Shape::Bezier(e) => e,
            Shape::Traced(s) => {
                let res = self.grid.resolution();
                let (mut points, mut normals) = (Vec::new(), Vec::new());
                s.sample(res.ru(), res.rv(), &mut points, &mut normals);
                let (p, _, _, n) = self.grid.parts_mut();
                let a = |v: &Vec3| [v.x, v.y, v.z];
                p.iter_mut().zip(&points).for_each(|(o, v)| *o = a(v));
                if let Some(n) = n {
                    n.iter_mut().zip(&normals).for_each(|(o, v)| *o = a(v));
                }
                return Ok(());
            }
        };
        match evaluator.evaluate_into(&mut self.grid) {
            Err(e) if e.is_device() => {
                self.fall_back(e);
                self.evaluate()
            }
            r => Ok(r?),
        }
    }

    /// Where the surface is evaluated now (`"cpu"`, `"wgpu"`, …).
    pub fn backend(&self) -> &'static str {
        match &self.shape {
            Shape::Bezier(e) => e.backend(),
            Shape::Traced(_) => "cpu",
        }
    }
    /// How often a device failure moved this surface to the CPU evaluator.
    pub fn device_fallbacks(&self) -> u32 {
        self.fallbacks
    }
    /// The last device failure that did, if any.
    pub fn device_error(&self) -> Option<&BezierError> {
        self.device_error.as_ref()
    }

    /// [ru, rv].
    pub fn resolution(&self) -> [usize; 2] {
        let r = self.grid.resolution();
        [r.ru(), r.rv()]
    }
    /// A Bézier surface's control net.
    pub fn net(&self) -> Option<&ControlNet<Real>> {
        match &self.shape {
            Shape::Bezier(e) => Some(e.net()),
            Shape::Traced(_) => None,
        }
    }
    /// The surface as a [`CutSurface`] (points, derivatives and curvature anywhere).
    pub fn cut_surface(&self) -> &dyn CutSurface {
        match &self.shape {
            Shape::Bezier(e) => e.net(),
            Shape::Traced(s) => s.as_ref(),
        }
    }
    /// Sample points, index `a·rv + b`.
    pub fn points(&self) -> Vec<Vec3> {
        self.grid.points().iter().map(to_vec3).collect()
    }
    /// Unit normals (∂S/∂u × ∂S/∂v direction), same indexing.
    pub fn normals(&self) -> Vec<Vec3> {
        self.grid
            .normals()
            .map(|n| n.iter().map(to_vec3).collect())
            .unwrap_or_default()
    }
    /// Raw sample buffers (points, normals).
    pub fn grid(&self) -> &SurfaceGrid<Real> {
        &self.grid
    }
    /// The surface at any (u, v) ∈ [0, 1]².
    pub fn point_at(&self, u: Real, v: Real) -> Vec3 {
        self.cut_surface().at(u, v).p
    }

    /// The triangulated surface with its normals.
    pub fn mesh(&self) -> Result<TriMesh, PlanError> {
        let [ru, rv] = self.resolution();
        Ok(TriMesh::new(self.points(), grid_triangles(ru, rv))?.with_normals(self.normals())?)
    }
}

/// Positions (RAS mm) of the axial (S), coronal (A) and sagittal (R) planes to intersect.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SlicePositions {
    pub axial: Option<Real>,
    pub coronal: Option<Real>,
    pub sagittal: Option<Real>,
}

/// The surface's intersections with the slice planes, as polylines in RAS.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SliceProjections {
    pub axial: Vec<Polyline>,
    pub coronal: Vec<Polyline>,
    pub sagittal: Vec<Polyline>,
}

/// Intersects `mesh` with the requested axis planes.
pub fn slice_projections(
    mesh: &TriMesh,
    at: &SlicePositions,
) -> Result<SliceProjections, PlanError> {
    let cut = |pos: Option<Real>, normal: Vec3| -> Result<Vec<Polyline>, PlanError> {
        match pos {
            None => Ok(Vec::new()),
            Some(p) => Ok(slice(mesh, &Plane::new(normal * p, normal)?)),
        }
    };
    Ok(SliceProjections {
        axial: cut(at.axial, Vec3::z())?,
        coronal: cut(at.coronal, Vec3::y())?,
        sagittal: cut(at.sagittal, Vec3::x())?,
    })
}
