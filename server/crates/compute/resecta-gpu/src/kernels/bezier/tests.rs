//! GPU vs CPU (`resecta_bezier` MLE and BRF) on the test device (lavapipe in CI).

use resecta_bezier::{
    ControlNet, MleEvaluator, Outputs, P3, Resolution, SurfaceGrid, bernstein_table, binomial_row,
    evaluate_brf,
};

use super::{BezierBackend, GpuMle, GpuPrepared, shader_source};
use crate::device::testing::context;
use crate::kernels::GpuScalar;

/// SplitMix64: deterministic test randomness without a dependency.
pub(crate) struct Rng(pub(crate) u64);
impl Rng {
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub(crate) fn range(&mut self, lo: usize, hi: usize) -> usize {
        lo + (self.next() % (hi - lo + 1) as u64) as usize
    }
}

/// A random M×N net in [−50, 50]³.
pub(crate) fn random_net<T: GpuScalar>(rng: &mut Rng, m: usize, n: usize) -> ControlNet<T> {
    ControlNet::from_fn(m, n, |_, _| {
        std::array::from_fn(|_| T::from_f64(100.0 * rng.unit() - 50.0))
    })
    .unwrap()
}

/// Largest coordinate magnitude of the net (the scale errors are relative to).
pub(crate) fn scale<T: GpuScalar>(net: &ControlNet<T>) -> f64 {
    let (lo, hi) = net.bounds();
    lo.iter()
        .chain(&hi)
        .map(|c| c.to_f64().abs())
        .fold(0.0, f64::max)
}

pub(crate) fn max_diff<T: GpuScalar>(a: &[P3<T>], b: &[P3<T>]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c].to_f64() - q[c].to_f64()).abs()))
        .fold(0.0, f64::max)
}

fn cpu_mle<T: GpuScalar>(net: &ControlNet<T>, res: Resolution) -> Vec<P3<T>> {
    let mut out = vec![[T::ZERO; 3]; res.len()];
    MleEvaluator::new(net.clone(), res)
        .evaluate_points_into(&mut out)
        .unwrap();
    out
}

/// Relative tolerance per type: f32 1e-5, f64 1e-12 (of the net's coordinate scale).
pub(crate) fn tol<T: GpuScalar>() -> f64 {
    if T::NAME == "f32" { 1e-5 } else { 1e-12 }
}

fn f64_ok() -> bool {
    context().is_some_and(|c| {
        if !c.caps.f64 {
            eprintln!("SKIP: device lacks SHADER_F64");
        }
        c.caps.f64
    })
}

#[test]
fn wgsl_validates_with_naga() {
    use wgpu::naga;
    for (name, src) in [
        ("f32", shader_source::<f32>()),
        ("f64", shader_source::<f64>()),
    ] {
        let module = naga::front::wgsl::parse_str(&src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&src)));
        let mut v = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::FLOAT64,
        );
        v.validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {e:?}"));
        assert_eq!(module.entry_points.len(), 5);
    }
    assert!(shader_source::<f64>().contains("alias real = f64;"));
    // Without the f64 capability the f64 variant must be rejected (it really uses f64).
    let src = shader_source::<f64>();
    let module = naga::front::wgsl::parse_str(&src).unwrap();
    let mut v = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    );
    assert!(v.validate(&module).is_err());
}

fn check_basis<T: GpuScalar>(m: usize, n: usize, ru: usize, rv: usize) {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(7);
    let net = random_net::<T>(&mut rng, m, n);
    let mut g = GpuMle::new(&ctx, net, Resolution::new(ru, rv).unwrap()).unwrap();
    let (bu, bv) = g.basis_tables().unwrap();
    let cu: Vec<T> = bernstein_table(&binomial_row(m), ru);
    let cv: Vec<T> = bernstein_table(&binomial_row(n), rv);
    let t = if T::NAME == "f32" { 1e-6 } else { 1e-14 };
    let diff = |a: &[T], b: &[T]| {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x.to_f64() - y.to_f64()).abs())
            .fold(0.0, f64::max)
    };
    let (du, dv) = (diff(&bu, &cu), diff(&bv, &cv));
    assert!(
        du <= t && dv <= t,
        "{} {m}x{n} @ {ru}x{rv}: du {du:e} dv {dv:e}",
        T::NAME
    );
    assert_eq!(g.counters().level2, 1);
}

#[test]
fn basis_tables_match_cpu_f32() {
    check_basis::<f32>(4, 7, 37, 53);
    check_basis::<f32>(12, 12, 40, 40); // isotropy: B^v is B^u (direct addressing)
    check_basis::<f32>(2, 9, 2, 300);
}

#[test]
fn basis_tables_match_cpu_f64() {
    if !f64_ok() {
        return;
    }
    check_basis::<f64>(4, 7, 37, 53);
    check_basis::<f64>(12, 12, 40, 40);
}

/// GPU vs CPU MLE and BRF (same type) for random nets, within `tol::<T>()·scale`.
fn check_random<T: GpuScalar>(seed: u64, cases: &[(usize, usize)]) {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(seed);
    for &(ru, rv) in cases {
        let (m, n) = (rng.range(2, 12), rng.range(2, 12));
        let net = random_net::<T>(&mut rng, m, n);
        let res = Resolution::new(ru, rv).unwrap();
        let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
        let mut out = vec![[T::ZERO; 3]; res.len()];
        g.evaluate_points_into(&mut out).unwrap();
        let s = scale(&net);
        let d_mle = max_diff(&out, &cpu_mle(&net, res)) / s;
        let d_brf = max_diff(&out, evaluate_brf(&net, res, Outputs::Points).points()) / s;
        eprintln!(
            "{} {m}x{n} @ {ru}x{rv}: vs MLE {d_mle:.2e}, vs BRF {d_brf:.2e}",
            T::NAME
        );
        assert!(
            d_mle <= tol::<T>(),
            "{} {m}x{n} @ {ru}x{rv}: vs MLE {d_mle:e}",
            T::NAME
        );
        assert!(
            d_brf <= tol::<T>(),
            "{} {m}x{n} @ {ru}x{rv}: vs BRF {d_brf:e}",
            T::NAME
        );
    }
}

const CASES: &[(usize, usize)] = &[
    (2, 2),
    (16, 16),
    (37, 53),
    (53, 37),
    (17, 200),
    (64, 5),
    (100, 100),
];

#[test]
fn random_nets_match_cpu_f32() {
    check_random::<f32>(1, CASES);
    check_random::<f32>(2, CASES);
}

#[test]
fn random_nets_match_cpu_f64() {
    if !f64_ok() {
        return;
    }
    check_random::<f64>(3, CASES);
    check_random::<f64>(4, CASES);
}

#[test]
fn every_net_size_2_to_12_f32() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(11);
    let res = Resolution::new(19, 23).unwrap();
    for m in 2..=12 {
        // n cycles through 2..=12 shifted, so M≠N almost always and every n occurs.
        let n = 2 + (m + 5) % 11;
        let net = random_net::<f32>(&mut rng, m, n);
        let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
        let mut out = vec![[0.0; 3]; res.len()];
        g.evaluate_points_into(&mut out).unwrap();
        let d = max_diff(&out, &cpu_mle(&net, res)) / scale(&net);
        assert!(d <= 1e-5, "{m}x{n}: {d:e}");
    }
}

#[test]
fn large_nets_and_ragged_row_segments_f64() {
    // Large M×N; RU not a multiple of ROWS (also RU < ROWS) and RV not a multiple of the
    // 64-thread workgroup exercise the clipped row segments and columns of level 1b.
    if !f64_ok() {
        return;
    }
    let Some(ctx) = context() else { return };
    let mut rng = Rng(5);
    for (m, n, ru, rv) in [(40, 17, 45, 33), (6, 9, 3, 70), (17, 40, 2, 129)] {
        let net = random_net::<f64>(&mut rng, m, n);
        let res = Resolution::new(ru, rv).unwrap();
        let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
        let mut out = vec![[0.0; 3]; res.len()];
        g.evaluate_points_into(&mut out).unwrap();
        let d = max_diff(&out, &cpu_mle(&net, res)) / scale(&net);
        assert!(d <= 1e-12, "{m}x{n} @ {ru}x{rv}: {d:e}");
    }
    const { assert!(super::ROWS > 3, "the cases above assume RU = 2, 3 < ROWS") };
}

#[test]
fn large_resolution_1000_squared() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(9);
    let res = Resolution::new(1000, 1000).unwrap();
    let net = random_net::<f32>(&mut rng, 4, 5);
    let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
    let mut out = vec![[0.0; 3]; res.len()];
    g.evaluate_points_into(&mut out).unwrap();
    let d = max_diff(&out, &cpu_mle(&net, res)) / scale(&net);
    assert!(d <= 1e-5, "f32: {d:e}");
    if ctx.caps.f64 {
        let net = random_net::<f64>(&mut rng, 12, 12);
        let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
        let mut out = vec![[0.0; 3]; res.len()];
        g.evaluate_points_into(&mut out).unwrap();
        let d = max_diff(&out, &cpu_mle(&net, res)) / scale(&net);
        assert!(d <= 1e-12, "f64: {d:e}");
    }
}

#[test]
fn split_output_bands_and_row_ranges() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(13);
    let net = random_net::<f32>(&mut rng, 5, 3);
    let res = Resolution::new(37, 53).unwrap();
    let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
    // 5 rows per band: 8 bands, the last partial.
    g.set_band_limit(5 * 53 * 12);
    let mut out = vec![[0.0; 3]; res.len()];
    g.evaluate_points_into(&mut out).unwrap();
    assert_eq!(g.bands().len(), 8);
    assert_eq!(g.bands()[7].rows(), 35..37);
    let cpu = cpu_mle(&net, res);
    assert!(max_diff(&out, &cpu) / scale(&net) <= 1e-5);
    // A row range straddling bands at an odd (8-byte-unaligned) offset.
    let mut part = vec![[0.0; 3]; 9 * 53];
    g.evaluate_rows_into(3..12, &mut part).unwrap();
    assert!(max_diff(&part, &cpu[3 * 53..12 * 53]) / scale(&net) <= 1e-5);
    // Bad ranges and lengths are typed errors.
    assert!(
        g.evaluate_rows_into(30..38, &mut vec![[0.0; 3]; 8 * 53])
            .is_err()
    );
    assert!(g.evaluate_rows_into(3..12, &mut part[1..]).is_err());
    assert!(g.evaluate_points_into(&mut out[1..]).is_err());
}

#[test]
fn level_caching_and_updates() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(17);
    let net = random_net::<f32>(&mut rng, 6, 4);
    let res = Resolution::new(33, 21).unwrap();
    let mut g = GpuMle::new(&ctx, net, res).unwrap();
    let mut out = vec![[0.0; 3]; res.len()];
    g.evaluate_points_into(&mut out).unwrap();
    for _ in 0..3 {
        let moved = random_net::<f32>(&mut rng, 6, 4);
        g.set_control_points(moved.points()).unwrap();
        g.evaluate_points_into(&mut out).unwrap();
        assert!(max_diff(&out, &cpu_mle(&moved, res)) / scale(&moved) <= 1e-5);
    }
    let c = g.counters();
    assert_eq!((c.level3, c.level2, c.level1), (1, 1, 4));
    // One point moved.
    g.set_control_point(2, 1, [1.0, 2.0, 3.0]).unwrap();
    g.evaluate_points_into(&mut out).unwrap();
    assert!(max_diff(&out, &cpu_mle(g.net(), res)) / scale(g.net()) <= 1e-5);
    // Requirement B keeps level 3; C rebuilds both.
    let res2 = Resolution::new(10, 70).unwrap();
    g.set_resolution(res2);
    let mut out2 = vec![[0.0; 3]; res2.len()];
    g.evaluate_points_into(&mut out2).unwrap();
    assert!(max_diff(&out2, &cpu_mle(g.net(), res2)) / scale(g.net()) <= 1e-5);
    assert_eq!((g.counters().level3, g.counters().level2), (1, 2));
    let net3 = random_net::<f32>(&mut rng, 9, 9);
    g.set_net(net3.clone());
    g.evaluate_points_into(&mut out2).unwrap();
    assert!(max_diff(&out2, &cpu_mle(&net3, res2)) / scale(&net3) <= 1e-5);
    assert_eq!((g.counters().level3, g.counters().level2), (2, 3));
}

fn check_corners<T: GpuScalar>() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(23);
    let net = random_net::<T>(&mut rng, 5, 8);
    let (ru, rv) = (29, 31);
    let res = Resolution::new(ru, rv).unwrap();
    let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
    let mut out = vec![[T::ZERO; 3]; res.len()];
    g.evaluate_points_into(&mut out).unwrap();
    let t = if T::NAME == "f32" { 1e-6 } else { 1e-14 } * scale(&net);
    for (a, b, i, j) in [
        (0, 0, 0, 0),
        (0, rv - 1, 0, 7),
        (ru - 1, 0, 4, 0),
        (ru - 1, rv - 1, 4, 7),
    ] {
        let d = max_diff(&out[a * rv + b..a * rv + b + 1], &[net.get(i, j).unwrap()]);
        assert!(d <= t, "{} corner ({a},{b}): {d:e}", T::NAME);
    }
}

#[test]
fn corners_interpolate_control_points() {
    check_corners::<f32>();
    if f64_ok() {
        check_corners::<f64>();
    }
}

#[test]
fn resident_result_stays_on_gpu() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(29);
    let net = random_net::<f32>(&mut rng, 4, 4);
    let res = Resolution::new(20, 30).unwrap();
    let mut g = GpuMle::new(&ctx, net.clone(), res).unwrap();
    g.set_band_limit(7 * 30 * 12);
    let bands = g.evaluate_resident().unwrap();
    assert_eq!(bands.len(), 3);
    // Copy the resident buffers out by hand, as a renderer or streamer would consume them.
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    let mut staging = Vec::new();
    for band in bands {
        let size = band.buffer().size();
        let st = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        enc.copy_buffer_to_buffer(band.buffer(), 0, &st, 0, size);
        staging.push((st, size));
    }
    ctx.queue.submit([enc.finish()]);
    let maps: Vec<_> = staging.iter().map(|(b, s)| (b, 0..*s)).collect();
    let mut all: Vec<f32> = Vec::new();
    ctx.read_back(&maps, |_, bytes| {
        all.extend(bytemuck::pod_collect_to_vec::<u8, f32>(bytes))
    })
    .unwrap();
    let pts: &[P3<f32>] = bytemuck::cast_slice(&all);
    assert!(max_diff(pts, &cpu_mle(&net, res)) / scale(&net) <= 1e-5);
}

#[test]
fn backend_picks_gpu_or_cpu_with_same_results() {
    let mut rng = Rng(31);
    let net = random_net::<f32>(&mut rng, 3, 6);
    let res = Resolution::new(25, 18).unwrap();
    let mut cpu = BezierBackend::new(None, net.clone(), res);
    assert_eq!(cpu.name(), "cpu");
    let mut a = vec![[0.0; 3]; res.len()];
    cpu.evaluate_points_into(&mut a).unwrap();
    let Some(ctx) = context() else { return };
    let mut gpu = BezierBackend::new(Some(&ctx), net.clone(), res);
    assert_eq!(gpu.name(), "wgpu");
    let mut b = vec![[0.0; 3]; res.len()];
    gpu.evaluate_points_into(&mut b).unwrap();
    assert!(max_diff(&a, &b) / scale(&net) <= 1e-5);
    let moved = random_net::<f32>(&mut rng, 3, 6);
    for be in [&mut cpu, &mut gpu] {
        be.set_control_points(moved.points()).unwrap();
        be.evaluate_points_into(&mut a).unwrap();
        assert!(max_diff(&a, &cpu_mle(&moved, res)) / scale(&moved) <= 1e-5);
        assert_eq!(be.counters().level2, 1);
    }
}

#[test]
fn prepared_runs_and_times() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(37);
    let net = random_net::<f32>(&mut rng, 4, 4);
    let res = Resolution::new(64, 64).unwrap();
    let mut p = GpuPrepared::new(&ctx, net.clone(), res).unwrap();
    assert!(max_diff(p.output(), &cpu_mle(&net, res)) / scale(&net) <= 1e-5);
    let moved = random_net::<f32>(&mut rng, 4, 4);
    p.set_control_points(moved.points()).unwrap();
    p.run().unwrap();
    assert!(max_diff(p.output(), &cpu_mle(&moved, res)) / scale(&moved) <= 1e-5);
    p.run_resident().unwrap();
    let mut out = vec![[0.0; 3]; res.len()];
    let dt = p.evaluator().evaluate_timed(&mut out).unwrap();
    assert!(dt.as_nanos() > 0);
    assert_eq!(p.evaluator().counters().level2, 1);
}

/// Largest differences (points and derivatives in mm, normals unitless) of a GPU grid from
/// the CPU's f64 grid.
#[derive(Debug, Clone, Copy)]
struct GridDiff {
    points: f64,
    derivatives: f64,
    normals: f64,
}

fn grid_diff<T: GpuScalar>(gpu: &SurfaceGrid<T>, cpu: &SurfaceGrid<f64>) -> GridDiff {
    let wide = |a: &[P3<T>]| -> Vec<P3<f64>> { a.iter().map(|p| p.map(|c| c.to_f64())).collect() };
    let pair = |a: Option<&[P3<T>]>, b: Option<&[P3<f64>]>| max_diff(&wide(a.unwrap()), b.unwrap());
    GridDiff {
        points: max_diff(&wide(gpu.points()), cpu.points()),
        derivatives: pair(gpu.du(), cpu.du()).max(pair(gpu.dv(), cpu.dv())),
        normals: pair(gpu.normals(), cpu.normals()),
    }
}

fn cpu_grid(net: &ControlNet<f64>, res: Resolution) -> SurfaceGrid<f64> {
    MleEvaluator::new(net.clone(), res).evaluate(Outputs::Normals)
}

/// GPU normals of `net` at `ru`×`rv` in `T` against the CPU's f64, and the evaluator.
fn gpu_vs_cpu<T: GpuScalar>(net: &ControlNet<f64>, ru: usize, rv: usize) -> Option<GridDiff> {
    let ctx = context()?;
    let res = Resolution::new(ru, rv).unwrap();
    let mut g = GpuMle::<T>::new(&ctx, net.cast(), res).unwrap();
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    g.evaluate_normals_into(&mut grid).unwrap();
    Some(grid_diff(&grid, &cpu_grid(net, res)))
}

/// A 4×4 net with the edge u = 0 collapsed to one point (∂S/∂v = 0 there: the limit normal)
/// and, when `apex`, the edge v = 1 collapsed to the same point (∂S/∂u = 0 there, and both
/// vanish at the corner: the neighbours' normal).
fn collapsed(apex: bool) -> ControlNet<f64> {
    ControlNet::from_fn(4, 4, |i, j| {
        if i == 0 || (apex && j == 3) {
            return [0.0, 0.0, 30.0];
        }
        let (u, v) = (i as f64 / 3.0, j as f64 / 3.0);
        [
            40.0 * u * (v - 0.5),
            40.0 * u * (0.5 - v).abs() + 20.0 * u,
            30.0 - 25.0 * u,
        ]
    })
    .unwrap()
}

fn normal_cases() -> Vec<(&'static str, ControlNet<f64>, usize, usize)> {
    let mut rng = Rng(21);
    vec![
        ("4x4 @ 40x40", random_net(&mut rng, 4, 4), 40, 40),
        ("5x7 @ 37x53", random_net(&mut rng, 5, 7), 37, 53),
        ("2x9 @ 3x64", random_net(&mut rng, 2, 9), 3, 64),
        ("6x6 @ 200x200", random_net(&mut rng, 6, 6), 200, 200),
        ("collapsed edge @ 40x40", collapsed(false), 40, 40),
        ("collapsed edges @ 33x41", collapsed(true), 33, 41),
    ]
}

/// f64: 1e-9 mm in points and derivatives, 1e-9 in unit normals (seen: ≤ 1e-12).
#[test]
fn normals_match_cpu_f64() {
    if !f64_ok() {
        return;
    }
    for (name, net, ru, rv) in normal_cases() {
        let d = gpu_vs_cpu::<f64>(&net, ru, rv).unwrap();
        eprintln!("f64 {name}: {d:?}");
        assert!(
            d.points <= 1e-9 && d.derivatives <= 1e-9 && d.normals <= 1e-9,
            "f64 {name}: {d:?}"
        );
    }
}

/// f32 against the CPU: points within 2e-5 of the net's scale and derivatives within 2e-5 of
/// 60× it (seen: ≤ 1.7e-5 mm and ≤ 1.4e-4 mm on a ±50 mm net) against the f64 CPU; normals
/// within 1e-4 of the f32 CPU's (seen ≤ 3e-5). Against the f64 CPU the normals are within
/// 4e-5 except where two collapsed edges meet (seen 0.96): f32's √ε thresholds classify
/// samples there otherwise, in the CPU's f32 evaluator as on the GPU.
#[test]
fn normals_match_cpu_f32() {
    for (name, net, ru, rv) in normal_cases() {
        let Some(d) = gpu_vs_cpu::<f32>(&net, ru, rv) else {
            return;
        };
        let res = Resolution::new(ru, rv).unwrap();
        let Some(ctx) = context() else { return };
        let mut g = GpuMle::<f32>::new(&ctx, net.cast(), res).unwrap();
        let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
        g.evaluate_normals_into(&mut grid).unwrap();
        let cpu32 = MleEvaluator::new(net.cast::<f32>(), res).evaluate(Outputs::Normals);
        let dn32 = max_diff(grid.normals().unwrap(), cpu32.normals().unwrap());
        eprintln!("f32 {name}: {d:?}, normals vs CPU f32 {dn32:e}");
        let s = scale(&net);
        assert!(
            d.points <= 2e-5 * s && d.derivatives <= 2e-5 * 60.0 * s && dn32 <= 1e-4,
            "f32 {name} (scale {s}): {d:?}, normals vs CPU f32 {dn32:e}"
        );
    }
}

#[test]
fn collapsed_edge_normals_are_the_cpu_limit_normals() {
    if !f64_ok() {
        return;
    }
    let net = collapsed(false);
    let res = Resolution::new(40, 40).unwrap();
    let Some(ctx) = context() else { return };
    let mut g = GpuMle::<f64>::new(&ctx, net.clone(), res).unwrap();
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    g.evaluate_normals_into(&mut grid).unwrap();
    let normals = grid.normals().unwrap();
    // Row u = 0 is one point: ∂S/∂v vanishes there, yet every normal is a unit vector.
    assert!(
        grid.dv().unwrap()[..40]
            .iter()
            .all(|d| d.iter().all(|c| c.abs() < 1e-12))
    );
    for n in normals {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-12, "{n:?}");
    }
    assert_eq!(normals[..40], cpu_grid(&net, res).normals().unwrap()[..40]);
}

#[test]
fn an_edited_point_uploads_alone_and_matches_a_fresh_cpu_evaluation() {
    if !f64_ok() {
        return;
    }
    let Some(ctx) = context() else { return };
    let mut rng = Rng(5);
    let mut net = random_net::<f64>(&mut rng, 5, 7);
    let res = Resolution::new(37, 53).unwrap();
    let mut g = GpuMle::<f64>::new(&ctx, net.clone(), res).unwrap();
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    g.evaluate_normals_into(&mut grid).unwrap();
    assert_eq!(g.uploaded_bytes(), 5 * 7 * 24);
    for (i, j) in [(2, 3), (0, 6), (4, 0)] {
        let p = [rng.unit() * 80.0 - 40.0, 12.5, -7.0];
        net.set(i, j, p).unwrap();
        let before = g.uploaded_bytes();
        g.set_control_point(i, j, p).unwrap();
        g.evaluate_normals_into(&mut grid).unwrap();
        assert_eq!(g.uploaded_bytes() - before, 24, "one point, xyz f64");
        let d = grid_diff(&grid, &cpu_grid(&net, res));
        assert!(d.points <= 1e-9 && d.normals <= 1e-9, "({i}, {j}): {d:?}");
    }
    // Points after normals share the bands; a new resolution and net are honoured too.
    let mut pts = vec![[0.0; 3]; res.len()];
    g.evaluate_points_into(&mut pts).unwrap();
    assert!(max_diff(&pts, grid.points()) <= 1e-12);
    let net2 = random_net::<f64>(&mut rng, 3, 8);
    let res2 = Resolution::new(20, 31).unwrap();
    g.set_net(net2.clone());
    g.set_resolution(res2);
    let mut grid2 = SurfaceGrid::zeroed(res2, Outputs::Normals);
    g.evaluate_normals_into(&mut grid2).unwrap();
    let d = grid_diff(&grid2, &cpu_grid(&net2, res2));
    assert!(d.points <= 1e-9 && d.normals <= 1e-9, "{d:?}");
    assert!(
        g.evaluate_normals_into(&mut grid).is_err(),
        "wrong resolution"
    );
}

#[test]
fn normals_split_into_bands_match_one_band() {
    if !f64_ok() {
        return;
    }
    let Some(ctx) = context() else { return };
    let net = random_net::<f64>(&mut Rng(9), 4, 5);
    let res = Resolution::new(45, 30).unwrap();
    let mut g = GpuMle::<f64>::new(&ctx, net.clone(), res).unwrap();
    g.set_band_limit(4 * 3 * 8 * 30 * 7); // 7 rows of the four outputs per band
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    g.evaluate_normals_into(&mut grid).unwrap();
    assert_eq!(g.bands().len(), 7);
    let d = grid_diff(&grid, &cpu_grid(&net, res));
    assert!(d.points <= 1e-9 && d.normals <= 1e-9, "{d:?}");
}

#[test]
fn a_second_evaluator_on_a_context_compiles_nothing_and_evaluates_the_same() {
    if context().is_none() {
        return;
    }
    // A context of its own: the shared test context's count moves with the other tests.
    let ctx = crate::GpuContext::new().unwrap();
    assert_eq!(ctx.pipelines_compiled(), 0);
    let net = random_net::<f64>(&mut Rng(21), 5, 4);
    let res = Resolution::new(33, 17).unwrap();
    let evaluate = |ctx: &crate::GpuContext| {
        let mut g = GpuMle::<f32>::new(ctx, net.cast(), res).unwrap();
        let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
        g.evaluate_normals_into(&mut grid).unwrap();
        grid
    };
    let first = evaluate(&ctx);
    assert_eq!(ctx.pipelines_compiled(), 5, "3 for points, 2 for normals");
    let second = evaluate(&ctx.clone());
    assert_eq!(ctx.pipelines_compiled(), 5, "a clone shares the cache");
    assert_eq!(first.points(), second.points());
    assert_eq!(first.normals(), second.normals());
    let d = grid_diff(&second, &cpu_grid(&net, res));
    assert!(d.points <= 1e-3 && d.normals <= 1e-4, "{d:?}");
    // Another scalar type is another source: its kernels are compiled once, then shared too.
    if ctx.caps.f64 {
        for expected in [8, 8] {
            GpuMle::<f64>::new(&ctx, net.clone(), res).unwrap();
            assert_eq!(ctx.pipelines_compiled(), expected);
        }
    }
}
