//! CPU–GPU cooperation on level 1 (thesis Sec. 8.5.2): the output rows (u samples) are cut
//! into tiles of `tile_rows` rows written into disjoint slices of one output buffer.
//! - **SDC** (static): a profiling step times whole evaluations on each side and gives the
//!   GPU the fraction α = t_cpu / (t_cpu + t_gpu) of the rows (rounded to whole tiles); the
//!   two parts then run concurrently.
//! - **DDC** (dynamic): a shared tile queue drained concurrently by a GPU worker (front) and a
//!   rayon CPU worker (back) until empty.
//!
//! The CPU side is `resecta_bezier`'s [`MleEvaluator`] in its two-step row form
//! (`prepare_rows` once per update, then `rows_into` for any tile, concurrently).

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;

use resecta_bezier::{BezierError, ControlNet, MleEvaluator, P3, Resolution};

use crate::device::{GpuContext, GpuError};
use crate::kernels::GpuScalar;
use crate::kernels::bezier::GpuMle;

/// Tiles left to compute: (tile index, its slice of the output).
type TileQueue<'a, T> = Mutex<VecDeque<(usize, &'a mut [P3<T>])>>;

/// Timings of the profiling step and the resulting GPU share.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Mean seconds per whole evaluation on the GPU (read-back included).
    pub gpu_s: f64,
    /// Mean seconds per whole evaluation on the CPU.
    pub cpu_s: f64,
    /// Fraction of rows for the GPU, `cpu_s / (cpu_s + gpu_s)`.
    pub alpha: f64,
}

/// How a DDC evaluation was shared out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DdcReport {
    /// Tiles the GPU worker took.
    pub gpu_tiles: usize,
    /// Tiles the CPU worker took.
    pub cpu_tiles: usize,
}

/// A GPU evaluator and its CPU twin sharing one surface, tiled by rows.
#[derive(Debug)]
pub struct Cooperative<T: GpuScalar> {
    gpu: GpuMle<T>,
    cpu: MleEvaluator<T>,
    tile_rows: usize,
}

impl<T: GpuScalar> Cooperative<T> {
    /// Both sides for `net` at `resolution`, tiles of `tile_rows` rows (at least 1).
    pub fn new(
        ctx: &GpuContext,
        net: ControlNet<T>,
        resolution: Resolution,
        tile_rows: usize,
    ) -> Result<Self, GpuError> {
        let cpu = MleEvaluator::new(net.clone(), resolution);
        Ok(Self {
            gpu: GpuMle::new(ctx, net, resolution)?,
            cpu,
            tile_rows: tile_rows.max(1),
        })
    }
    /// Rows per tile.
    pub fn tile_rows(&self) -> usize {
        self.tile_rows
    }
    /// Requirement A on both sides.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        self.gpu.set_control_points(points)
    }
    /// The GPU evaluator.
    pub fn gpu(&mut self) -> &mut GpuMle<T> {
        &mut self.gpu
    }

    fn check_out(&self, out: &[P3<T>]) -> Result<(), GpuError> {
        let expected = self.gpu.resolution().len();
        if out.len() != expected {
            return Err(BezierError::BufferLength {
                expected,
                got: out.len(),
            }
            .into());
        }
        Ok(())
    }

    /// Brings the CPU twin to the GPU side's net and resolution and computes its Q.
    fn prepare_cpu(&mut self) {
        self.cpu.set_resolution(self.gpu.resolution());
        self.cpu.set_net(self.gpu.net().clone());
        self.cpu.prepare_rows();
    }

    /// The whole surface on the CPU only.
    pub fn evaluate_cpu(&mut self, out: &mut [P3<T>]) -> Result<(), GpuError> {
        self.check_out(out)?;
        self.prepare_cpu();
        Ok(self.cpu.rows_into(0..self.gpu.resolution().ru(), out)?)
    }

    /// The whole surface on the GPU only.
    pub fn evaluate_gpu(&mut self, out: &mut [P3<T>]) -> Result<(), GpuError> {
        self.gpu.evaluate_points_into(out)
    }

    /// Profiling step of SDC: `reps` (≥ 1) timed evaluations per side after one warm-up each.
    pub fn profile(&mut self, reps: usize, out: &mut [P3<T>]) -> Result<Profile, GpuError> {
        let reps = reps.max(1);
        self.evaluate_gpu(out)?;
        let t = Instant::now();
        for _ in 0..reps {
            self.evaluate_gpu(out)?;
        }
        let gpu_s = t.elapsed().as_secs_f64() / reps as f64;
        self.evaluate_cpu(out)?;
        let t = Instant::now();
        for _ in 0..reps {
            self.evaluate_cpu(out)?;
        }
        let cpu_s = t.elapsed().as_secs_f64() / reps as f64;
        let alpha = if cpu_s + gpu_s > 0.0 {
            cpu_s / (cpu_s + gpu_s)
        } else {
            0.5
        };
        Ok(Profile {
            gpu_s,
            cpu_s,
            alpha,
        })
    }

    /// Rows the GPU gets for share `alpha` under SDC (whole tiles, clamped to 0..=RU).
    pub fn sdc_split(&self, alpha: f64) -> usize {
        let ru = self.gpu.resolution().ru();
        let tiles = (alpha.clamp(0.0, 1.0) * ru as f64 / self.tile_rows as f64).round() as usize;
        (tiles * self.tile_rows).min(ru)
    }

    /// SDC: rows `0..k` on the GPU and `k..RU` on the CPU, concurrently, `k` from
    /// [`Cooperative::sdc_split`]. Returns `k`.
    pub fn evaluate_sdc(&mut self, alpha: f64, out: &mut [P3<T>]) -> Result<usize, GpuError> {
        self.check_out(out)?;
        let (ru, rv) = (self.gpu.resolution().ru(), self.gpu.resolution().rv());
        let k = self.sdc_split(alpha);
        self.prepare_cpu();
        let (gpu_out, cpu_out) = out.split_at_mut(k * rv);
        let (gpu, cpu) = (&mut self.gpu, &self.cpu);
        std::thread::scope(|s| {
            let handle = (k > 0).then(|| s.spawn(move || gpu.evaluate_rows_into(0..k, gpu_out)));
            let cpu_res = if k < ru {
                cpu.rows_into(k..ru, cpu_out).map_err(GpuError::from)
            } else {
                Ok(())
            };
            let gpu_res = match handle.map(|h| h.join()) {
                Some(Ok(r)) => r,
                Some(Err(_)) => Err(GpuError::ReadBack("GPU worker panicked".into())),
                None => Ok(()),
            };
            gpu_res.and(cpu_res)
        })?;
        Ok(k)
    }

    /// DDC: a GPU worker takes tiles from the front of the queue, the CPU worker (rayon
    /// inside each tile) from the back, until the queue is empty.
    pub fn evaluate_ddc(&mut self, out: &mut [P3<T>]) -> Result<DdcReport, GpuError> {
        self.check_out(out)?;
        let rv = self.gpu.resolution().rv();
        let tile = self.tile_rows;
        self.prepare_cpu();
        let queue: TileQueue<'_, T> = Mutex::new(out.chunks_mut(tile * rv).enumerate().collect());
        let pop = |front: bool| {
            let mut q = queue.lock().unwrap_or_else(|e| e.into_inner());
            if front { q.pop_front() } else { q.pop_back() }
        };
        let (gpu, cpu) = (&mut self.gpu, &self.cpu);
        std::thread::scope(|s| {
            let gpu_worker = s.spawn(|| {
                let mut taken = 0;
                while let Some((t, slice)) = pop(true) {
                    let start = t * tile;
                    gpu.evaluate_rows_into(start..start + slice.len() / rv, slice)?;
                    taken += 1;
                }
                Ok::<usize, GpuError>(taken)
            });
            let mut cpu_tiles = 0;
            let mut cpu_res = Ok(());
            while let Some((t, slice)) = pop(false) {
                let start = t * tile;
                if let Err(e) = cpu.rows_into(start..start + slice.len() / rv, slice) {
                    cpu_res = Err(GpuError::from(e));
                    break;
                }
                cpu_tiles += 1;
            }
            let gpu_tiles = match gpu_worker.join() {
                Ok(r) => r?,
                Err(_) => return Err(GpuError::ReadBack("GPU worker panicked".into())),
            };
            cpu_res.map(|()| DdcReport {
                gpu_tiles,
                cpu_tiles,
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use resecta_bezier::{MleEvaluator, P3, Resolution};

    use super::Cooperative;
    use crate::device::testing::context;
    use crate::kernels::GpuScalar;
    use crate::kernels::bezier::tests::{Rng, max_diff, random_net, scale, tol};

    fn cpu_mle<T: GpuScalar>(net: &resecta_bezier::ControlNet<T>, res: Resolution) -> Vec<P3<T>> {
        let mut out = vec![[T::ZERO; 3]; res.len()];
        MleEvaluator::new(net.clone(), res)
            .evaluate_points_into(&mut out)
            .unwrap();
        out
    }

    fn check<T: GpuScalar>(seed: u64) {
        let Some(ctx) = context() else { return };
        if !T::supported(&ctx) {
            eprintln!("SKIP: device lacks SHADER_F64");
            return;
        }
        let mut rng = Rng(seed);
        let net = random_net::<T>(&mut rng, 5, 9);
        let res = Resolution::new(61, 47).unwrap();
        let want = cpu_mle(&net, res);
        let s = scale(&net);
        let mut out = vec![[T::ZERO; 3]; res.len()];
        for tile in [1, 7, 16, 64] {
            let mut co = Cooperative::new(&ctx, net.clone(), res, tile).unwrap();
            for alpha in [0.0, 0.3, 0.5, 1.0] {
                out.fill([T::from_f64(f64::NAN); 3]);
                let k = co.evaluate_sdc(alpha, &mut out).unwrap();
                assert!(
                    k == 61 || k % tile == 0,
                    "split {k} not whole tiles of {tile}"
                );
                if alpha == 0.0 || alpha == 1.0 {
                    assert_eq!(k, if alpha == 0.0 { 0 } else { 61 });
                }
                let d = max_diff(&out, &want) / s;
                assert!(d <= tol::<T>(), "SDC tile {tile} α {alpha}: {d:e}");
            }
            out.fill([T::from_f64(f64::NAN); 3]);
            let rep = co.evaluate_ddc(&mut out).unwrap();
            assert_eq!(rep.gpu_tiles + rep.cpu_tiles, 61usize.div_ceil(tile));
            let d = max_diff(&out, &want) / s;
            assert!(d <= tol::<T>(), "DDC tile {tile}: {d:e} ({rep:?})");
        }
        // After moving the control points both sides follow.
        let mut co = Cooperative::new(&ctx, net, res, 8).unwrap();
        let moved = random_net::<T>(&mut rng, 5, 9);
        co.set_control_points(moved.points()).unwrap();
        co.evaluate_ddc(&mut out).unwrap();
        assert!(max_diff(&out, &cpu_mle(&moved, res)) / scale(&moved) <= tol::<T>());
        let p = co.profile(1, &mut out).unwrap();
        assert!(p.alpha > 0.0 && p.alpha < 1.0, "{p:?}");
        co.evaluate_sdc(p.alpha, &mut out).unwrap();
        assert!(max_diff(&out, &cpu_mle(&moved, res)) / scale(&moved) <= tol::<T>());
    }

    #[test]
    fn sdc_and_ddc_match_cpu_f32() {
        check::<f32>(43);
    }

    #[test]
    fn sdc_and_ddc_match_cpu_f64() {
        check::<f64>(47);
    }
}
