//! The planner's surfaces on the GPU: [`GpuSurface`] implements
//! `resecta_bezier::SurfaceEvaluator` over [`GpuMle`] (points and unit normals, one read-back
//! per evaluation, the net resident), and [`gpu_engine`] is the `SurfaceEngine` a planner is
//! given. f64 where the device has `SHADER_F64` (within 1e-13 mm and 1e-12 in normals of the
//! CPU on lavapipe), f32 otherwise (widened on the host; within 2e-5 mm of the f64 CPU on a
//! ±50 mm net and 4e-5 in normals, except next to collapsed corners, where f32's own √ε
//! thresholds decide: see the kernel tests). Device failures surface as
//! `BezierError::Device`, on which the planner's surfaces move to the CPU.

use resecta_bezier::{
    BezierError, ControlNet, Outputs, P3, Resolution, SurfaceEngine, SurfaceEvaluator, SurfaceGrid,
};

use crate::device::{GpuContext, GpuError};
use crate::kernels::bezier::GpuMle;

/// Invalid input stays itself; whatever the device cannot do (lost, out of limits, no f64,
/// a kernel that does not compile) is a device error, which the CPU evaluator takes over.
impl From<GpuError> for BezierError {
    fn from(e: GpuError) -> Self {
        match e {
            GpuError::Bezier(e) => e,
            e @ (GpuError::NoAdapter { .. }
            | GpuError::RequestDevice(_)
            | GpuError::NoF64
            | GpuError::TooLarge { .. }
            | GpuError::Pipeline(_)
            | GpuError::ReadBack(_)
            | GpuError::DeviceLost(_)
            // Not raised by surfaces.
            | GpuError::Margin(_)) => BezierError::Device(e.to_string()),
        }
    }
}

/// A surface evaluated by [`GpuMle`] in the device's best precision.
#[derive(Debug)]
pub enum GpuSurface {
    /// f64 kernels (`SHADER_F64`).
    F64(Box<GpuMle<f64>>),
    /// f32 kernels; `net` is the f64 net the planner set, `grid` the f32 scratch.
    F32 {
        /// The evaluator.
        mle: Box<GpuMle<f32>>,
        /// The net as set (f64).
        net: ControlNet<f64>,
        /// f32 results before widening.
        grid: SurfaceGrid<f32>,
    },
}

impl GpuSurface {
    /// f64 when `ctx` has `SHADER_F64`, f32 otherwise.
    pub fn new(
        ctx: &GpuContext,
        net: ControlNet<f64>,
        resolution: Resolution,
    ) -> Result<Self, GpuError> {
        if ctx.caps.f64 {
            Ok(Self::F64(Box::new(GpuMle::new(ctx, net, resolution)?)))
        } else {
            Self::new_f32(ctx, net, resolution)
        }
    }

    /// f32 kernels whatever the device offers.
    pub fn new_f32(
        ctx: &GpuContext,
        net: ControlNet<f64>,
        resolution: Resolution,
    ) -> Result<Self, GpuError> {
        Ok(Self::F32 {
            mle: Box::new(GpuMle::new(ctx, net.cast(), resolution)?),
            net,
            grid: SurfaceGrid::zeroed(resolution, Outputs::Normals),
        })
    }

    /// `"f64"` or `"f32"`.
    pub fn precision(&self) -> &'static str {
        match self {
            Self::F64(_) => "f64",
            Self::F32 { .. } => "f32",
        }
    }

    /// Control-point bytes uploaded so far.
    pub fn uploaded_bytes(&self) -> u64 {
        match self {
            Self::F64(g) => g.uploaded_bytes(),
            Self::F32 { mle, .. } => mle.uploaded_bytes(),
        }
    }
}

fn narrow(p: P3<f64>) -> P3<f32> {
    p.map(|c| c as f32)
}

impl SurfaceEvaluator for GpuSurface {
    fn backend(&self) -> &'static str {
        "wgpu"
    }
    fn net(&self) -> &ControlNet<f64> {
        match self {
            Self::F64(g) => g.net(),
            Self::F32 { net, .. } => net,
        }
    }
    fn resolution(&self) -> Resolution {
        match self {
            Self::F64(g) => g.resolution(),
            Self::F32 { mle, .. } => mle.resolution(),
        }
    }
    fn set_net(&mut self, new: ControlNet<f64>) {
        match self {
            Self::F64(g) => g.set_net(new),
            Self::F32 { mle, net, .. } => {
                mle.set_net(new.cast());
                *net = new;
            }
        }
    }
    fn set_control_points(&mut self, points: &[P3<f64>]) -> Result<(), BezierError> {
        match self {
            Self::F64(g) => g.set_control_points(points),
            Self::F32 { mle, net, .. } => {
                net.set_points(points)?;
                let narrow: Vec<P3<f32>> = points.iter().copied().map(narrow).collect();
                mle.set_control_points(&narrow)
            }
        }
    }
    fn set_control_point(&mut self, i: usize, j: usize, p: P3<f64>) -> Result<(), BezierError> {
        match self {
            Self::F64(g) => g.set_control_point(i, j, p),
            Self::F32 { mle, net, .. } => {
                net.set(i, j, p)?;
                mle.set_control_point(i, j, narrow(p))
            }
        }
    }
    fn set_resolution(&mut self, resolution: Resolution) {
        match self {
            Self::F64(g) => g.set_resolution(resolution),
            Self::F32 { mle, grid, .. } => {
                mle.set_resolution(resolution);
                if grid.resolution() != resolution {
                    *grid = SurfaceGrid::zeroed(resolution, Outputs::Normals);
                }
            }
        }
    }
    fn as_any_mut(&mut self) -> Option<&mut dyn std::any::Any> {
        Some(self)
    }
    fn evaluate_into(&mut self, out: &mut SurfaceGrid<f64>) -> Result<(), BezierError> {
        match self {
            Self::F64(g) => Ok(g.evaluate_normals_into(out)?),
            Self::F32 { mle, grid, .. } => {
                if out.resolution() != grid.resolution() || out.outputs() != Outputs::Normals {
                    return Err(BezierError::MissingOutput("normals at this resolution"));
                }
                mle.evaluate_normals_into(grid)?;
                let (p, du, dv, n) = grid.parts_mut();
                let (q, eu, ev, m) = out.parts_mut();
                let srcs = [Some(p), du, dv, n];
                for (src, dst) in srcs.into_iter().zip([Some(q), eu, ev, m]) {
                    if let (Some(src), Some(dst)) = (src, dst) {
                        for (d, s) in dst.iter_mut().zip(src.iter()) {
                            *d = s.map(f64::from);
                        }
                    }
                }
                Ok(())
            }
        }
    }
}

/// The engine of [`GpuSurface`]s on `ctx` (backend `"wgpu"`).
pub fn gpu_engine(ctx: &GpuContext) -> SurfaceEngine {
    let ctx = ctx.clone();
    SurfaceEngine::new("wgpu", move |net, res| {
        Ok(Box::new(GpuSurface::new(&ctx, net, res)?) as Box<dyn SurfaceEvaluator>)
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use std::sync::Arc;

    use resecta_geom::{Real, RoleMap};
    use resecta_margin::FAR_TOLERANCE_MM;
    use resecta_phantom::{
        EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate,
    };
    use resecta_plan::{Anatomy, ComputeEngine, Plan, PlanEvent, Planner, Resection};

    use super::*;
    use crate::device::testing::context;
    use crate::probe::gpu_compute_engine;

    pub(crate) fn anatomy() -> (Arc<Anatomy>, RoleMap) {
        let spec = PhantomSpec {
            grid: GridSpec::centred(
                [80, 64, 52],
                [1.6, 1.5, 1.7],
                [0.0, 0.0, 0.0],
                Orientation::EulerDeg([4.0, -3.0, 7.0]),
            ),
            liver: vec![EllipsoidSpec {
                center: [0.0, 0.0, 0.0],
                radii: [55.0, 42.0, 38.0],
                rotation: Orientation::default(),
            }],
            tumors: vec![SphereSpec {
                center: [22.0, 4.0, -3.0],
                radius: 9.0,
            }],
            vessels: vec![],
            roles: RoleMap::default(),
            max_voxels: None,
            truth_tolerance_mm: 0.05,
        };
        let p = generate(&spec).unwrap();
        (
            Arc::new(Anatomy::new(&p.labels, &spec.roles).unwrap()),
            spec.roles,
        )
    }

    /// A 5×4 resection across x = 8 mm, slightly bent, at `res`.
    pub(crate) fn resection(res: [usize; 2]) -> Resection {
        let pts = (0..20)
            .map(|k| {
                let (u, v) = ((k / 4) as Real / 4.0, (k % 4) as Real / 3.0);
                [
                    8.0 + 6.0 * (u - 0.5).powi(2),
                    -65.0 + 130.0 * u,
                    -60.0 + 120.0 * v,
                ]
            })
            .collect();
        let mut r = Resection::new("r1", [5, 4], pts);
        r.resolution = res;
        r
    }

    /// The GPU planner's resection "r1" against the CPU's: surfaces to rounding; with probes
    /// (`probed`), inside levels to rounding, exact distances (the CPU's within its tolerances),
    /// the same classes and minimum, areas within 1 % (far
    /// samples' tolerant CPU distances move the clipped lines of the cells next to them).
    fn assert_same(gpu: &Planner, cpu: &Planner, probed: bool, what: &str) {
        let (g, c) = (gpu.state("r1").unwrap(), cpu.state("r1").unwrap());
        assert_eq!(g.surface.backend(), "wgpu", "{what}");
        assert_eq!(g.surface.device_fallbacks(), 0, "{what}");
        let (gg, cg) = (g.surface.grid(), c.surface.grid());
        let diff = |a: &[P3<f64>], b: &[P3<f64>]| {
            a.iter()
                .zip(b)
                .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
                .fold(0.0, f64::max)
        };
        let dp = diff(gg.points(), cg.points());
        let dn = diff(gg.normals().unwrap(), cg.normals().unwrap());
        assert!(
            dp <= 1e-9 && dn <= 1e-9,
            "{what}: points {dp:e} normals {dn:e}"
        );
        assert_eq!(g.margins.class, c.margins.class, "{what}");
        let levels = g
            .inside
            .iter()
            .zip(&c.inside)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(levels <= 1e-12, "{what}: inside levels {levels:e}");
        let (mut above, mut below) = (0.0f64, 0.0f64);
        for (a, b) in g.margins.distance.iter().zip(&c.margins.distance) {
            (above, below) = (above.max(a - b), below.max(b - a));
        }
        // Kept distances of a drag may also lie below the exact ones (by what a sample moved).
        let far = if probed { FAR_TOLERANCE_MM } else { 1e-9 };
        assert!(above <= far && below <= far, "{what}: {above:e} {below:e}");
        let (gv, cv) = (&g.verdict, &c.verdict);
        let (gm, cm) = (gv.min_margin_mm.unwrap(), cv.min_margin_mm.unwrap());
        assert!((gm - cm).abs() <= 1e-6, "{what}: min margin {gm} vs {cm}");
        assert_eq!(gv.violation, cv.violation, "{what}");
        let area = if probed { 1e-2 } else { 1e-6 };
        for (a, b) in [
            (gv.violating_area_mm2, cv.violating_area_mm2),
            (gv.warning_area_mm2, cv.warning_area_mm2),
            (gv.inside_area_mm2, cv.inside_area_mm2),
        ] {
            assert!(
                (a - b).abs() <= area * b.max(1.0),
                "{what}: area {a} vs {b}"
            );
        }
        eprintln!(
            "{what}: points {dp:.1e} normals {dn:.1e} levels {levels:.1e} distances +{above:.1e} \
             -{below:.1e} min margin {gm:.6} mm"
        );
    }

    /// The phantom's plan with one 40×40 resection, planned by `engine` and on the CPU.
    pub(crate) fn planners(engine: impl Into<ComputeEngine>) -> (Planner, Planner) {
        let (anatomy, roles) = anatomy();
        let mut plan = Plan::new(roles);
        plan.apply(&PlanEvent::AddResection {
            resection: resection([40, 40]),
        })
        .unwrap();
        let gpu = Planner::with_engine(Arc::clone(&anatomy), plan.clone(), engine).unwrap();
        (gpu, Planner::new(anatomy, plan).unwrap())
    }

    #[test]
    fn a_planner_on_the_gpu_plans_as_the_cpu_one() {
        let Some(ctx) = context() else { return };
        plans_as_the_cpu(gpu_engine(&ctx).into(), false);
    }

    #[test]
    fn a_planner_measuring_on_the_gpu_plans_as_the_cpu_one() {
        let Some(ctx) = context() else { return };
        let engine = gpu_compute_engine(&ctx);
        assert_eq!(engine.probes.as_ref().map(|p| p.backend()), Some("wgpu"));
        plans_as_the_cpu(engine, true);
    }

    fn plans_as_the_cpu(engine: ComputeEngine, probed: bool) {
        let (mut gpu, mut cpu) = planners(engine);
        assert_eq!(gpu.compute_engine().backend(), "wgpu");
        let assert_same = |gpu: &Planner, cpu: &Planner, what: &str| {
            assert_same(gpu, cpu, probed, what);
        };
        assert_same(&gpu, &cpu, "initial");
        let edits = [
            PlanEvent::SetControlPoint {
                name: "r1".into(),
                i: 2,
                j: 1,
                point: [16.0, 0.0, -20.0],
            },
            PlanEvent::SetControlPoint {
                name: "r1".into(),
                i: 2,
                j: 2,
                point: [15.0, 0.0, 20.0],
            },
            PlanEvent::Translate {
                name: "r1".into(),
                delta: [-2.0, 1.0, 0.5],
            },
            PlanEvent::Rotate {
                name: "r1".into(),
                axis: [0.0, 0.0, 1.0],
                angle_deg: 6.0,
                centre: None,
            },
        ];
        for (k, e) in edits.into_iter().enumerate() {
            gpu.edit(e.clone()).unwrap();
            cpu.edit(e).unwrap();
            assert_same(&gpu, &cpu, &format!("edit {k}"));
        }
        gpu.undo().unwrap();
        cpu.undo().unwrap();
        assert_same(&gpu, &cpu, "undo");
        // A resolution change on the same evaluator.
        let e = PlanEvent::SetResolution {
            name: "r1".into(),
            resolution: [57, 33],
        };
        gpu.edit(e.clone()).unwrap();
        cpu.edit(e).unwrap();
        assert_same(&gpu, &cpu, "57x33");
        // Volumes: the band and side components on the GPU with probes, equal to the CPU's.
        let (gv, cv) = (gpu.volumes().unwrap(), cpu.volumes().unwrap());
        let v = gpu.volumetry().unwrap();
        assert_eq!(v.is_accelerated(), probed);
        assert_eq!(v.accelerator_fallbacks().0, 0);
        assert!(gv.complete && cv.complete);
        let (g, c) = (gv.resected_ml.unwrap(), cv.resected_ml.unwrap());
        assert!((g - c).abs() <= 1e-9 * c, "resected {g} vs {c} ml");
        assert_eq!(gv.remnant_ml, cv.remnant_ml);
    }

    fn res40() -> Resolution {
        Resolution::new(40, 40).unwrap()
    }

    #[test]
    fn a_lost_device_moves_the_planner_to_the_cpu_and_the_edit_succeeds() {
        if context().is_none() {
            return;
        }
        // A device of its own: destroyed below.
        let ctx = GpuContext::new().unwrap();
        let (mut gpu, mut cpu) = planners(gpu_compute_engine(&ctx));
        ctx.device.destroy();
        let e = PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 2,
            j: 1,
            point: [16.0, 0.0, -20.0],
        };
        gpu.edit(e.clone()).unwrap();
        cpu.edit(e).unwrap();
        let (g, c) = (gpu.state("r1").unwrap(), cpu.state("r1").unwrap());
        assert_eq!(g.surface.backend(), "cpu");
        assert_eq!(gpu.device_fallbacks(), 1);
        assert_eq!(gpu.compute_engine().backend(), "cpu");
        assert!(gpu.compute_engine().probes.is_none());
        eprintln!("lost: {}", g.surface.device_error().unwrap());
        assert_eq!(g.surface.grid(), c.surface.grid());
        // Measured afresh on the CPU (no distances kept from the GPU's measurements).
        assert_eq!(g.margins.class, c.margins.class);
        assert_eq!(g.verdict.min_margin_mm, c.verdict.min_margin_mm);
        // The context remembers the failure (wgpu's errors were recorded, not panicked on).
        let err = ctx.check().unwrap_err();
        assert!(matches!(err, GpuError::DeviceLost(_)), "{err}");
        // A new surface on it fails as a device error too (made or evaluated).
        let mut grid = SurfaceGrid::zeroed(res40(), Outputs::Normals);
        let e = GpuSurface::new(&ctx, resection([40, 40]).net().unwrap(), res40())
            .map_err(BezierError::from)
            .and_then(|mut s| s.evaluate_into(&mut grid))
            .unwrap_err();
        assert!(e.is_device(), "{e}");
    }

    #[test]
    fn the_f32_surface_stays_within_its_tolerance_and_widens_to_f64() {
        let Some(ctx) = context() else { return };
        let net = resection([40, 40]).net().unwrap();
        let res = Resolution::new(40, 40).unwrap();
        let mut s = GpuSurface::new_f32(&ctx, net.clone(), res).unwrap();
        assert_eq!((s.precision(), s.backend()), ("f32", "wgpu"));
        let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
        s.set_control_point(1, 1, [12.0, -30.0, -20.0]).unwrap();
        s.evaluate_into(&mut grid).unwrap();
        let mut cpu = resecta_bezier::cpu_evaluator(net, res);
        cpu.set_control_point(1, 1, [12.0, -30.0, -20.0]).unwrap();
        let mut want = SurfaceGrid::zeroed(res, Outputs::Normals);
        cpu.evaluate_into(&mut want).unwrap();
        let max = |a: &[P3<f64>], b: &[P3<f64>]| {
            a.iter()
                .zip(b)
                .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
                .fold(0.0, f64::max)
        };
        let dp = max(grid.points(), want.points());
        let dn = max(grid.normals().unwrap(), want.normals().unwrap());
        eprintln!("f32 surface: points {dp:e} mm, normals {dn:e}");
        assert!(
            dp <= 2e-5 * 65.0 && dn <= 2e-3,
            "points {dp:e} normals {dn:e}"
        );
        assert_eq!(s.net().get(1, 1), Some([12.0, -30.0, -20.0]));
    }

    #[test]
    fn gpu_errors_map_to_device_errors_and_input_errors_stay_themselves() {
        let e: BezierError = GpuError::ReadBack("device lost".into()).into();
        assert!(e.is_device(), "{e}");
        let e: BezierError = GpuError::Bezier(BezierError::NonFinite { index: 3 }).into();
        assert_eq!(e, BezierError::NonFinite { index: 3 });
    }
}
