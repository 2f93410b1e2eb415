//! Quick timing of the GPU Bézier path against the CPU MLE, and of SDC/DDC cooperation.
//! Run: `WGPU_BACKEND=vulkan cargo run --release -p resecta-gpu --example bezier_timing`.
//! Pass `--no-coop` to skip the SDC/DDC table. "empty submit+wait" is the floor of any GPU
//! call; "gpu" is one evaluation with read-back into host memory; "gpu-resident" leaves the
//! surface on the GPU (kernels + wait); "+ upload" re-sends the control points first. The
//! drag table times what a planner's edit costs: one control point moved, then points and unit
//! normals read back (`GpuSurface`), against the CPU MLE doing the same.

use std::time::Instant;

use resecta_bezier::{
    ControlNet, MleEvaluator, Outputs, P3, Resolution, SurfaceEvaluator, SurfaceGrid, cpu_evaluator,
};
use resecta_gpu::{Cooperative, GpuContext, GpuError, GpuPrepared, GpuScalar, GpuSurface};

fn net<T: GpuScalar>(m: usize) -> Result<ControlNet<T>, resecta_bezier::BezierError> {
    ControlNet::from_fn(m, m, |i, j| {
        let (x, y) = (i as f64, j as f64);
        [
            T::from_f64(10.0 * x),
            T::from_f64(10.0 * y),
            T::from_f64((x * 0.7 + y * 1.3).sin() * 5.0),
        ]
    })
}

fn per_s(reps: usize, f: &mut dyn FnMut() -> Result<(), GpuError>) -> Result<f64, GpuError> {
    f()?;
    let t = Instant::now();
    for _ in 0..reps {
        f()?;
    }
    Ok(reps as f64 / t.elapsed().as_secs_f64())
}

/// Floor of any GPU evaluation: an empty compute pass, submitted and waited for.
fn empty_rate(ctx: &GpuContext) -> Result<f64, GpuError> {
    per_s(200, &mut || {
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        drop(enc.begin_compute_pass(&Default::default()));
        ctx.queue.submit([enc.finish()]);
        ctx.wait()
    })
}

fn table<T: GpuScalar>(ctx: &GpuContext) -> Result<(), Box<dyn std::error::Error>> {
    for m in [4, 12] {
        for r in [256, 1000] {
            let res = Resolution::new(r, r)?;
            let reps = if r == 256 { 20 } else { 5 };
            let mut p = GpuPrepared::new(ctx, net::<T>(m)?, res)?;
            let gpu = per_s(reps, &mut || p.run())?;
            let resident = per_s(reps, &mut || p.run_resident())?;
            // Upload included: the same points re-sent before each resident run.
            let pts = p.evaluator().net().points().to_vec();
            let upload = per_s(reps, &mut || {
                p.set_control_points(&pts)?;
                p.run_resident()
            })?;
            let mut cpu = MleEvaluator::new(net::<T>(m)?, res);
            let mut out: Vec<P3<T>> = vec![[T::ZERO; 3]; res.len()];
            let cpu_rate = per_s(reps, &mut || Ok(cpu.evaluate_points_into(&mut out)?))?;
            println!(
                "| {} | {m}x{m} | {r}x{r} | {gpu:.1} | {resident:.1} | {upload:.1} | {cpu_rate:.1} |",
                T::NAME
            );
        }
    }
    Ok(())
}

/// Drags (one control point moved, points + normals evaluated) per second on `e`.
fn drags(mut e: Box<dyn SurfaceEvaluator>, reps: usize) -> Result<f64, GpuError> {
    let mut grid = SurfaceGrid::zeroed(e.resolution(), Outputs::Normals);
    let mut k = 0.0;
    per_s(reps, &mut || {
        k += 0.01;
        e.set_control_point(1, 2, [10.0, 20.0, k])?;
        Ok(e.evaluate_into(&mut grid)?)
    })
}

fn drag_table(ctx: &GpuContext) -> Result<(), Box<dyn std::error::Error>> {
    for (m, r) in [(4, 40), (4, 200), (12, 200)] {
        let res = Resolution::new(r, r)?;
        let reps = if r == 40 { 200 } else { 20 };
        let gpu = drags(Box::new(GpuSurface::new(ctx, net::<f64>(m)?, res)?), reps)?;
        let gpu32 = drags(
            Box::new(GpuSurface::new_f32(ctx, net::<f64>(m)?, res)?),
            reps,
        )?;
        let cpu = drags(cpu_evaluator(net::<f64>(m)?, res), reps)?;
        println!("| {m}x{m} | {r}x{r} | {gpu:.1} | {gpu32:.1} | {cpu:.1} |");
    }
    Ok(())
}

fn cooperation<T: GpuScalar>(
    ctx: &GpuContext,
    m: usize,
    r: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let res = Resolution::new(r, r)?;
    let mut co = Cooperative::new(ctx, net::<T>(m)?, res, 32)?;
    let mut out: Vec<P3<T>> = vec![[T::ZERO; 3]; res.len()];
    let prof = co.profile(3, &mut out)?;
    let reps = 5;
    let cpu = per_s(reps, &mut || co.evaluate_cpu(&mut out))?;
    let gpu = per_s(reps, &mut || co.evaluate_gpu(&mut out))?;
    let sdc = per_s(reps, &mut || {
        co.evaluate_sdc(prof.alpha, &mut out).map(|_| ())
    })?;
    let mut rep = Default::default();
    let ddc = per_s(reps, &mut || {
        rep = co.evaluate_ddc(&mut out)?;
        Ok(())
    })?;
    println!(
        "| {} | {m}x{m} | {r}x{r} | {:.2} | {cpu:.1} | {gpu:.1} | {sdc:.1} | {ddc:.1} | {}/{} |",
        T::NAME,
        prof.alpha,
        rep.gpu_tiles,
        rep.cpu_tiles
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let coop = std::env::args().all(|a| a != "--no-coop");
    let ctx = GpuContext::new()?;
    println!(
        "adapter: {} ({:?}), f64: {}, threads (rayon): {}",
        ctx.info.name,
        ctx.info.backend,
        ctx.caps.f64,
        rayon::current_num_threads()
    );
    println!("empty submit+wait: {:.0}/s", empty_rate(&ctx)?);
    println!(
        "| type | net | resolution | gpu eval/s (with read-back) | gpu-resident eval/s | resident + upload /s | cpu MLE eval/s |"
    );
    println!("|---|---|---|---|---|---|---|");
    table::<f32>(&ctx)?;
    if ctx.caps.f64 {
        table::<f64>(&ctx)?;
    }
    println!(
        "\n| net | resolution | gpu drags/s (f64 when offered) | gpu drags/s (f32) | cpu MLE drags/s |"
    );
    println!("|---|---|---|---|---|");
    drag_table(&ctx)?;
    if !coop {
        return Ok(());
    }
    println!(
        "\n| type | net | resolution | α (SDC) | cpu only /s | gpu only /s | SDC /s | DDC /s | DDC tiles gpu/cpu |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (m, r) in [(4, 1000), (12, 1000), (12, 256)] {
        cooperation::<f32>(&ctx, m, r)?;
        if ctx.caps.f64 {
            cooperation::<f64>(&ctx, m, r)?;
        }
    }
    Ok(())
}
