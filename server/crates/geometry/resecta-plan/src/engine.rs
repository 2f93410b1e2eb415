//! The planner: one patient's anatomy, a plan with its history, and for every resection the
//! live surface with per-vertex margins, inside flags and the global verdict; volumetry on
//! demand. This is the operation core the CLI and the server drive.

use std::collections::BTreeMap;
use std::sync::Arc;

use rayon::prelude::*;
use resecta_geom::{CutSurface, Plane, Real, TriMesh, Vec3, Volume};
use resecta_margin::{
    MarginClass, MarginField, MarginMemo, MarginSettings, SurfaceMargins, SurfaceOracle, Verdict,
    evaluate_exact_into,
};
use resecta_volumetry::{IncompleteCut, LiverVoxels, MultiCut, Volumetry, VolumetryError};
use serde::Serialize;

use crate::anatomy::Anatomy;
use crate::error::PlanError;
use crate::history::{Change, History, Staged};
use crate::init::{Initialisation, initialise, slicing_plane};
use crate::metrics::{ResectionMetrics, resection_metrics, volume_deviation_pct};
use crate::plan::{Plan, PlanEvent};
use crate::probe::{ComputeEngine, SampleProbe};
use crate::resection::{Resection, Target, arr};
use crate::surface::LiveSurface;
use crate::vascular::{self, CutMesh, RiskMap, RiskReport, TERRITORY_GENERATION, Vascular};
use resecta_vessels::VesselSystem;

/// Default future-liver-remnant warning threshold (% of the total functional liver).
pub const DEFAULT_FLR_THRESHOLD_PCT: Real = 30.0;

/// Spacing of the margin field's nearest-triangle hints (mm), coarser only for livers so large
/// that the grid would exceed [`HINT_NODES`] nodes.
const HINT_SPACING_MM: Real = 2.0;
const HINT_NODES: Real = 4.0e6;
/// Hints cover the liver's bounding box grown by this (mm); farther queries stay exact, only slower.
const HINT_PAD_MM: Real = 10.0;

/// Below this many vertices inside levels are computed on the calling thread (waking the pool
/// costs more than the ~25 ns lookups).
const PARALLEL_INSIDE: usize = 10_000;
/// Target selections remembered (more distinct targets start the memory afresh).
const MAX_SELECTIONS: usize = 32;

/// The margin structures of the tumours `selected` of `tumours` (mesh of all of them, hints
/// over the liver's bounding box `liver` grown by [`HINT_PAD_MM`], voxel cell `cell`).
pub(crate) fn build_target(
    tumours: &[crate::anatomy::Tumour],
    selected: &[usize],
    liver: (Vec3, Vec3),
    cell: resecta_geom::Mat3,
) -> Result<TargetModel, PlanError> {
    let meshes: Vec<TriMesh> = selected.iter().map(|&k| tumours[k].mesh.clone()).collect();
    let mesh = TriMesh::concat(&meshes)?;
    let (lo, hi) = liver;
    let pad = Vec3::repeat(HINT_PAD_MM);
    let (lo, hi) = (lo - pad, hi + pad);
    let extent = hi - lo;
    let spacing = HINT_SPACING_MM.max((extent.x * extent.y * extent.z / HINT_NODES).cbrt());
    let field = MarginField::new(&mesh, lo, hi, spacing)?.with_voxel_cell(cell);
    let centroids = selected.iter().map(|&k| tumours[k].centroid).collect();
    Ok(TargetModel {
        tumours: selected.to_vec(),
        centroids,
        field,
    })
}

/// The target tumours of a resection, ready for margin queries.
#[derive(Debug)]
pub struct TargetModel {
    /// Indices into [`Anatomy::tumours`].
    pub tumours: Vec<usize>,
    /// Centroid of every selected tumour: the resected side holds them.
    pub centroids: Vec<Vec3>,
    pub field: MarginField,
}

/// A resection's current surface and margin analysis.
#[derive(Debug)]
pub struct ResectionState {
    pub surface: LiveSurface,
    pub target: Arc<TargetModel>,
    /// Inside level of the liver envelope per vertex (> 0 inside).
    pub inside: Vec<Real>,
    pub margins: SurfaceMargins,
    pub verdict: Verdict,
    /// Distances kept for the next edit of this resection.
    memo: MarginMemo,
    /// Measures the samples on a device (for this target), when the planner has a probe engine.
    probe: Option<Box<dyn SampleProbe>>,
}

impl ResectionState {
    /// The surface mesh with `margin_mm` and `margin_class` scalars per vertex.
    pub fn mesh(&self) -> Result<TriMesh, PlanError> {
        let classes = self
            .margins
            .class
            .iter()
            .map(|&c| Real::from(c as u8))
            .collect();
        Ok(self
            .surface
            .mesh()?
            .with_scalars("margin_mm", self.margins.distance.clone())?
            .with_scalars("margin_class", classes)?)
    }
}

struct Oracle<'a> {
    surface: &'a LiveSurface,
    anatomy: &'a Anatomy,
}

impl SurfaceOracle for Oracle<'_> {
    fn point(&self, u: Real, v: Real) -> Vec3 {
        self.surface.point_at(u, v)
    }
    fn inside(&self, p: &Vec3) -> Real {
        self.anatomy.inside_level(p)
    }
}

/// Volumes of a plan (ml and %).
#[derive(Debug, Clone, Serialize)]
pub struct VolumeReport {
    pub total_ml: Real,
    /// `None` when some resection does not cut through the liver completely.
    pub remnant_ml: Option<Real>,
    pub remnant_pct: Option<Real>,
    pub resected_ml: Option<Real>,
    pub flr_threshold_pct: Real,
    /// Remnant below the threshold.
    pub flr_warning: Option<bool>,
    pub complete: bool,
    pub resections: Vec<ResectionVolume>,
    /// What the cuts put at risk, when the anatomy has vessel trees and every cut is complete
    /// (then `flr_warning` is based on the functional remnant).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub risk: Option<RiskReport>,
    /// Why there is no risk analysis although the roles name vessels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub risk_unavailable: Option<String>,
}

/// One resection's volume.
#[derive(Debug, Clone, Serialize)]
pub struct ResectionVolume {
    pub name: String,
    pub resected_ml: Option<Real>,
    pub resected_pct: Option<Real>,
    pub complete_cut: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub incomplete: Option<IncompleteCut>,
    /// Sec. 7.4's metrics (the volume deviation once compared with a reference,
    /// [`VolumeReport::compare_with`]).
    pub metrics: ResectionMetrics,
}

impl VolumeReport {
    /// Sets every resection's volume deviation against the same-named resection of
    /// `reference` (absent there or incomplete on either side: none).
    pub fn compare_with(&mut self, reference: &VolumeReport) {
        for r in &mut self.resections {
            let v_ref = reference
                .resections
                .iter()
                .find(|x| x.name == r.name)
                .and_then(|x| x.resected_ml);
            r.metrics.volume_deviation_pct = volume_deviation_pct(r.resected_ml, v_ref);
        }
    }
}

/// One patient's planning session (without the network).
#[derive(Debug)]
pub struct Planner {
    anatomy: Arc<Anatomy>,
    history: History,
    states: BTreeMap<String, ResectionState>,
    targets: BTreeMap<Vec<usize>, Arc<TargetModel>>,
    /// Tumours picked by each target seen (selection scans tumour voxels: once per target).
    selections: Vec<(Target, Vec<usize>)>,
    volumetry: Option<Volumetry>,
    /// Makes each resection's surface evaluator and probe; the CPU's after a device failure.
    compute: ComputeEngine,
    device_fallbacks: u32,
    pub flr_threshold_pct: Real,
}

impl Planner {
    /// A planner for `plan` (roles must match the anatomy's) on `anatomy`, its surfaces
    /// evaluated on the CPU.
    pub fn new(anatomy: Arc<Anatomy>, plan: Plan) -> Result<Self, PlanError> {
        Self::with_engine(anatomy, plan, ComputeEngine::cpu())
    }

    /// Like [`Planner::new`], its surfaces evaluated by `engine`'s evaluators and their samples
    /// measured by its probes (each resection falls back to the CPU when its device fails, see
    /// [`LiveSurface`]).
    pub fn with_engine(
        anatomy: Arc<Anatomy>,
        plan: Plan,
        engine: impl Into<ComputeEngine>,
    ) -> Result<Self, PlanError> {
        anatomy.liver_bounds().ok_or(PlanError::EmptyLiver)?;
        let mut planner = Self {
            anatomy,
            history: History::new(plan),
            states: BTreeMap::new(),
            targets: BTreeMap::new(),
            selections: Vec::new(),
            volumetry: None,
            compute: engine.into(),
            device_fallbacks: 0,
            flr_threshold_pct: DEFAULT_FLR_THRESHOLD_PCT,
        };
        planner.refresh_all()?;
        Ok(planner)
    }

    /// Continues a persisted session: the base plan and its log.
    pub fn resume(anatomy: Arc<Anatomy>, history: History) -> Result<Self, PlanError> {
        Self::resume_with_engine(anatomy, history, ComputeEngine::cpu())
    }

    /// Like [`Planner::resume`] computing with `engine`.
    pub fn resume_with_engine(
        anatomy: Arc<Anatomy>,
        history: History,
        engine: impl Into<ComputeEngine>,
    ) -> Result<Self, PlanError> {
        let mut planner = Self::with_engine(anatomy, history.base().clone(), engine)?;
        planner.history = history;
        planner.states.clear();
        planner.refresh_all()?;
        Ok(planner)
    }

    /// The shared anatomy (for a new planner on the same patient).
    pub fn anatomy_shared(&self) -> Arc<Anatomy> {
        Arc::clone(&self.anatomy)
    }
    /// The engine that makes the surface evaluators and probes (for a new planner on the same
    /// device).
    pub fn compute_engine(&self) -> &ComputeEngine {
        &self.compute
    }
    /// How often a resection's device failed since this planner was made; the first failure
    /// moves the planner to the CPU engine (its other resections move at their own next
    /// failure).
    pub fn device_fallbacks(&self) -> u32 {
        self.device_fallbacks
    }
    pub fn anatomy(&self) -> &Anatomy {
        &self.anatomy
    }
    pub fn plan(&self) -> &Plan {
        self.history.plan()
    }
    pub fn history(&self) -> &History {
        &self.history
    }
    /// The live state of a resection.
    pub fn state(&self, name: &str) -> Result<&ResectionState, PlanError> {
        self.states
            .get(name)
            .ok_or_else(|| PlanError::UnknownResection(name.to_owned()))
    }
    /// Every resection's state, by name.
    pub fn states(&self) -> &BTreeMap<String, ResectionState> {
        &self.states
    }

    /// Computes the initial resection for a target and an end point (Algorithms 1–2) without
    /// changing the plan.
    pub fn initial_resection(
        &mut self,
        name: &str,
        target: &Target,
        end_point: Vec3,
        grid: [usize; 2],
    ) -> Result<(Resection, Initialisation), PlanError> {
        let model = self.target_model(target)?;
        let centroid = self
            .anatomy
            .centroid(&model.tumours)
            .ok_or(PlanError::NoTumour)?;
        self.initial_on_plane(name, target, &slicing_plane(centroid, end_point)?, grid)
    }

    /// The initial resection on a given plane (scripted use: a point and a normal).
    pub fn initial_on_plane(
        &mut self,
        name: &str,
        target: &Target,
        plane: &Plane,
        grid: [usize; 2],
    ) -> Result<(Resection, Initialisation), PlanError> {
        self.target_model(target)?;
        let init = initialise(self.anatomy.parenchyma(), plane, grid)?;
        let mut r = Resection::new(name, grid, init.control_points.clone());
        r.target = target.clone();
        r.validate()?;
        Ok((r, init))
    }

    /// Applies an edit and updates the affected resection; returns what changed and the log
    /// entry. On error nothing changes.
    pub fn edit(&mut self, event: PlanEvent) -> Result<Change, PlanError> {
        let step = self.history.stage_edit(event)?;
        self.commit(step)
    }

    /// Takes back the last edit.
    pub fn undo(&mut self) -> Result<Change, PlanError> {
        let step = self.history.stage_undo()?;
        self.commit(step)
    }

    /// Restores the last undone edit.
    pub fn redo(&mut self) -> Result<Change, PlanError> {
        let step = self.history.stage_redo()?;
        self.commit(step)
    }

    /// Recomputes the resections a staged step changes, then records the step in the history
    /// (nothing applied again); on any failure the plan is unchanged (the states are rebuilt
    /// for it).
    fn commit(&mut self, step: Staged) -> Result<Change, PlanError> {
        let mut fresh = Vec::with_capacity(step.changed().len());
        let mut outcome = Ok(());
        for name in step.changed() {
            let r = match step.plan().resection(name) {
                Ok(r) => r,
                Err(e) => {
                    outcome = Err(e);
                    break;
                }
            };
            let prev = self.states.remove(name);
            match self.compute(r, prev) {
                Ok(s) => fresh.push((name.clone(), s)),
                Err(e) => {
                    outcome = Err(e);
                    break;
                }
            }
        }
        let recorded = outcome.and_then(|()| self.history.record(step));
        let change = match recorded {
            Ok(change) => change,
            Err(e) => {
                self.refresh_all()?;
                return Err(e);
            }
        };
        for name in &change.removed {
            self.states.remove(name);
        }
        self.states.extend(fresh);
        Ok(change)
    }

    fn refresh_all(&mut self) -> Result<(), PlanError> {
        let plan = self.history.plan().clone();
        let mut states = BTreeMap::new();
        for r in &plan.resections {
            let prev = self.states.remove(&r.name);
            states.insert(r.name.clone(), self.compute(r, prev)?);
        }
        self.states = states;
        Ok(())
    }

    fn target_model(&mut self, target: &Target) -> Result<Arc<TargetModel>, PlanError> {
        let tumours = match self.selections.iter().find(|(t, _)| t == target) {
            Some((_, tumours)) => tumours.clone(),
            None => {
                let tumours = self.anatomy.select(target)?;
                if self.selections.len() >= MAX_SELECTIONS {
                    self.selections.clear();
                }
                self.selections.push((target.clone(), tumours.clone()));
                tumours
            }
        };
        if let Some(m) = self.targets.get(&tumours) {
            return Ok(Arc::clone(m));
        }
        let model = self.anatomy.target(&tumours)?;
        self.targets.insert(tumours, Arc::clone(&model));
        Ok(model)
    }

    /// Surface, inside levels, margins and verdict of one resection (reusing `prev`'s buffers):
    /// measured by its probe when the planner has a probe engine, else on the CPU.
    fn compute(
        &mut self,
        r: &Resection,
        prev: Option<ResectionState>,
    ) -> Result<ResectionState, PlanError> {
        let target = self.target_model(&r.target)?;
        let before = prev.as_ref().map_or(0, |s| s.surface.device_fallbacks());
        let (mut surface, mut inside, mut margins, mut memo, probe) = match prev {
            Some(mut s) if s.surface.fits(r) => {
                s.surface.set(r)?;
                // A probe measures against its own target.
                let probe = s.probe.filter(|_| Arc::ptr_eq(&s.target, &target));
                (s.surface, s.inside, s.margins, s.memo, probe)
            }
            _ => (
                LiveSurface::unevaluated(r, &self.compute.surfaces)?,
                Vec::new(),
                SurfaceMargins::default(),
                MarginMemo::default(),
                None,
            ),
        };
        let mut probe = match (probe, &self.compute.probes) {
            (Some(p), _) => Some(p),
            // Probes measure Bézier surfaces.
            (None, Some(engine)) if surface.device_fallbacks() == 0 && surface.net().is_some() => {
                match engine.make(&self.anatomy, &target) {
                    Ok(p) => Some(p),
                    Err(e) if e.is_device() => {
                        surface.fall_back(e);
                        None
                    }
                    Err(e) => return Err(e.into()),
                }
            }
            (None, _) => None,
        };
        let measured = match probe.as_deref_mut() {
            Some(p) => surface.evaluate_probed(p, &mut inside, &mut margins.distance)?,
            None => {
                surface.evaluate()?;
                false
            }
        };
        if surface.device_fallbacks() > before {
            self.device_fallbacks += 1;
            self.compute = ComputeEngine::cpu();
            probe = None;
        }
        let points = surface.points();
        let anatomy = &self.anatomy;
        if !measured {
            if points.len() < PARALLEL_INSIDE {
                inside.clear();
                inside.extend(points.iter().map(|p| anatomy.inside_level(p)));
            } else {
                points
                    .par_iter()
                    .map(|p| anatomy.inside_level(p))
                    .collect_into_vec(&mut inside);
            }
        }
        let settings = MarginSettings {
            margin_mm: r.margin_mm,
            band_mm: r.band_mm,
        };
        let [ru, rv] = surface.resolution();
        let oracle = Oracle {
            surface: &surface,
            anatomy,
        };
        let field = &target.field;
        let verdict = if measured {
            evaluate_exact_into(
                field,
                ru,
                rv,
                &points,
                &inside,
                &settings,
                &oracle,
                &mut margins,
            )
        } else {
            resecta_margin::evaluate_reusing(
                field,
                ru,
                rv,
                &points,
                &inside,
                &settings,
                &oracle,
                &mut memo,
                &mut margins,
            )
        }
        .map_err(|e| PlanError::resection(&r.name, format!("margins: {e}")))?;
        Ok(ResectionState {
            surface,
            target,
            inside,
            margins,
            verdict,
            memo,
            probe,
        })
    }

    /// The volumetry engine, once volumes were asked for (absent while a [`VolumeJob`] has it).
    pub fn volumetry(&self) -> Option<&Volumetry> {
        self.volumetry.as_ref()
    }

    fn volumetry_engine(&mut self) -> Result<&mut Volumetry, PlanError> {
        if self.volumetry.is_none() {
            let liver = match self.anatomy.take_liver_voxels() {
                Some(liver) => liver,
                None => LiverVoxels::new(self.anatomy.functional())?,
            };
            let mut volumetry = Volumetry::new(liver);
            // A device that cannot make one leaves the cuts to the CPU.
            let accelerator = self.compute.volumetry.as_ref().and_then(|f| f.make().ok());
            volumetry.set_accelerator(accelerator);
            self.volumetry = Some(volumetry);
        }
        self.volumetry.as_mut().ok_or(PlanError::EmptyLiver)
    }

    /// Every resection's surface and tumour points: what a volumetry needs of the plan.
    fn cut_inputs(&self) -> Result<Vec<CutInput>, PlanError> {
        self.plan()
            .resections
            .iter()
            .map(|r| Ok((r.shape()?, self.state(&r.name)?.target.centroids.clone())))
            .collect()
    }

    /// Runs `f` on the volumetry engine with every resection's surface and tumour points.
    fn run_cuts<T>(
        &mut self,
        f: impl FnOnce(&mut Volumetry, &[(&dyn CutSurface, &[Vec3])]) -> Result<T, VolumetryError>,
    ) -> Result<T, PlanError> {
        let inputs = self.cut_inputs()?;
        let engine = self.volumetry_engine()?;
        Ok(f(engine, &cut_refs(&inputs))?)
    }

    /// Resected and remnant volumes of every resection and of the plan.
    pub fn volumes(&mut self) -> Result<VolumeReport, PlanError> {
        let job = self.volume_job()?;
        let (engine, report) = job.run();
        self.restore_volumetry(engine);
        report
    }

    /// The volumetry of the current plan as a job that runs without the planner (so that edits
    /// go on meanwhile): it takes the volumetry engine along; give it back with
    /// [`Planner::restore_volumetry`] (until then a volumetry on the planner builds a new one).
    pub fn volume_job(&mut self) -> Result<VolumeJob, PlanError> {
        let inputs = self.cut_inputs()?;
        let metrics = self
            .plan()
            .resections
            .iter()
            .map(|r| Ok(resection_metrics(self.state(&r.name)?, r.margin_mm)))
            .collect::<Result<_, PlanError>>()?;
        let vascular = match self.anatomy.vascular() {
            Vascular::Ready(_) => Some((self.anatomy_shared(), self.cut_meshes()?)),
            Vascular::Absent | Vascular::Failed(_) => None,
        };
        self.volumetry_engine()?;
        let engine = self.volumetry.take().ok_or(PlanError::EmptyLiver)?;
        Ok(VolumeJob {
            engine,
            names: self
                .plan()
                .resections
                .iter()
                .map(|r| r.name.clone())
                .collect(),
            metrics,
            inputs,
            threshold: self.flr_threshold_pct,
            vascular,
            risk_unavailable: match self.anatomy.vascular() {
                Vascular::Failed(why) => Some(why.clone()),
                Vascular::Absent | Vascular::Ready(_) => None,
            },
        })
    }

    /// Every resection's surface mesh, for the risk analysis.
    pub fn cut_meshes(&self) -> Result<Vec<CutMesh>, PlanError> {
        self.plan()
            .resections
            .iter()
            .map(|r| {
                let s = self.state(&r.name)?;
                Ok(CutMesh {
                    name: r.name.clone(),
                    mesh: s.surface.mesh()?,
                    resolution: s.surface.resolution(),
                })
            })
            .collect()
    }

    /// The volumes of `reference` (a plan with the same roles) on this planner's anatomy: what
    /// [`VolumeReport::compare_with`] takes.
    pub fn reference_volumes(&self, reference: Plan) -> Result<VolumeReport, PlanError> {
        self.reference(reference)?.volumes()
    }

    /// A planner for `reference` (a plan with the same roles) on this planner's anatomy and
    /// engine.
    pub fn reference(&self, reference: Plan) -> Result<Planner, PlanError> {
        if reference.roles != self.plan().roles {
            return Err(PlanError::InvalidArgument(
                "the reference plan's roles differ from the plan's: its volumes would not be comparable"
                    .into(),
            ));
        }
        Planner::with_engine(self.anatomy_shared(), reference, self.compute.clone())
    }

    /// The plan's risk per voxel (cropped to the functional liver) with its report; `None`
    /// without vessel trees or while some cut is incomplete.
    pub fn risk_map(&mut self) -> Result<Option<RiskMap>, PlanError> {
        let anatomy = self.anatomy_shared();
        let Some(model) = anatomy.vascular().model() else {
            return Ok(None);
        };
        let meshes = self.cut_meshes()?;
        let (multi, resected) = self.run_cuts(|v, cuts| v.cuts_with_fractions(cuts))?;
        if !multi.complete {
            return Ok(None);
        }
        let (x, report) = vascular::assess(&anatomy, model, &meshes, &resected, multi.total_mm3)?;
        let regions = model.regions(&x);
        let offsets = self.volumetry_engine()?.liver().offsets();
        let territories = model.voxel_territories(VesselSystem::Portal, TERRITORY_GENERATION);
        Ok(Some(vascular::risk_map(
            anatomy.functional().grid(),
            &offsets,
            &resected,
            &regions,
            territories,
            report,
        )?))
    }

    /// Takes back the engine of a [`VolumeJob`] (one built for the same anatomy).
    pub fn restore_volumetry(&mut self, engine: Volumetry) {
        self.volumetry = Some(engine);
    }

    /// The resected regions as a label map on the liver grid: 0 outside the functional liver,
    /// 1 remnant, 2 + i resected by resection i.
    pub fn resected_labels(&mut self) -> Result<Volume<u8>, PlanError> {
        self.run_cuts(|v, cuts| v.resected_labels(cuts))
    }
}

/// A resection's surface and the tumour points on its resected side.
type CutInput = (Arc<dyn CutSurface>, Vec<Vec3>);

fn cut_refs(inputs: &[CutInput]) -> Vec<(&dyn CutSurface, &[Vec3])> {
    inputs
        .iter()
        .map(|(s, p)| (s.as_ref(), p.as_slice()))
        .collect()
}

/// A volumetry of one plan version, detached from its [`Planner`].
#[derive(Debug)]
pub struct VolumeJob {
    engine: Volumetry,
    names: Vec<String>,
    metrics: Vec<ResectionMetrics>,
    inputs: Vec<CutInput>,
    threshold: Real,
    /// The risk analysis' inputs: the anatomy (its trees and inside levels) and the meshes.
    vascular: Option<(Arc<Anatomy>, Vec<CutMesh>)>,
    /// Why the anatomy has no trees although its roles name vessels.
    risk_unavailable: Option<String>,
}

impl VolumeJob {
    /// The volumes, and the engine to give back to the planner.
    pub fn run(mut self) -> (Volumetry, Result<VolumeReport, PlanError>) {
        let cuts = cut_refs(&self.inputs);
        let report = match &self.vascular {
            None => self
                .engine
                .cuts(&cuts)
                .map(|multi| volume_report(&self.names, &self.metrics, &multi, self.threshold))
                .map_err(PlanError::from),
            Some((anatomy, meshes)) => self
                .engine
                .cuts_with_fractions(&cuts)
                .map_err(PlanError::from)
                .and_then(|(multi, resected)| {
                    let mut report =
                        volume_report(&self.names, &self.metrics, &multi, self.threshold);
                    if multi.complete
                        && let Some(model) = anatomy.vascular().model()
                    {
                        let (_, risk) =
                            vascular::assess(anatomy, model, meshes, &resected, multi.total_mm3)?;
                        report.flr_warning = Some(risk.functional_remnant_pct < self.threshold);
                        report.risk = Some(risk);
                    }
                    Ok(report)
                }),
        };
        let report = report.map(|mut r| {
            r.risk_unavailable = self.risk_unavailable.take();
            r
        });
        (self.engine, report)
    }
}

fn ml(mm3: Real) -> Real {
    mm3 / 1000.0
}

fn volume_report(
    names: &[String],
    metrics: &[ResectionMetrics],
    multi: &MultiCut,
    threshold: Real,
) -> VolumeReport {
    let total = multi.total_mm3;
    let pct = |v: Real| if total > 0.0 { 100.0 * v / total } else { 0.0 };
    let resections = names
        .iter()
        .zip(&multi.cuts)
        .zip(metrics)
        .map(|((name, c), m)| ResectionVolume {
            name: name.clone(),
            resected_ml: c.complete.then(|| ml(c.resected_mm3)),
            resected_pct: c.complete.then(|| pct(c.resected_mm3)),
            complete_cut: c.complete,
            incomplete: c.incomplete.clone(),
            metrics: *m,
        })
        .collect();
    let ok = multi.complete;
    VolumeReport {
        total_ml: ml(total),
        remnant_ml: ok.then(|| ml(multi.remnant_mm3)),
        remnant_pct: ok.then(|| pct(multi.remnant_mm3)),
        resected_ml: ok.then(|| ml(multi.resected_mm3)),
        flr_threshold_pct: threshold,
        flr_warning: ok.then(|| pct(multi.remnant_mm3) < threshold),
        complete: ok,
        resections,
        risk: None,
        risk_unavailable: None,
    }
}

/// A point as `[x, y, z]` (for reports).
pub fn point(p: &Vec3) -> [Real; 3] {
    arr(*p)
}

/// Counts of vertices per class (outside, safe, warning, violation).
pub fn class_counts(classes: &[MarginClass]) -> [usize; 4] {
    let mut c = [0usize; 4];
    for &k in classes {
        c[k as usize] += 1;
    }
    c
}
