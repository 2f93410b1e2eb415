//! GPU vs CPU (`resecta_poisson::CpuMultigrid`, and `resecta_recon::psr` on both fields) on the
//! test device (lavapipe in CI): sphere and ellipsoid livers on oblique anisotropic grids.

use resecta_geom::{RoleMap, Volume};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, generate};
use resecta_poisson::{
    CpuSobel, MultigridSolver, PoissonError, PoissonParams, PoissonSolver, SobelPass, System,
    SystemLevel, mask_box, oriented_points, oriented_points_with,
};
use resecta_recon::psr;

use super::{GpuMultigrid, GpuSobel, gpu_poisson_solver};
use crate::device::testing::context;

/// Largest |GPU − CPU| of the field (its values span about −0.5…1): rounding of f32 sweeps.
const FIELD_TOL: f32 = 2e-4;
/// The bounds: surfaces within 0.05 mm, volumes within 0.05 %.
const SURFACE_MM: f64 = 0.05;
const VOLUME_PCT: f64 = 0.05;

/// The liver mask (label 1) of one ellipsoid on an oblique anisotropic grid.
pub(crate) fn liver(radii: [f64; 3], dims: [usize; 3], spacing: [f64; 3]) -> Volume<bool> {
    let spec = PhantomSpec {
        grid: GridSpec::centred(
            dims,
            spacing,
            [1.0, -2.0, 3.0],
            Orientation::EulerDeg([12.0, -8.0, 20.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.3, -0.2, 0.1],
            radii,
            rotation: Orientation::EulerDeg([0.0, 10.0, 25.0]),
        }],
        tumors: vec![],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    };
    let p = generate(&spec).unwrap();
    resecta_recon::mask::select(&p.labels, &[1]).unwrap()
}

pub(crate) fn masks() -> [(&'static str, Volume<bool>); 2] {
    [
        ("sphere", liver([30.0; 3], [40, 36, 28], [1.9, 2.1, 2.7])),
        (
            "ellipsoid",
            liver([45.0, 32.0, 24.0], [56, 44, 26], [1.8, 1.6, 2.5]),
        ),
    ]
}

#[test]
fn fields_surfaces_and_volumes_match_the_cpu() {
    let Some(ctx) = context() else { return };
    let gpu = gpu_poisson_solver(&ctx);
    assert_eq!(gpu.backend(), "gpu");
    for (name, mask) in masks() {
        let pts = psr::points(&mask).unwrap();
        for depth in [5, 6] {
            let params = PoissonParams {
                depth,
                ..Default::default()
            };
            let c = psr::field(&pts, &params, &PoissonSolver::cpu()).unwrap();
            let g = psr::field(&pts, &params, &gpu).unwrap();
            assert_eq!((c.report.backend, g.report.backend), ("cpu", "gpu"));
            assert_eq!(c.values.len(), g.values.len());
            let worst = c
                .values
                .iter()
                .zip(&g.values)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            let (rc, rg) = (&c.report.residuals, &g.report.residuals);
            let rel = (rc[0] - rg[0]).abs() / rc[0];
            let mc = psr::field_surface(&c, &PoissonSolver::cpu()).unwrap();
            let mg = psr::field_surface(&g, &gpu).unwrap();
            let d = psr::surface_diff(&mc, &mg).unwrap();
            eprintln!(
                "{name} d={depth}: max |field| diff {worst:.2e}, iso {:.2e}, residuals cpu \
                 {rc:.3?} gpu {rg:.3?}, surface {:.2e} mm, volume {:.2e} %",
                (c.iso - g.iso).abs(),
                d.max_mm,
                d.volume_pct
            );
            assert!(
                worst <= FIELD_TOL,
                "{name} d={depth}: field differs by {worst}"
            );
            assert!(
                rel <= 1e-3,
                "{name} d={depth}: FMG residual {rc:?} vs {rg:?}"
            );
            assert!(rg.last().unwrap() <= &params.tolerance, "{rg:?}");
            assert!(
                mg.report().watertight,
                "{name} d={depth}: {:?}",
                mg.report()
            );
            assert!(d.max_mm <= SURFACE_MM, "{name} d={depth}: {d:?}");
            assert!(d.volume_pct <= VOLUME_PCT, "{name} d={depth}: {d:?}");
        }
    }
}

#[test]
fn a_malformed_system_is_a_typed_error() {
    let Some(ctx) = context() else { return };
    let system = System {
        levels: vec![SystemLevel {
            n: 3,
            lap: 1.0,
            b: vec![0.0; 5],
            diag: vec![0.0; 27],
        }],
    };
    let r = GpuMultigrid::new(&ctx).solve(system, &PoissonParams::default());
    assert!(
        matches!(r, Err(PoissonError::Backend { backend: "gpu", .. })),
        "{r:?}"
    );
    // The device is still usable afterwards.
    assert!(ctx.check().is_ok());
}

#[test]
fn oriented_points_equal_the_cpu() {
    let Some(ctx) = context() else { return };
    let gpu = GpuSobel::new(&ctx);
    for (name, mask) in masks() {
        let b = mask_box(&mask).unwrap();
        assert_eq!(
            gpu.gradients(&b).unwrap(),
            CpuSobel.gradients(&b).unwrap(),
            "{name}"
        );
        let c = oriented_points(&mask).unwrap();
        let g = oriented_points_with(&mask, &gpu).unwrap();
        eprintln!("{name}: {} points, identical", c.len());
        assert_eq!(c, g, "{name}");
    }
    // Slabs: a binding limit of a few planes splits the box; the result is the same.
    let (_, mask) = &masks()[1];
    let b = mask_box(mask).unwrap();
    let mut small = ctx.clone();
    let plane = (b.dims[0] * b.dims[1]) as u64;
    small.caps.limits.max_storage_buffer_binding_size = 4 * 5 * plane;
    assert_eq!(
        GpuSobel::new(&small).gradients(&b).unwrap(),
        CpuSobel.gradients(&b).unwrap()
    );
}

#[test]
fn gpu_solver_reconstructs_like_the_cpu() {
    let Some(ctx) = context() else { return };
    let (_, mask) = &masks()[1];
    let c = psr::reconstruct(mask, 6).unwrap();
    let g = psr::reconstruct_with(mask, 6, &gpu_poisson_solver(&ctx)).unwrap();
    assert_eq!(c.points, g.points);
    let d = psr::surface_diff(&c.mesh, &g.mesh).unwrap();
    assert!(
        d.max_mm <= SURFACE_MM && d.volume_pct <= VOLUME_PCT,
        "{d:?}"
    );
}
