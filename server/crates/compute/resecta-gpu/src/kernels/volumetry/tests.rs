//! GPU vs CPU (`resecta_volumetry::Volumetry` without an accelerator) on phantoms: volumes,
//! incomplete cuts, unions and label maps, on the test device (lavapipe in CI).

use resecta_bezier::ControlNet;
use resecta_geom::{CutSurface, Real, RoleMap, Vec3, Volume};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_volumetry::{CutAccelerator, CutResult, IncompleteCut, LiverVoxels, Volumetry};

use super::{ENTRIES, GpuVolumetry, SOURCE};
use crate::device::testing::context;

#[test]
fn wgsl_validates_and_each_entry_point_binds_what_it_uses() {
    use wgpu::naga;
    let module = naga::front::wgsl::parse_str(SOURCE)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(SOURCE)));
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::FLOAT64,
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{e:?}"));
    assert_eq!(module.entry_points.len(), ENTRIES.len());
    for (k, ep) in module.entry_points.iter().enumerate() {
        let uses = info.get_entry_point(k);
        let mut bound: Vec<u32> = module
            .global_variables
            .iter()
            .filter(|(h, _)| !uses[*h].is_empty())
            .filter_map(|(_, g)| g.binding.as_ref().map(|b| b.binding))
            .collect();
        bound.sort_unstable();
        let (_, want) = ENTRIES.iter().find(|(n, _)| *n == ep.name).unwrap();
        assert_eq!(bound, *want, "{}", ep.name);
    }
}

/// Largest relative difference of GPU and CPU volumes allowed (summation order only; measured
/// 0 on lavapipe).
const REL: f64 = 1e-9;

fn ellipsoid(center: [Real; 3], radii: [Real; 3], yaw: Real) -> EllipsoidSpec {
    EllipsoidSpec {
        center,
        radii,
        rotation: Orientation::EulerDeg([0.0, 0.0, yaw]),
    }
}

/// The functional liver (parenchyma label) of a phantom on an oblique anisotropic grid.
fn liver(livers: Vec<EllipsoidSpec>, tumors: Vec<SphereSpec>) -> Volume<bool> {
    let spec = PhantomSpec {
        grid: GridSpec::centred(
            [72, 72, 40],
            [1.6, 1.3, 2.2],
            [1.0, -2.0, 3.0],
            Orientation::EulerDeg([3.0, -2.0, 6.0]),
        ),
        liver: livers,
        tumors,
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.5,
    };
    let labels = generate(&spec).unwrap().labels;
    let data = labels.data().iter().map(|&l| l == 1).collect();
    Volume::from_vec(labels.grid().clone(), data).unwrap()
}

/// An ellipsoid liver with two tumours and a detached island.
fn tumour_liver() -> Volume<bool> {
    liver(
        vec![
            ellipsoid([0.0, 0.0, 0.0], [40.0, 30.0, 25.0], 20.0),
            ellipsoid([-40.0, 32.0, 22.0], [5.0, 4.0, 4.0], 0.0),
        ],
        vec![
            SphereSpec {
                center: [20.0, 5.0, 0.0],
                radius: 8.0,
            },
            SphereSpec {
                center: [-18.0, -6.0, 4.0],
                radius: 5.0,
            },
        ],
    )
}

/// A square ring of four arms.
fn ring_liver() -> Volume<bool> {
    liver(
        vec![
            ellipsoid([0.0, 25.0, 0.0], [36.0, 6.0, 8.0], 0.0),
            ellipsoid([0.0, -25.0, 0.0], [36.0, 6.0, 8.0], 0.0),
            ellipsoid([30.0, 0.0, 0.0], [6.0, 31.0, 8.0], 0.0),
            ellipsoid([-30.0, 0.0, 0.0], [6.0, 31.0, 8.0], 0.0),
        ],
        vec![],
    )
}

fn planar(o: [Real; 3], u: [Real; 3], v: [Real; 3]) -> ControlNet<Real> {
    ControlNet::planar(4, 4, o, u, v).unwrap()
}

fn bent() -> ControlNet<Real> {
    ControlNet::from_fn(4, 4, |i, j| {
        let (u, v) = (i as Real / 3.0, j as Real / 3.0);
        [
            4.0 + 14.0 * (u - 0.5) * (v - 0.4),
            -60.0 + 120.0 * u,
            -60.0 + 120.0 * v,
        ]
    })
    .unwrap()
}

/// Asserts equal results; returns the relative volume difference.
fn same(cpu: &CutResult, gpu: &CutResult, what: &str) -> f64 {
    assert_eq!(cpu.incomplete, gpu.incomplete, "{what}");
    assert_eq!(cpu.complete, gpu.complete, "{what}");
    assert_eq!(cpu.band_voxels, gpu.band_voxels, "{what}");
    assert_eq!(cpu.samples, gpu.samples, "{what}");
    let rel = relative(cpu.resected_mm3, gpu.resected_mm3);
    eprintln!(
        "{what}: cpu {:.6} ml, gpu {:.6} ml, rel {rel:.1e}, {} band voxels, {:?}",
        cpu.resected_mm3 / 1e3,
        gpu.resected_mm3 / 1e3,
        gpu.band_voxels,
        gpu.incomplete
    );
    assert!(rel <= REL, "{what}: rel {rel:e}");
    rel
}

fn relative(a: f64, b: f64) -> f64 {
    if a == b {
        0.0
    } else {
        (a - b).abs() / a.abs().max(b.abs())
    }
}

/// The CPU engine and one with the GPU accelerator, on the same liver; `None` without an adapter
/// or f64.
/// `tiny`: output capacities of one voxel, so that every cut overflows and retries.
fn engines(m: &Volume<bool>, tiny: bool) -> Option<(Volumetry, Volumetry)> {
    let ctx = context()?;
    if !ctx.caps.f64 {
        eprintln!("SKIP: the device lacks SHADER_F64 ({})", ctx.info.name);
        return None;
    }
    let gpu: Box<dyn CutAccelerator> = if tiny {
        let mut g = GpuVolumetry::new(&ctx).unwrap();
        (g.band_cap, g.roots_cap) = (1, 1);
        Box::new(g)
    } else {
        let factory = super::gpu_volumetry(&ctx);
        assert_eq!(factory.backend(), "wgpu");
        factory.make().unwrap()
    };
    Some((
        Volumetry::new(LiverVoxels::new(m).unwrap()),
        Volumetry::new(LiverVoxels::new(m).unwrap()).with_accelerator(gpu),
    ))
}

#[test]
fn phantom_cuts_unions_and_labels_equal_the_cpu() {
    let m = tumour_liver();
    let Some((mut cpu, mut gpu)) = engines(&m, false) else {
        return;
    };
    let t1 = vec![Vec3::new(20.0, 5.0, 0.0)];
    let t2 = vec![Vec3::new(-18.0, -6.0, 4.0)];
    let cases = [
        (
            "oblique plane",
            planar([8.0, -60.0, -60.0], [-6.0, 120.0, 0.0], [5.0, 0.0, 120.0]),
            &t1,
        ),
        ("curved", bent(), &t1),
        (
            "ends inside",
            planar([4.0, -10.0, -10.0], [0.0, 20.0, 0.0], [0.0, 0.0, 20.0]),
            &t1,
        ),
        (
            "misses",
            planar([70.0, -60.0, -60.0], [0.0, 120.0, 0.0], [0.0, 0.0, 120.0]),
            &t1,
        ),
        (
            "second tumour",
            planar([-8.0, -60.0, -60.0], [0.0, 120.0, 0.0], [-3.0, 0.0, 120.0]),
            &t2,
        ),
    ];
    let mut kinds = Vec::new();
    for (what, net, t) in &cases {
        let (c, g) = (cpu.cut(net, t).unwrap(), gpu.cut(net, t).unwrap());
        same(&c, &g, what);
        kinds.push(g.incomplete.clone());
    }
    assert!(kinds[0].is_none() && kinds[1].is_none() && kinds[4].is_none());
    assert!(matches!(
        kinds[2],
        Some(IncompleteCut::EdgeInsideLiver { .. })
    ));
    assert_eq!(kinds[3], Some(IncompleteCut::MissesLiver));
    // Two cuts: the union, and the label map of all five.
    let two: [(&dyn CutSurface, &[Vec3]); 2] =
        [(&cases[0].1, t1.as_slice()), (&cases[4].1, t2.as_slice())];
    let (c, g) = (cpu.cuts(&two).unwrap(), gpu.cuts(&two).unwrap());
    assert_eq!(c.complete, g.complete);
    for (a, b) in c.cuts.iter().zip(&g.cuts) {
        same(a, b, "two cuts, each");
    }
    let rel = relative(c.resected_mm3, g.resected_mm3);
    eprintln!(
        "two cuts: union {:.6} ml, rel {rel:.1e}",
        g.resected_mm3 / 1e3
    );
    assert!(rel <= REL && relative(c.remnant_mm3, g.remnant_mm3) <= REL);
    let all: Vec<(&dyn CutSurface, &[Vec3])> = cases
        .iter()
        .map(|(_, n, t)| (n as &dyn CutSurface, t.as_slice()))
        .collect();
    assert_eq!(
        cpu.resected_labels(&all).unwrap().data(),
        gpu.resected_labels(&all).unwrap().data(),
        "label maps"
    );
    assert_eq!(
        gpu.accelerator_fallbacks().0,
        0,
        "{:?}",
        gpu.accelerator_fallbacks()
    );
}

#[test]
fn a_leaking_ring_equals_the_cpu_with_outputs_grown_on_overflow() {
    let m = ring_liver();
    let Some((mut cpu, mut gpu)) = engines(&m, true) else {
        return;
    };
    let t = [Vec3::new(30.0, 6.0, 0.0)];
    let one_arm = planar([15.0, 0.0, -15.0], [30.0, 0.0, 0.0], [0.0, 0.0, 30.0]);
    let (c, g) = (
        cpu.cut(&one_arm, &t).unwrap(),
        gpu.cut(&one_arm, &t).unwrap(),
    );
    same(&c, &g, "one arm");
    assert_eq!(g.incomplete, Some(IncompleteCut::Leak));
    let both = planar([-50.0, 0.0, -15.0], [100.0, 0.0, 0.0], [0.0, 0.0, 30.0]);
    let (c, g) = (cpu.cut(&both, &t).unwrap(), gpu.cut(&both, &t).unwrap());
    same(&c, &g, "both arms");
    assert!(g.complete);
    assert_eq!(
        gpu.accelerator_fallbacks().0,
        0,
        "{:?}",
        gpu.accelerator_fallbacks()
    );
}

#[test]
fn a_lost_device_moves_the_cut_to_the_cpu() {
    if context().is_none_or(|c| !c.caps.f64) {
        return;
    }
    // A device of its own: destroyed below.
    let ctx = crate::GpuContext::new().unwrap();
    let m = ring_liver();
    let mut cpu = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let mut gpu = Volumetry::new(LiverVoxels::new(&m).unwrap())
        .with_accelerator(Box::new(GpuVolumetry::new(&ctx).unwrap()));
    let t = [Vec3::new(30.0, 6.0, 0.0)];
    let net = planar([-50.0, 0.0, -15.0], [100.0, 0.0, 0.0], [0.0, 0.0, 30.0]);
    let want = cpu.cut(&net, &t).unwrap();
    assert_eq!(gpu.cut(&net, &t).unwrap(), want);
    assert_eq!(gpu.accelerator_fallbacks().0, 0);
    ctx.device.destroy();
    assert_eq!(gpu.cut(&net, &t).unwrap(), want);
    let (n, e) = gpu.accelerator_fallbacks();
    eprintln!("fallback: {e:?}");
    assert_eq!(n, 1);
    assert!(e.is_some_and(|e| e.0.contains("device failed")), "{e:?}");
}

#[test]
fn a_speckled_liver_of_many_components_equals_the_cpu() {
    // The tumour phantom with 45 % of its voxels dropped at random: hundreds of components
    // (isolated voxels alone), islands on both sides of the cut.
    let m = tumour_liver();
    let mut rng = crate::kernels::bezier::tests::Rng(11);
    let data = m.data().iter().map(|&b| b && rng.unit() > 0.45).collect();
    let m = Volume::from_vec(m.grid().clone(), data).unwrap();
    let Some((mut cpu, mut gpu)) = engines(&m, false) else {
        return;
    };
    let t = [Vec3::new(20.0, 5.0, 0.0)];
    for (what, net) in [
        (
            "plane",
            planar([8.0, -60.0, -60.0], [-6.0, 120.0, 0.0], [5.0, 0.0, 120.0]),
        ),
        ("curved", bent()),
    ] {
        same(
            &cpu.cut(&net, &t).unwrap(),
            &gpu.cut(&net, &t).unwrap(),
            what,
        );
        let one: [(&dyn CutSurface, &[Vec3]); 1] = [(&net, t.as_slice())];
        assert_eq!(
            cpu.resected_labels(&one).unwrap().data(),
            gpu.resected_labels(&one).unwrap().data(),
            "{what}: label maps"
        );
    }
    assert_eq!(
        gpu.accelerator_fallbacks().0,
        0,
        "{:?}",
        gpu.accelerator_fallbacks()
    );
}

#[test]
fn grid_aligned_cuts_with_exact_ties_equal_the_cpu() {
    // An axis-aligned 1 mm grid and planes through voxel centres whose samples fall on voxel
    // centres: many samples at exactly the same distance from a voxel (ties to the smallest
    // index) and voxels exactly on the tangent plane.
    let grid = resecta_geom::Grid::axis_aligned(
        [48, 40, 36],
        [1.0, 1.0, 1.0],
        Vec3::new(-24.0, -20.0, -18.0),
    )
    .unwrap();
    let data = (0..grid.len())
        .map(|v| {
            let p = grid.voxel_center(grid.ijk(v));
            (p.x / 20.0).powi(2) + (p.y / 16.0).powi(2) + (p.z / 14.0).powi(2) <= 1.0
        })
        .collect();
    let m = Volume::from_vec(grid, data).unwrap();
    let Some((mut cpu, mut gpu)) = engines(&m, false) else {
        return;
    };
    let t = [Vec3::new(10.0, 0.0, 0.0)];
    for (what, net) in [
        (
            "x = 2",
            planar([2.0, -20.0, -18.0], [0.0, 40.0, 0.0], [0.0, 0.0, 36.0]),
        ),
        (
            "x = 0.5",
            planar([0.5, -20.0, -18.0], [0.0, 40.0, 0.0], [0.0, 0.0, 36.0]),
        ),
        (
            "diagonal",
            planar([-16.0, -20.0, -18.0], [36.0, 36.0, 0.0], [0.0, 0.0, 36.0]),
        ),
    ] {
        same(
            &cpu.cut(&net, &t).unwrap(),
            &gpu.cut(&net, &t).unwrap(),
            what,
        );
    }
    assert_eq!(
        gpu.accelerator_fallbacks().0,
        0,
        "{:?}",
        gpu.accelerator_fallbacks()
    );
}
