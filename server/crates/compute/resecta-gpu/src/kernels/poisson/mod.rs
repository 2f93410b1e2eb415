//! Screened Poisson multigrid on the GPU: the CPU twin is `resecta_poisson::CpuMultigrid`,
//! whose schedule and operations ([`resecta_poisson::System`]'s module docs) this solver runs.
//!
//! Design: the host assembles the system (`resecta_poisson::solve_with`: splatting, restricted
//! right-hand sides and screening weights) and [`GpuMultigrid`] uploads every level once into
//! four arrays (`x`, `b`, `diag`, `r`, levels at offsets; allocated once per solve). Each
//! operation is a compute dispatch of `poisson.wgsl` (red–black Gauss–Seidel by colour, residual,
//! full-weighting restriction, trilinear prolongation, clearing), its level chosen by a 256-byte
//! uniform slot. Full multigrid and the first residual go in one command buffer, then one per
//! V-cycle with the next residual; the residual norms are reduced on the device (per workgroup,
//! then one workgroup) so each check reads back 8 bytes; the finest `x` is read back once.
//!
//! Agreement with the CPU: the kernels transcribe the CPU's neighbour order and weights in
//! `f32`; red–black colours have no intra-colour dependency, so results differ only by rounding
//! (the device may fuse or round division differently) and by the norm's `f32` tree sum (the
//! CPU sums in `f64`), which can move the stopping cycle when a residual sits at the tolerance.
//! Tests compare fields, iso-surfaces and volumes with the CPU's (`tests.rs`); on lavapipe the
//! field is bitwise the CPU's (d = 5–8 measured), the bounds tested are 2e-4 on the field,
//! 0.05 mm on the surface and 0.05 % on the volume.
//!
//! Oriented points: [`GpuSobel`] is `resecta_poisson::CpuSobel` on the device, the integer 3D
//! Sobel gradient of every voxel of the padded mask box (slabs of planes sized to the device's
//! binding limit, one dispatch and one read-back each); the host turns gradients into samples
//! (`resecta_poisson::oriented_points_with`, shared with the CPU), so the points are identical.
//! Marching cubes stays on the host (`resecta_isosurface`), so both backends' meshes follow
//! the same topology rules and are closed and manifold by construction.

use resecta_poisson::{
    COARSEST_SWEEPS, MaskBox, MultigridSolver, PoissonError, PoissonParams, PoissonSolver,
    SobelPass, Solution, System,
};
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};
use crate::kernels::isosurface::GpuClassifier;

#[cfg(test)]
mod tests;

/// The WGSL source.
pub const SOURCE: &str = include_str!("poisson.wgsl");
/// Invocations per workgroup (`GROUP` in the WGSL).
const GROUP: u32 = 256;

/// Entry points and the bindings each uses.
const ENTRIES: [(&str, &[u32]); 6] = [
    ("gs_smooth", &[0, 1, 2, 3]),
    ("residual", &[0, 1, 2, 3, 4, 5]),
    ("norm_reduce", &[0, 5, 6]),
    ("restriction", &[0, 2, 4]),
    ("clear", &[0, 1]),
    ("prolongation", &[0, 1]),
];
const SMOOTH: usize = 0;
const RESIDUAL: usize = 1;
const REDUCE: usize = 2;
const RESTRICT: usize = 3;
const CLEAR: usize = 4;
const PROLONG: usize = 5;

/// One uniform slot (32 bytes used). Mirrors `Params` in the WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n: u32,
    off: u32,
    nc: u32,
    offc: u32,
    lap: f32,
    flag: u32,
    groups: u32,
    pad: u32,
}

/// The multigrid of `resecta-poisson` on a wgpu device (f32).
#[derive(Debug, Clone)]
pub struct GpuMultigrid {
    ctx: GpuContext,
}

impl GpuMultigrid {
    pub fn new(ctx: &GpuContext) -> Self {
        Self { ctx: ctx.clone() }
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Solves `system` as [`resecta_poisson::CpuMultigrid`] does.
    pub fn run(&self, system: &System, params: &PoissonParams) -> Result<Solution, GpuError> {
        self.ctx.check()?;
        if system.levels.is_empty() {
            return Ok(Solution::default());
        }
        let mg = Resident::new(&self.ctx, system)?;
        let top = system.levels.len() - 1;
        let sweeps = params.sweeps;
        let mut ops = Vec::new();
        mg.v_cycle(&mut ops, 0, sweeps);
        for l in 1..=top {
            mg.op(&mut ops, PROLONG, l, 0);
            mg.v_cycle(&mut ops, l, sweeps);
        }
        let mut out = Solution::default();
        loop {
            mg.op(&mut ops, RESIDUAL, top, 0);
            mg.op(&mut ops, REDUCE, top, 0);
            let [rr, bb] = mg.norms(&ops)?;
            ops.clear();
            let rel = if bb > 0.0 { (rr / bb).sqrt() } else { 0.0 };
            out.residuals.push(rel);
            if rel <= params.tolerance || out.cycles >= params.max_cycles {
                break;
            }
            mg.v_cycle(&mut ops, top, sweeps);
            out.cycles += 1;
        }
        out.x = mg.finest()?;
        Ok(out)
    }
}

impl MultigridSolver for GpuMultigrid {
    fn backend(&self) -> &'static str {
        "gpu"
    }
    fn solve(&self, system: System, params: &PoissonParams) -> Result<Solution, PoissonError> {
        self.run(&system, params)
            .map_err(|e| PoissonError::Backend {
                backend: "gpu",
                reason: e.to_string(),
            })
    }
}

/// A [`PoissonSolver`] on `ctx`: multigrid, Sobel pass and the iso-surface's node
/// classification (for `resecta_recon`'s `*_with` calls and the server).
pub fn gpu_poisson_solver(ctx: &GpuContext) -> PoissonSolver {
    PoissonSolver::new(GpuMultigrid::new(ctx))
        .with_sobel(GpuSobel::new(ctx))
        .with_classifier(GpuClassifier::new(ctx))
}

/// The oriented points' Sobel pass on a wgpu device.
#[derive(Debug, Clone)]
pub struct GpuSobel {
    ctx: GpuContext,
}

impl GpuSobel {
    pub fn new(ctx: &GpuContext) -> Self {
        Self { ctx: ctx.clone() }
    }

    /// `resecta_poisson::CpuSobel::gradients` on the device.
    pub fn run(&self, b: &MaskBox) -> Result<Vec<[i8; 3]>, GpuError> {
        self.ctx.check()?;
        let [px, py, pz] = b.dims;
        let plane = px * py;
        if b.data.len() != plane * pz || pz < 3 || px < 3 || py < 3 {
            return Err(GpuError::Pipeline(format!(
                "mask box of {:?} voxels holds {} values",
                b.dims,
                b.data.len()
            )));
        }
        let limit = self.ctx.max_binding() as usize;
        // Output planes per slab: 4 bytes per voxel out, and their planes ±1 in.
        let slab = (limit / 4 / plane).min(pz - 2);
        if slab == 0 || (slab + 2) * plane > limit {
            return Err(too_large("Sobel plane", 4 * plane as u64, limit as u64));
        }
        let to_u32 = |v: usize| {
            u32::try_from(v).map_err(|_| too_large("Sobel plane", 4 * plane as u64, limit as u64))
        };
        let (x, y) = (to_u32(px)?, to_u32(py)?);
        let pipeline = self.ctx.compute_pipeline("poisson", SOURCE, "sobel")?;
        let device = &self.ctx.device;
        use wgpu::BufferUsages as U;
        let buffer = |label, size: usize, usage| self.ctx.buffer(label, size as u64, usage);
        let in_bytes = ((slab + 2) * plane).next_multiple_of(4);
        let out_bytes = 4 * slab * plane;
        let uniform = buffer("sobel-params", 16, U::UNIFORM | U::COPY_DST);
        let input = buffer("sobel-mask", in_bytes, U::STORAGE | U::COPY_DST);
        let out = buffer("sobel-gradients", out_bytes, U::STORAGE | U::COPY_SRC);
        let staging = buffer("sobel-staging", out_bytes, U::MAP_READ | U::COPY_DST);
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sobel"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[(7, &uniform), (8, &input), (9, &out)].map(|(binding, b)| {
                wgpu::BindGroupEntry {
                    binding,
                    resource: b.as_entire_binding(),
                }
            }),
        });
        let mut grads = vec![[0i8; 3]; b.data.len()];
        let mut chunk = vec![0u8; in_bytes];
        let max_dim = self.ctx.caps.limits.max_compute_workgroups_per_dimension;
        for k0 in (1..pz - 1).step_by(slab) {
            let m = slab.min(pz - 1 - k0);
            let src = &b.data[(k0 - 1) * plane..(k0 + m + 1) * plane];
            chunk[..src.len()].copy_from_slice(src);
            let q = &self.ctx.queue;
            q.write_buffer(&input, 0, &chunk[..(src.len()).next_multiple_of(4)]);
            let params = [x, y, to_u32(m)?, 0];
            q.write_buffer(&uniform, 0, bytemuck::cast_slice(&params));
            let groups = to_u32(m * plane)?.div_ceil(GROUP);
            let gx = groups.min(max_dim);
            let mut enc = device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
            }
            let used = (4 * m * plane) as u64;
            enc.copy_buffer_to_buffer(&out, 0, &staging, 0, used);
            q.submit([enc.finish()]);
            let dst = &mut grads[k0 * plane..(k0 + m) * plane];
            let read = self.ctx.read_back(&[(&staging, 0..used)], |_, bytes| {
                for (g, w) in dst.iter_mut().zip(bytes.chunks_exact(4)) {
                    let w = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
                    if w != 0 {
                        *g = [0, 6, 12].map(|s| ((w >> s & 63) as i32 - 16) as i8);
                    }
                }
            });
            self.ctx.check()?;
            read?;
        }
        Ok(grads)
    }
}

impl SobelPass for GpuSobel {
    fn backend(&self) -> &'static str {
        "gpu"
    }
    fn gradients(&self, b: &MaskBox) -> Result<Vec<[i8; 3]>, PoissonError> {
        self.run(b).map_err(|e| PoissonError::Backend {
            backend: "gpu",
            reason: e.to_string(),
        })
    }
}

/// One dispatch: entry, uniform slot, invocations.
type Op = (usize, usize, u32);

/// A system resident on the device for one solve.
struct Resident<'a> {
    ctx: &'a GpuContext,
    pipelines: Vec<wgpu::ComputePipeline>,
    /// `binds[entry][slot]`.
    binds: Vec<Vec<wgpu::BindGroup>>,
    /// Nodes per axis and first node of each level.
    levels: Vec<(u32, u32)>,
    x: wgpu::Buffer,
    norms: wgpu::Buffer,
    staging_norms: wgpu::Buffer,
}

fn too_large(what: &'static str, bytes: u64, limit: u64) -> GpuError {
    GpuError::TooLarge { what, bytes, limit }
}

impl<'a> Resident<'a> {
    fn new(ctx: &'a GpuContext, system: &System) -> Result<Self, GpuError> {
        let limit = ctx.max_binding();
        let mut levels = Vec::with_capacity(system.levels.len());
        let mut total = 0u64;
        for lv in &system.levels {
            let nodes = (lv.n as u64).pow(3);
            if lv.b.len() as u64 != nodes || lv.diag.len() as u64 != nodes {
                return Err(GpuError::Pipeline(format!(
                    "Poisson level of {} nodes per axis has {} b and {} diag values",
                    lv.n,
                    lv.b.len(),
                    lv.diag.len()
                )));
            }
            let n = u32::try_from(lv.n).map_err(|_| too_large("Poisson level", nodes, limit))?;
            let off = u32::try_from(total).map_err(|_| too_large("Poisson grid", total, limit))?;
            levels.push((n, off));
            total += nodes;
        }
        let bytes = 4 * total;
        if bytes > limit {
            return Err(too_large("Poisson multigrid array", bytes, limit));
        }
        let max_dim = ctx.caps.limits.max_compute_workgroups_per_dimension;
        let dims = |count: u32| {
            let groups = count.div_ceil(GROUP).max(1);
            let gx = groups.min(max_dim);
            (gx, groups.div_ceil(gx))
        };
        let align = ctx.caps.limits.min_uniform_buffer_offset_alignment.max(32) as usize;
        let mut slots = vec![0u8; align * 2 * levels.len()];
        let mut max_groups = 1;
        for (l, (lv, &(n, off))) in system.levels.iter().zip(&levels).enumerate() {
            let (gx, gy) = dims(n * n * n);
            max_groups = max_groups.max(gx * gy);
            let (nc, offc) = if l > 0 { levels[l - 1] } else { (0, 0) };
            for flag in 0..2 {
                let p = Params {
                    n,
                    off,
                    nc,
                    offc,
                    lap: lv.lap,
                    flag,
                    groups: gx * gy,
                    pad: 0,
                };
                let at = align * (2 * l + flag as usize);
                slots[at..at + 32].copy_from_slice(bytemuck::bytes_of(&p));
            }
        }
        let device = &ctx.device;
        use wgpu::BufferUsages as U;
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("poisson-params"),
            contents: &slots,
            usage: U::UNIFORM,
        });
        let buffer = |label, size, usage| ctx.buffer(label, size, usage);
        let x = buffer("poisson-x", bytes, U::STORAGE | U::COPY_SRC);
        let b = buffer("poisson-b", bytes, U::STORAGE | U::COPY_DST);
        let diag = buffer("poisson-diag", bytes, U::STORAGE | U::COPY_DST);
        let r = buffer("poisson-r", bytes, U::STORAGE);
        let partials = buffer("poisson-partials", 8 * u64::from(max_groups), U::STORAGE);
        let norms = buffer("poisson-norms", 8, U::STORAGE | U::COPY_SRC);
        let staging_norms = buffer("poisson-norms-staging", 8, U::MAP_READ | U::COPY_DST);
        for (lv, &(_, off)) in system.levels.iter().zip(&levels) {
            let at = 4 * u64::from(off);
            ctx.queue.write_buffer(&b, at, bytemuck::cast_slice(&lv.b));
            ctx.queue
                .write_buffer(&diag, at, bytemuck::cast_slice(&lv.diag));
        }
        let pipelines = ENTRIES
            .iter()
            .map(|(entry, _)| ctx.compute_pipeline("poisson", SOURCE, entry))
            .collect::<Result<Vec<_>, _>>()?;
        let storage = [&x, &b, &diag, &r, &partials, &norms];
        let binds = ENTRIES
            .iter()
            .zip(&pipelines)
            .map(|((entry, used), pipeline)| {
                let layout = pipeline.get_bind_group_layout(0);
                (0..2 * levels.len())
                    .map(|slot| {
                        let entries: Vec<_> = used
                            .iter()
                            .map(|&k| wgpu::BindGroupEntry {
                                binding: k,
                                resource: if k == 0 {
                                    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                        buffer: &uniform,
                                        offset: (align * slot) as u64,
                                        size: std::num::NonZeroU64::new(32),
                                    })
                                } else {
                                    storage[k as usize - 1].as_entire_binding()
                                },
                            })
                            .collect();
                        device.create_bind_group(&wgpu::BindGroupDescriptor {
                            label: Some(entry),
                            layout: &layout,
                            entries: &entries,
                        })
                    })
                    .collect()
            })
            .collect();
        ctx.check()?;
        Ok(Self {
            ctx,
            pipelines,
            binds,
            levels,
            x,
            norms,
            staging_norms,
        })
    }

    /// Appends `entry` at level `l` with uniform variant `flag`.
    fn op(&self, ops: &mut Vec<Op>, entry: usize, l: usize, flag: usize) {
        let (n, _) = self.levels[l];
        let count = match entry {
            SMOOTH => n.div_ceil(2) * n * n,
            REDUCE => 1,
            RESTRICT => self.levels[l - 1].0.pow(3),
            _ => n * n * n,
        };
        ops.push((entry, 2 * l + flag, count));
    }

    fn smooth(&self, ops: &mut Vec<Op>, l: usize, sweeps: u32) {
        for _ in 0..sweeps {
            self.op(ops, SMOOTH, l, 0);
            self.op(ops, SMOOTH, l, 1);
        }
    }

    /// The CPU's `v_cycle` at level `l`.
    fn v_cycle(&self, ops: &mut Vec<Op>, l: usize, sweeps: u32) {
        if l == 0 {
            self.smooth(ops, 0, COARSEST_SWEEPS);
            return;
        }
        self.smooth(ops, l, sweeps);
        self.op(ops, RESIDUAL, l, 0);
        self.op(ops, RESTRICT, l, 0);
        self.op(ops, CLEAR, l - 1, 0);
        self.v_cycle(ops, l - 1, sweeps);
        self.op(ops, PROLONG, l, 1);
        self.smooth(ops, l, sweeps);
    }

    /// Records `ops` in one compute pass.
    fn encode(&self, ops: &[Op]) -> wgpu::CommandEncoder {
        let max_dim = self.ctx.caps.limits.max_compute_workgroups_per_dimension;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            for &(entry, slot, count) in ops {
                let groups = if entry == REDUCE {
                    1
                } else {
                    count.div_ceil(GROUP).max(1)
                };
                let gx = groups.min(max_dim);
                pass.set_pipeline(&self.pipelines[entry]);
                pass.set_bind_group(0, &self.binds[entry][slot], &[]);
                pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
            }
        }
        enc
    }

    /// Runs `ops` (ending with a reduction) and reads `[|r|², |b|²]` back.
    fn norms(&self, ops: &[Op]) -> Result<[f64; 2], GpuError> {
        let mut enc = self.encode(ops);
        enc.copy_buffer_to_buffer(&self.norms, 0, &self.staging_norms, 0, 8);
        self.ctx.queue.submit([enc.finish()]);
        let mut v = [0f32; 2];
        let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut v);
        let read = self
            .ctx
            .read_back(&[(&self.staging_norms, 0..8)], |_, src| {
                dst.copy_from_slice(src);
            });
        self.ctx.check()?;
        read?;
        Ok(v.map(f64::from))
    }

    /// The finest level's `x`.
    fn finest(&self) -> Result<Vec<f32>, GpuError> {
        let &(n, off) = self
            .levels
            .last()
            .ok_or(GpuError::ReadBack("no level".into()))?;
        let bytes = 4 * u64::from(n).pow(3);
        let staging = self.ctx.buffer(
            "poisson-x-staging",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&self.x, 4 * u64::from(off), &staging, 0, bytes);
        self.ctx.queue.submit([enc.finish()]);
        let mut x = vec![0f32; (n as usize).pow(3)];
        let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut x);
        let read = self.ctx.read_back(&[(&staging, 0..bytes)], |_, src| {
            dst.copy_from_slice(src);
        });
        self.ctx.check()?;
        read?;
        Ok(x)
    }
}
