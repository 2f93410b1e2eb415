//! The inside-level and margin kernels against their CPU twins through [`GpuProbe`]: levels
//! equal `Anatomy::inside_level` and distances `MarginField::nearest` to rounding, at voxel
//! centres, across cell and brick edges and beyond the grid of an oblique anisotropic phantom;
//! a probe chained onto a GPU surface measures in one round trip, with the same results.

use std::sync::Arc;

use resecta_bezier::{Outputs, Resolution, SurfaceEvaluator, SurfaceGrid, cpu_evaluator};
use resecta_geom::{Real, Vec3};
use resecta_plan::SampleProbe;

use super::GpuInsideField;
use crate::device::testing::context;
use crate::probe::GpuProbe;
use crate::surface::GpuSurface;
use crate::surface::tests::{planners, resection};

fn max_diff(a: &[Real], b: &[Real]) -> Real {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, Real::max)
}

#[test]
fn levels_and_distances_equal_the_cpu_twins_anywhere() {
    let Some(ctx) = context() else { return };
    let (cpu, _) = planners(resecta_plan::ComputeEngine::cpu());
    let anatomy = cpu.anatomy_shared();
    let target = Arc::clone(&cpu.state("r1").unwrap().target);
    let inside = Arc::new(GpuInsideField::new(&ctx, &anatomy.inside_layout()).unwrap());
    let mut probe = GpuProbe::new(inside, &target).unwrap();
    // A lattice over and beyond the liver, off the voxel lattice (the phantom's grid is about
    // ±65 × ±48 × ±45 mm), and points on the margin region's edge.
    let mut points = Vec::new();
    for (i, j, k) in
        (0..28).flat_map(|i| (0..24).flat_map(move |j| (0..30).map(move |k| (i, j, k))))
    {
        let [i, j, k] = [i, j, k].map(Real::from);
        points.push([6.07 * i - 84.9, 5.53 * j - 64.7, 4.11 * k - 59.8]);
    }
    let (mut levels, mut distances) = (Vec::new(), Vec::new());
    probe
        .measure_points(&points, &mut levels, &mut distances)
        .unwrap();
    let p3 = |p: &[Real; 3]| Vec3::new(p[0], p[1], p[2]);
    let want_levels: Vec<Real> = points
        .iter()
        .map(|p| anatomy.inside_level(&p3(p)))
        .collect();
    let want_distances: Vec<Real> = points
        .iter()
        .map(|p| target.field.nearest(&p3(p)).distance)
        .collect();
    let (dl, dd) = (
        max_diff(&levels, &want_levels),
        max_diff(&distances, &want_distances),
    );
    let inside = levels.iter().filter(|&&l| l > 0.0).count();
    eprintln!(
        "{} points, {inside} inside: levels {dl:.1e}, distances {dd:.1e} mm",
        points.len()
    );
    assert!(inside > 1000 && inside < points.len() - 1000, "{inside}");
    assert!(dl <= 1e-12 && dd <= 1e-9, "levels {dl:e} distances {dd:e}");
    // The same signs: the inside/outside decisions of the classes.
    assert!(
        levels
            .iter()
            .zip(&want_levels)
            .all(|(a, b)| (*a > 0.0) == (*b > 0.0))
    );
    // No points: nothing measured, no device work.
    probe
        .measure_points(&[], &mut levels, &mut distances)
        .unwrap();
    assert!(levels.is_empty() && distances.is_empty());
}

#[test]
fn a_probe_chained_onto_a_gpu_surface_measures_in_one_round_trip() {
    let Some(ctx) = context() else { return };
    let (cpu, _) = planners(resecta_plan::ComputeEngine::cpu());
    let anatomy = cpu.anatomy_shared();
    let target = Arc::clone(&cpu.state("r1").unwrap().target);
    let inside = Arc::new(GpuInsideField::new(&ctx, &anatomy.inside_layout()).unwrap());
    let mut probe = GpuProbe::new(Arc::clone(&inside), &target).unwrap();
    let res = Resolution::new(61, 47).unwrap();
    let net = resection([61, 47]).net().unwrap();
    let mut gpu = GpuSurface::new(&ctx, net.clone(), res).unwrap();
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    let (mut levels, mut distances) = (Vec::new(), Vec::new());
    for step in 0..3 {
        gpu.set_control_point(2, 1, [10.0 + 3.0 * step as Real, 0.0, -20.0])
            .unwrap();
        probe
            .measure(&mut gpu, &mut grid, &mut levels, &mut distances)
            .unwrap();
        let (mut l2, mut d2) = (Vec::new(), Vec::new());
        probe
            .measure_points(grid.points(), &mut l2, &mut d2)
            .unwrap();
        assert_eq!((levels.len(), distances.len()), (res.len(), res.len()));
        assert!(max_diff(&levels, &l2) == 0.0 && max_diff(&distances, &d2) == 0.0);
    }
    assert_eq!(probe.round_trips(), (3, 0));
    // A CPU surface: evaluated first, its points uploaded; the same answers.
    let mut cpu_surface = cpu_evaluator(net, res);
    cpu_surface
        .set_control_point(2, 1, [16.0, 0.0, -20.0])
        .unwrap();
    let mut cpu_grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    let (mut l3, mut d3) = (Vec::new(), Vec::new());
    probe
        .measure(cpu_surface.as_mut(), &mut cpu_grid, &mut l3, &mut d3)
        .unwrap();
    assert_eq!(probe.round_trips(), (3, 1));
    assert!(max_diff(&levels, &l3) <= 1e-12 && max_diff(&distances, &d3) <= 1e-9);
}
