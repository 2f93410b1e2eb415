//! Multi-level Bézier evaluation on the GPU (thesis Sec. 8.5.1): level 3 (binomials) on the
//! CPU, level 2 (Bernstein tables, Algorithm 8) and level 1 (tensor product, Algorithm 7) as
//! WGSL kernels. [`GpuMle`] mirrors `resecta_bezier::MleEvaluator`: the tables stay on the
//! GPU and are rebuilt only when M×N or the resolution change; control-point changes re-run
//! level 1 only. Outputs larger than one storage binding are split into row bands.
//!
//! Level 1 runs as two small products, like the CPU MLE: pass 1a computes Q = P·B^vᵀ
//! (Q_i(b) = Σ_j P_ij B^v_j(b), 3×M×RV, one thread per (i, b)), pass 1b computes
//! S(a, b) = Σ_i B^u_i(a) Q_i(b), each thread a segment of [`ROWS`] rows of one column, in
//! 64-thread workgroups along v. Algorithm 7's original form (16×16 workgroups staging P and
//! basis blocks in workgroup memory between barriers, M·N terms per point) was 10–80× slower
//! on lavapipe, where the barriers and the 4·M·N workgroup-memory loads per point dominated;
//! the two-pass form needs about M·(1 + 3/ROWS) loads per point in 1b (plus 4·M·N·RV in 1a,
//! shared by all RU rows), no workgroup memory and no barriers. ROWS = 4 measured best on
//! lavapipe (1: 2–4× slower; 8: slower again, the accumulators spill).
//!
//! GPU layouts: B^u is M×RU and B^v is N×RV (basis-function major: consecutive threads read
//! consecutive memory); Q is SoA `[c][i][b]`; the surface is AoS `xyz` with index `a·RV + b`,
//! byte-identical to `&[P3<T>]`.
//!
//! Normals ([`GpuMle::evaluate_normals_into`]) use the same two passes with the
//! degree-reduced bases B'^u, B'^v (level 2 of degree M−2, N−2): pass 1a' computes Q and
//! R = ΔvP·B'^vᵀ, pass 1b' computes S, ∂S/∂u = (M−1)·B'^u·ΔQ (Q reused), ∂S/∂v = B^u·R and the
//! unit normal ∂S/∂u × ∂S/∂v with `resecta_bezier::NormalTolerance`'s test in `T`; degenerate
//! samples come back as zero and are repaired on the host by `resecta_bezier::repair_normals`,
//! so the result is the CPU's. Each band then holds four blocks (points, ∂S/∂u, ∂S/∂v,
//! normals), read back together. The control net stays on the GPU: moved points
//! ([`GpuMle::set_control_point`]) are uploaded alone.

use std::ops::Range;
use std::time::{Duration, Instant};

use resecta_bezier::{
    BezierError, ControlNet, MleCounters, MleEvaluator, NormalTolerance, Outputs, P3, Resolution,
    SurfaceGrid, binomial_row, repair_normals,
};
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};
use crate::kernels::GpuScalar;

#[cfg(test)]
pub(crate) mod tests;

/// The WGSL template (f32); see [`shader_source`].
pub const TEMPLATE: &str = include_str!("bezier.wgsl");
/// Rows of one output column computed per level-1b thread (`ROWS` in the WGSL).
pub const ROWS: u32 = 4;
/// Threads per workgroup of both level-1 passes (along v).
const GROUP: u32 = 64;
const BASIS_GROUP: u32 = 256;

/// WGSL source of both kernels for scalar `T`.
pub fn shader_source<T: GpuScalar>() -> String {
    T::specialise(TEMPLATE)
}

/// Uniform block shared by both entry points (32 bytes, no implicit padding).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    m: u32,
    n: u32,
    ru: u32,
    rv: u32,
    row_start: u32,
    row_end: u32,
    band_start: u32,
    band_rows: u32,
}

/// One output buffer holding rows `rows` of the surface (AoS xyz, `RV` points per row), then,
/// once normals were evaluated, ∂S/∂u, ∂S/∂v and the normals of those rows in three more
/// blocks of the same size.
#[derive(Debug)]
pub struct OutputBand {
    rows: Range<usize>,
    buffer: wgpu::Buffer,
    staging: wgpu::Buffer,
    uniform: wgpu::Buffer,
}

impl OutputBand {
    /// Surface rows (u samples) held by this band.
    pub fn rows(&self) -> Range<usize> {
        self.rows.clone()
    }
    /// The storage buffer (usage STORAGE | COPY_SRC), e.g. for rendering or streaming.
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

/// Work chained onto a surface evaluation ([`GpuMle::evaluate_normals_chained`]): passes
/// reading the sample points where the evaluation left them, and a staging buffer read back
/// with the surface's.
pub(crate) trait Chained {
    /// Encodes the passes over `count` points stored as xyz triples at the start of `points`,
    /// and the copy of their results into the staging buffer.
    fn encode(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        points: &wgpu::Buffer,
        count: usize,
    ) -> Result<(), GpuError>;
    /// The staging buffer (MAP_READ, a shared handle) and the byte range to map.
    fn staging(&self) -> (wgpu::Buffer, Range<u64>);
    /// Takes the mapped bytes.
    fn read(&mut self, bytes: &[u8]);
}

/// Control points changed on the host since the last upload.
#[derive(Debug)]
enum Dirty {
    None,
    /// These flat indices only.
    Points(Vec<usize>),
    All,
}

/// What the normals path adds: its pipelines, the degree-reduced level 3–2, R = ΔvP·B'^vᵀ,
/// the normal tolerances, and its bind groups (level 1a', then one per band).
#[derive(Debug)]
struct Normals {
    partial: wgpu::ComputePipeline,
    surface: wgpu::ComputePipeline,
    /// B'^u ((M−1)×RU), B'^v ((N−1)×RV; `None` on isotropy), R (3×M×RV).
    bud: wgpu::Buffer,
    bvd: Option<wgpu::Buffer>,
    r: wgpu::Buffer,
    /// `[small, root_eps]` of `NormalTolerance`, written per evaluation.
    tol: wgpu::Buffer,
    binds: Vec<wgpu::BindGroup>,
}

/// Level-2 tables and what else depends only on M×N and the resolution.
#[derive(Debug)]
struct Level2 {
    bu: wgpu::Buffer,
    /// `None` on isotropy (M = N, RU = RV): B^u is bound as B^v (direct addressing).
    bv: Option<wgpu::Buffer>,
    /// Level-1a partial sums Q = P·B^vᵀ (3×M×RV, SoA), rewritten by every evaluation.
    q: wgpu::Buffer,
    /// Whole-surface parameters (rows 0..RU), read by the basis and level-1a passes.
    uniform: wgpu::Buffer,
}

/// Stateful GPU multi-level evaluator (points, or points, derivatives and unit normals),
/// mirroring `MleEvaluator`.
#[derive(Debug)]
pub struct GpuMle<T: GpuScalar> {
    ctx: GpuContext,
    basis: wgpu::ComputePipeline,
    partial: wgpu::ComputePipeline,
    surface: wgpu::ComputePipeline,
    net: ControlNet<T>,
    resolution: Resolution,
    level3: Option<wgpu::Buffer>,
    level2: Option<Level2>,
    ctrl: Option<wgpu::Buffer>,
    dirty: Dirty,
    uploaded: u64,
    /// Output blocks per band: 1 (points) until normals are asked for, then 4.
    blocks: usize,
    normals: Option<Normals>,
    bands: Vec<OutputBand>,
    /// Level-1a bind group, then one level-1b bind group per band (empty when stale).
    bind_groups: Vec<wgpu::BindGroup>,
    band_limit: u64,
    counters: MleCounters,
}

fn bytes_of<T>(count: usize) -> u64 {
    (count * std::mem::size_of::<T>()) as u64
}

fn u32_of(x: usize) -> u32 {
    // Every count here is bounded by MAX_SAMPLES·3 < 2³².
    u32::try_from(x).unwrap_or(u32::MAX)
}

impl<T: GpuScalar> GpuMle<T> {
    /// Takes the kernels for `T` from `ctx`'s pipeline cache (compiled there on first use);
    /// nothing is evaluated yet.
    /// Errors with [`GpuError::NoF64`] for `f64` on a device without `SHADER_F64`.
    pub fn new(
        ctx: &GpuContext,
        net: ControlNet<T>,
        resolution: Resolution,
    ) -> Result<Self, GpuError> {
        if !T::supported(ctx) {
            return Err(GpuError::NoF64);
        }
        let src = shader_source::<T>();
        let basis = ctx.compute_pipeline("bezier-basis", &src, "basis")?;
        let partial = ctx.compute_pipeline("bezier-partial", &src, "partial_sums")?;
        let surface = ctx.compute_pipeline("bezier-surface", &src, "surface_points")?;
        Ok(Self {
            ctx: ctx.clone(),
            basis,
            partial,
            surface,
            net,
            resolution,
            level3: None,
            level2: None,
            ctrl: None,
            dirty: Dirty::All,
            uploaded: 0,
            blocks: 1,
            normals: None,
            bands: Vec::new(),
            bind_groups: Vec::new(),
            band_limit: ctx.max_binding(),
            counters: MleCounters::default(),
        })
    }
    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
    /// Current control net.
    pub fn net(&self) -> &ControlNet<T> {
        &self.net
    }
    /// Current resolution.
    pub fn resolution(&self) -> Resolution {
        self.resolution
    }
    /// Level computation counts (`level2_derivative` counts the normals path's set-ups).
    pub fn counters(&self) -> MleCounters {
        self.counters
    }
    /// Requirement A: new coordinates, same M×N; levels 2–3 stay on the GPU.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        self.net.set_points(points)?;
        self.dirty = Dirty::All;
        Ok(())
    }
    /// Requirement A for one point: the next evaluation uploads only the points moved so.
    pub fn set_control_point(&mut self, i: usize, j: usize, p: P3<T>) -> Result<(), BezierError> {
        self.net.set(i, j, p)?;
        let k = i * self.net.n() + j;
        match &mut self.dirty {
            Dirty::Points(ks) if !ks.contains(&k) => ks.push(k),
            Dirty::None => self.dirty = Dirty::Points(vec![k]),
            Dirty::Points(_) | Dirty::All => {}
        }
        Ok(())
    }
    /// Control-point bytes uploaded to the device so far.
    pub fn uploaded_bytes(&self) -> u64 {
        self.uploaded
    }
    /// Requirement B: a new resolution drops level 2 and the output buffers.
    pub fn set_resolution(&mut self, resolution: Resolution) {
        if resolution != self.resolution {
            self.resolution = resolution;
            self.level2 = None;
            self.normals = None;
            self.bands.clear();
            self.drop_binds();
        }
    }
    /// Requirement C: another M×N drops levels 3 and 2; same M×N acts like A.
    pub fn set_net(&mut self, net: ControlNet<T>) {
        if net.dims() != self.net.dims() {
            self.level3 = None;
            self.level2 = None;
            self.normals = None;
            self.ctrl = None;
            self.drop_binds();
        }
        self.net = net;
        self.dirty = Dirty::All;
    }

    fn drop_binds(&mut self) {
        self.bind_groups.clear();
        if let Some(d) = &mut self.normals {
            d.binds.clear();
        }
    }

    /// Caps the bytes per output band (at most the device's storage binding size; at least
    /// one row is kept per band). Drops the output buffers.
    pub fn set_band_limit(&mut self, bytes: u64) {
        self.band_limit = bytes.min(self.ctx.max_binding());
        self.bands.clear();
        self.drop_binds();
    }

    /// Output bands (empty before the first evaluation after a resolution change).
    pub fn bands(&self) -> &[OutputBand] {
        &self.bands
    }

    fn buffer(&self, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.ctx.buffer(label, size, usage)
    }

    fn check_size(&self, what: &'static str, bytes: u64) -> Result<(), GpuError> {
        let limit = self.ctx.max_binding();
        if bytes > limit {
            return Err(GpuError::TooLarge { what, bytes, limit });
        }
        Ok(())
    }

    fn params(&self, rows: Range<usize>, band: Range<usize>) -> Params {
        let (m, n) = self.net.dims();
        Params {
            m: u32_of(m),
            n: u32_of(n),
            ru: u32_of(self.resolution.ru()),
            rv: u32_of(self.resolution.rv()),
            row_start: u32_of(rows.start),
            row_end: u32_of(rows.end),
            band_start: u32_of(band.start),
            band_rows: u32_of(band.len()),
        }
    }

    /// Builds whatever is missing: level 3, level 2 (GPU kernel), control-point buffer (and
    /// upload when changed), output bands and bind groups.
    fn ensure(&mut self) -> Result<(), GpuError> {
        let (m, n) = self.net.dims();
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let storage = wgpu::BufferUsages::STORAGE;
        if self.level3.is_none() {
            self.counters.level3 += 1;
            let binoms: Vec<T> = binomial_row(m)
                .into_iter()
                .chain(binomial_row(n))
                .map(|c| T::from_f64(c as f64))
                .collect();
            let buf = self
                .ctx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("bezier-level3"),
                    contents: bytemuck::cast_slice(&binoms),
                    usage: storage,
                });
            self.level3 = Some(buf);
            self.level2 = None;
        }
        if self.level2.is_none() {
            self.build_level2()?;
            self.drop_binds();
        }
        if self.ctrl.is_none() {
            let size = bytes_of::<T>(3 * m * n);
            self.ctrl =
                Some(self.buffer("bezier-ctrl", size, storage | wgpu::BufferUsages::COPY_DST));
            self.dirty = Dirty::All;
            self.drop_binds();
        }
        if let Some(ctrl) = &self.ctrl {
            let pts = self.net.points();
            let mut write = |k: usize, p: &[P3<T>]| {
                let bytes: &[u8] = bytemuck::cast_slice(p.as_flattened());
                self.ctx
                    .queue
                    .write_buffer(ctrl, bytes_of::<P3<T>>(k), bytes);
                self.uploaded += bytes.len() as u64;
            };
            match std::mem::replace(&mut self.dirty, Dirty::None) {
                Dirty::None => {}
                Dirty::Points(ks) => ks.iter().for_each(|&k| write(k, &pts[k..=k])),
                Dirty::All => write(0, pts),
            }
        }
        if self.bands.is_empty() {
            let row_bytes = bytes_of::<T>(3 * rv * self.blocks);
            self.check_size("one surface row", row_bytes)?;
            let rows_per_band = usize::try_from(self.band_limit / row_bytes)
                .unwrap_or(usize::MAX)
                .clamp(1, ru);
            let mut start = 0;
            while start < ru {
                let end = (start + rows_per_band).min(ru);
                let size = row_bytes * (end - start) as u64;
                let band = OutputBand {
                    rows: start..end,
                    buffer: self.buffer(
                        "bezier-surface",
                        size,
                        storage | wgpu::BufferUsages::COPY_SRC,
                    ),
                    staging: self.buffer(
                        "bezier-staging",
                        size,
                        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    ),
                    uniform: self.buffer(
                        "bezier-params",
                        std::mem::size_of::<Params>() as u64,
                        wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    ),
                };
                self.bands.push(band);
                start = end;
            }
            self.drop_binds();
        }
        if self.bind_groups.is_empty() {
            let (Some(l2), Some(ctrl)) = (&self.level2, &self.ctrl) else {
                return Err(GpuError::Pipeline("levels missing".into()));
            };
            let bv = l2.bv.as_ref().unwrap_or(&l2.bu);
            let device = &self.ctx.device;
            let partial = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bezier-partial"),
                layout: &self.partial.get_bind_group_layout(0),
                entries: &[
                    entry(0, &l2.uniform),
                    entry(1, ctrl),
                    entry(2, bv),
                    entry(3, &l2.q),
                ],
            });
            let layout = self.surface.get_bind_group_layout(0);
            let bands = self.bands.iter().map(|band| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("bezier-surface"),
                    layout: &layout,
                    entries: &[
                        entry(0, &band.uniform),
                        entry(1, &l2.q),
                        entry(2, &l2.bu),
                        entry(3, &band.buffer),
                    ],
                })
            });
            self.bind_groups = std::iter::once(partial).chain(bands).collect();
        }
        Ok(())
    }

    /// Level 2 on the GPU (Algorithm 8), with direct addressing of B^u on isotropy.
    fn build_level2(&mut self) -> Result<(), GpuError> {
        let (m, n) = self.net.dims();
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let Some(binom) = &self.level3 else {
            return Err(GpuError::Pipeline("level 3 missing".into()));
        };
        self.counters.level2 += 1;
        self.check_size("Q", bytes_of::<T>(3 * m * rv))?;
        let (bu, bv) = self.bernstein_tables(m, n, binom)?;
        let uniform = self
            .ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("bezier-basis-params"),
                contents: bytemuck::bytes_of(&self.params(0..ru, 0..ru)),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let q = self.buffer(
            "bezier-q",
            bytes_of::<T>(3 * m * rv),
            wgpu::BufferUsages::STORAGE,
        );
        self.level2 = Some(Level2 { bu, bv, q, uniform });
        Ok(())
    }

    /// Bernstein tables of `mm` functions along u and `nn` along v (basis-function major) from
    /// the binomials `binom` (`[C(mm−1, ·) | C(nn−1, ·)]`); B^v is `None` on isotropy (B^u
    /// serves as both).
    fn bernstein_tables(
        &self,
        mm: usize,
        nn: usize,
        binom: &wgpu::Buffer,
    ) -> Result<(wgpu::Buffer, Option<wgpu::Buffer>), GpuError> {
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let iso = mm == nn && ru == rv;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        self.check_size("B^u", bytes_of::<T>(mm * ru))?;
        self.check_size("B^v", bytes_of::<T>(nn * rv))?;
        let bu = self.buffer("bezier-bu", bytes_of::<T>(mm * ru), storage);
        let bv = (!iso).then(|| self.buffer("bezier-bv", bytes_of::<T>(nn * rv), storage));
        let params = Params {
            m: u32_of(mm),
            n: u32_of(nn),
            ..self.params(0..ru, 0..ru)
        };
        let uniform = self
            .ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("bezier-basis-params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let bind = self
            .ctx
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bezier-basis"),
                layout: &self.basis.get_bind_group_layout(0),
                entries: &[
                    entry(0, &uniform),
                    entry(1, binom),
                    entry(2, &bu),
                    // On isotropy the v half of the dispatch is skipped; bind B^u as a stand-in.
                    entry(3, bv.as_ref().unwrap_or(&bu)),
                ],
            });
        let work = (mm * ru).max(if iso { 0 } else { nn * rv });
        let groups = u32_of(work.div_ceil(BASIS_GROUP as usize));
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.basis);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(groups, if iso { 1 } else { 2 }, 1);
        }
        self.ctx.queue.submit([enc.finish()]);
        Ok((bu, bv))
    }

    /// Encodes level 1 for `rows`: 1a (Q = P·B^vᵀ) once, 1b per band (clipped); with `copy`,
    /// also copies the computed bytes into each band's staging buffer. Returns (band, byte
    /// range) pairs touched.
    fn encode_rows(
        &self,
        rows: Range<usize>,
        copy: bool,
    ) -> (wgpu::CommandEncoder, Vec<(usize, Range<u64>)>) {
        let (m, _) = self.net.dims();
        let rv = self.resolution.rv();
        let row_bytes = bytes_of::<T>(3 * rv);
        let columns = u32_of(rv.div_ceil(GROUP as usize));
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        let mut touched = Vec::new();
        let Some((partial, band_binds)) = self.bind_groups.split_first() else {
            return (enc, touched);
        };
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.partial);
            pass.set_bind_group(0, partial, &[]);
            pass.dispatch_workgroups(columns, u32_of(m), 1);
        }
        for (k, (band, bind)) in self.bands.iter().zip(band_binds).enumerate() {
            let lo = rows.start.max(band.rows.start);
            let hi = rows.end.min(band.rows.end);
            if lo >= hi {
                continue;
            }
            let params = self.params(lo..hi, band.rows.clone());
            self.ctx
                .queue
                .write_buffer(&band.uniform, 0, bytemuck::bytes_of(&params));
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.surface);
                pass.set_bind_group(0, bind, &[]);
                pass.dispatch_workgroups(columns, u32_of((hi - lo).div_ceil(ROWS as usize)), 1);
            }
            let bytes = row_bytes * (lo - band.rows.start) as u64
                ..row_bytes * (hi - band.rows.start) as u64;
            if copy {
                enc.copy_buffer_to_buffer(
                    &band.buffer,
                    bytes.start,
                    &band.staging,
                    bytes.start,
                    bytes.end - bytes.start,
                );
            }
            touched.push((k, bytes));
        }
        (enc, touched)
    }

    fn check_rows(&self, rows: &Range<usize>, out_len: usize) -> Result<(), GpuError> {
        let ru = self.resolution.ru();
        if rows.start >= rows.end || rows.end > ru {
            return Err(BezierError::IndexOutOfRange {
                i: rows.start,
                j: rows.end,
                m: ru,
                n: self.resolution.rv(),
            }
            .into());
        }
        let expected = (rows.end - rows.start) * self.resolution.rv();
        if out_len != expected {
            return Err(BezierError::BufferLength {
                expected,
                got: out_len,
            }
            .into());
        }
        Ok(())
    }

    /// Surface points of all RU·RV samples into `out` (index `a·RV + b`): uploads changed
    /// control points, runs level 1 (and levels 2–3 when stale), reads back.
    pub fn evaluate_points_into(&mut self, out: &mut [P3<T>]) -> Result<(), GpuError> {
        self.evaluate_rows_into(0..self.resolution.ru(), out)
    }

    /// Rows `rows` (u samples) only, into `out` of `rows.len()·RV` points (for tiling).
    pub fn evaluate_rows_into(
        &mut self,
        rows: Range<usize>,
        out: &mut [P3<T>],
    ) -> Result<(), GpuError> {
        self.check_rows(&rows, out.len())?;
        self.ctx.check()?;
        self.ensure()?;
        self.counters.level1 += 1;
        let (enc, touched) = self.encode_rows(rows, true);
        self.ctx.queue.submit([enc.finish()]);
        // MAP_ALIGNMENT is 8: map from the aligned-down offset and skip the head.
        let maps: Vec<_> = touched
            .iter()
            .map(|(k, r)| (&self.bands[*k].staging, (r.start & !7)..r.end))
            .collect();
        let dst: &mut [u8] = bytemuck::cast_slice_mut(out.as_flattened_mut());
        let mut at = 0;
        self.ctx.read_back(&maps, |k, bytes| {
            let skip = (touched[k].1.start & 7) as usize;
            let src = &bytes[skip..];
            dst[at..at + src.len()].copy_from_slice(src);
            at += src.len();
        })?;
        self.ctx.check()
    }

    /// Builds what the normals path adds to [`GpuMle::ensure`] (after it): pipelines (cached on
    /// the context), the degree-reduced tables, R, and its bind groups; writes the normal
    /// tolerances.
    fn ensure_normals(&mut self) -> Result<(), GpuError> {
        let (m, n) = self.net.dims();
        let rv = self.resolution.rv();
        if self.normals.is_none() {
            self.counters.level2_derivative += 1;
            let src = shader_source::<T>();
            let partial = self
                .ctx
                .compute_pipeline("bezier-partial-d", &src, "partial_sums_d")?;
            let surface = self
                .ctx
                .compute_pipeline("bezier-normals", &src, "surface_normals")?;
            let binoms: Vec<T> = binomial_row(m - 1)
                .into_iter()
                .chain(binomial_row(n - 1))
                .map(|c| T::from_f64(c as f64))
                .collect();
            let binom = self
                .ctx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("bezier-level3-d"),
                    contents: bytemuck::cast_slice(&binoms),
                    usage: wgpu::BufferUsages::STORAGE,
                });
            let (bud, bvd) = self.bernstein_tables(m - 1, n - 1, &binom)?;
            let r = self.buffer(
                "bezier-r",
                bytes_of::<T>(3 * m * rv),
                wgpu::BufferUsages::STORAGE,
            );
            let tol = self.buffer(
                "bezier-tol",
                bytes_of::<T>(2),
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            );
            self.normals = Some(Normals {
                partial,
                surface,
                bud,
                bvd,
                r,
                tol,
                binds: Vec::new(),
            });
        }
        let (Some(l2), Some(ctrl), Some(d)) = (&self.level2, &self.ctrl, &mut self.normals) else {
            return Err(GpuError::Pipeline("levels missing".into()));
        };
        let tol = NormalTolerance::of(&self.net);
        self.ctx
            .queue
            .write_buffer(&d.tol, 0, bytemuck::cast_slice(&[tol.small, tol.root_eps]));
        if d.binds.is_empty() {
            let device = &self.ctx.device;
            let partial = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bezier-partial-d"),
                layout: &d.partial.get_bind_group_layout(0),
                entries: &[
                    entry(0, &l2.uniform),
                    entry(1, ctrl),
                    entry(2, l2.bv.as_ref().unwrap_or(&l2.bu)),
                    entry(3, &l2.q),
                    entry(4, d.bvd.as_ref().unwrap_or(&d.bud)),
                    entry(5, &d.r),
                ],
            });
            let layout = d.surface.get_bind_group_layout(0);
            let bands = self.bands.iter().map(|band| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("bezier-normals"),
                    layout: &layout,
                    entries: &[
                        entry(0, &band.uniform),
                        entry(1, &l2.q),
                        entry(2, &l2.bu),
                        entry(3, &band.buffer),
                        entry(4, &d.r),
                        entry(5, &d.bud),
                        entry(6, &d.tol),
                    ],
                })
            });
            d.binds = std::iter::once(partial).chain(bands).collect();
        }
        Ok(())
    }

    /// Points, ∂S/∂u, ∂S/∂v and unit normals of all samples into `grid` (made with
    /// [`Outputs::Normals`] at this resolution), with one read-back; degenerate normals are
    /// repaired on the host as the CPU does (`resecta_bezier::repair_normals`).
    pub fn evaluate_normals_into(&mut self, grid: &mut SurfaceGrid<T>) -> Result<(), GpuError> {
        self.evaluate_normals(grid, None).map(|_| ())
    }

    /// [`GpuMle::evaluate_normals_into`] with `chained` encoded after the surface passes in the
    /// same submission and read back with it: `Ok(true)`. A surface held in several output
    /// bands (beyond the binding limit) is evaluated alone: `Ok(false)`, `chained` untouched.
    pub(crate) fn evaluate_normals_chained(
        &mut self,
        grid: &mut SurfaceGrid<T>,
        chained: &mut dyn Chained,
    ) -> Result<bool, GpuError> {
        self.evaluate_normals(grid, Some(chained))
    }

    fn evaluate_normals(
        &mut self,
        grid: &mut SurfaceGrid<T>,
        mut chained: Option<&mut dyn Chained>,
    ) -> Result<bool, GpuError> {
        let res = self.resolution;
        if grid.resolution() != res {
            return Err(BezierError::BufferLength {
                expected: res.len(),
                got: grid.resolution().len(),
            }
            .into());
        }
        if grid.outputs() != Outputs::Normals {
            return Err(BezierError::MissingOutput("normals").into());
        }
        self.ctx.check()?;
        if self.blocks != 4 {
            self.blocks = 4;
            self.bands.clear();
            self.drop_binds();
        }
        self.ensure()?;
        self.ensure_normals()?;
        self.counters.level1 += 1;
        let (Some(d), Some((partial, band_binds))) = (
            &self.normals,
            self.normals.as_ref().and_then(|d| d.binds.split_first()),
        ) else {
            return Err(GpuError::Pipeline("normal bind groups missing".into()));
        };
        let (m, _) = self.net.dims();
        let rv = res.rv();
        let columns = u32_of(rv.div_ceil(GROUP as usize));
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&d.partial);
            pass.set_bind_group(0, partial, &[]);
            pass.dispatch_workgroups(columns, u32_of(m), 1);
        }
        for (band, bind) in self.bands.iter().zip(band_binds) {
            let params = self.params(band.rows.clone(), band.rows.clone());
            self.ctx
                .queue
                .write_buffer(&band.uniform, 0, bytemuck::bytes_of(&params));
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&d.surface);
                pass.set_bind_group(0, bind, &[]);
                let groups = u32_of(band.rows.len().div_ceil(ROWS as usize));
                pass.dispatch_workgroups(columns, groups, 1);
            }
            enc.copy_buffer_to_buffer(&band.buffer, 0, &band.staging, 0, band.buffer.size());
        }
        if self.bands.len() != 1 {
            chained = None;
        }
        let chained_staging = match (&mut chained, self.bands.first()) {
            (Some(c), Some(band)) => {
                c.encode(&mut enc, &band.buffer, res.len())?;
                Some(c.staging())
            }
            _ => None,
        };
        self.ctx.queue.submit([enc.finish()]);
        let maps: Vec<_> = self
            .bands
            .iter()
            .map(|b| (&b.staging, 0..b.staging.size()))
            .chain(chained_staging.as_ref().map(|(b, r)| (b, r.clone())))
            .collect();
        let (points, du, dv, normals) = grid.parts_mut();
        let (Some(du), Some(dv), Some(normals)) = (du, dv, normals) else {
            return Err(BezierError::MissingOutput("derivatives").into());
        };
        let mut outs = [points, du, dv, normals];
        let bands = &self.bands;
        let ran = chained.is_some();
        self.ctx.read_back(&maps, |k, bytes| {
            let Some(band) = bands.get(k) else {
                if let Some(c) = chained.as_mut() {
                    c.read(bytes);
                }
                return;
            };
            let rows = &band.rows;
            let block = bytes.len() / 4;
            for (out, src) in outs.iter_mut().zip(bytes.chunks_exact(block)) {
                let dst = out[rows.start * rv..rows.end * rv].as_flattened_mut();
                bytemuck::cast_slice_mut::<T, u8>(dst).copy_from_slice(src);
            }
        })?;
        // A device that failed during the evaluation may have left anything in the buffers.
        self.ctx.check()?;
        repair_normals(&self.net, res, outs[3]);
        Ok(ran)
    }

    /// Runs level 1 and leaves the result on the GPU (see [`GpuMle::bands`]); submitted, not
    /// awaited: later GPU work on the same queue sees the result.
    pub fn evaluate_resident(&mut self) -> Result<&[OutputBand], GpuError> {
        self.ctx.check()?;
        self.ensure()?;
        self.counters.level1 += 1;
        let (enc, _) = self.encode_rows(0..self.resolution.ru(), false);
        self.ctx.queue.submit([enc.finish()]);
        Ok(&self.bands)
    }

    /// One evaluation into `out`, timed from upload to read-back completion (transfer
    /// included): wall-clock time of [`GpuMle::evaluate_points_into`].
    pub fn evaluate_timed(&mut self, out: &mut [P3<T>]) -> Result<Duration, GpuError> {
        let t = Instant::now();
        self.evaluate_points_into(out)?;
        Ok(t.elapsed())
    }

    /// Reads the GPU's level-2 tables back in the CPU layout (row-major B^u: RU×M, B^v: RV×N),
    /// building them first when stale.
    pub fn basis_tables(&mut self) -> Result<(Vec<T>, Vec<T>), GpuError> {
        self.ensure()?;
        let (m, n) = self.net.dims();
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let Some(l2) = &self.level2 else {
            return Err(GpuError::Pipeline("level 2 missing".into()));
        };
        let bv = l2.bv.as_ref().unwrap_or(&l2.bu);
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        let mut staging = Vec::new();
        for (src, count) in [(&l2.bu, m * ru), (bv, n * rv)] {
            let size = bytes_of::<T>(count);
            let st = self.buffer(
                "bezier-basis-staging",
                size,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            enc.copy_buffer_to_buffer(src, 0, &st, 0, size);
            staging.push((st, size));
        }
        self.ctx.queue.submit([enc.finish()]);
        let maps: Vec<_> = staging.iter().map(|(b, s)| (b, 0..*s)).collect();
        let mut tables: [Vec<T>; 2] = [Vec::new(), Vec::new()];
        self.ctx.read_back(&maps, |k, bytes| {
            let vals: Vec<T> = bytemuck::pod_collect_to_vec(bytes);
            let (count, r) = if k == 0 { (m, ru) } else { (n, rv) };
            // GPU layout is count×r; transpose to r×count.
            tables[k] = (0..r * count)
                .map(|x| vals[(x % count) * r + x / count])
                .collect();
        })?;
        self.ctx.check()?;
        let [u, v] = tables;
        Ok((u, v))
    }
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// The MLE evaluator on whichever side is available: callers never care which.
#[derive(Debug)]
pub enum BezierBackend<T: GpuScalar> {
    /// `resecta_bezier::MleEvaluator` (rayon).
    Cpu(Box<MleEvaluator<T>>),
    /// [`GpuMle`] (wgpu).
    Gpu(Box<GpuMle<T>>),
}

impl<T: GpuScalar> BezierBackend<T> {
    /// GPU when `ctx` is given, supports `T` and the kernels compile; the CPU otherwise.
    pub fn new(ctx: Option<&GpuContext>, net: ControlNet<T>, resolution: Resolution) -> Self {
        match ctx.map(|c| GpuMle::new(c, net.clone(), resolution)) {
            Some(Ok(g)) => Self::Gpu(Box::new(g)),
            _ => Self::Cpu(Box::new(MleEvaluator::new(net, resolution))),
        }
    }
    /// `"wgpu"` or `"cpu"`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Cpu(_) => "cpu",
            Self::Gpu(_) => "wgpu",
        }
    }
    /// Current control net.
    pub fn net(&self) -> &ControlNet<T> {
        match self {
            Self::Cpu(e) => e.net(),
            Self::Gpu(g) => g.net(),
        }
    }
    /// Current resolution.
    pub fn resolution(&self) -> Resolution {
        match self {
            Self::Cpu(e) => e.resolution(),
            Self::Gpu(g) => g.resolution(),
        }
    }
    /// Level computation counts.
    pub fn counters(&self) -> MleCounters {
        match self {
            Self::Cpu(e) => e.counters(),
            Self::Gpu(g) => g.counters(),
        }
    }
    /// Requirement A.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        match self {
            Self::Cpu(e) => e.set_control_points(points),
            Self::Gpu(g) => g.set_control_points(points),
        }
    }
    /// Requirement B.
    pub fn set_resolution(&mut self, resolution: Resolution) {
        match self {
            Self::Cpu(e) => e.set_resolution(resolution),
            Self::Gpu(g) => g.set_resolution(resolution),
        }
    }
    /// Requirement C.
    pub fn set_net(&mut self, net: ControlNet<T>) {
        match self {
            Self::Cpu(e) => e.set_net(net),
            Self::Gpu(g) => g.set_net(net),
        }
    }
    /// Surface points into `out` (RU·RV, index `a·RV + b`).
    pub fn evaluate_points_into(&mut self, out: &mut [P3<T>]) -> Result<(), GpuError> {
        match self {
            Self::Cpu(e) => Ok(e.evaluate_points_into(out)?),
            Self::Gpu(g) => g.evaluate_points_into(out),
        }
    }
}

/// Benchmark wrapper matching `resecta_bezier::Prepared`: the evaluator plus its output, warm
/// after construction, so [`GpuPrepared::run`] times one update (upload, level 1, read-back).
#[derive(Debug)]
pub struct GpuPrepared<T: GpuScalar> {
    mle: GpuMle<T>,
    out: Vec<P3<T>>,
}

impl<T: GpuScalar> GpuPrepared<T> {
    /// Builds levels 3–2 and output buffers and runs once (warm-up).
    pub fn new(
        ctx: &GpuContext,
        net: ControlNet<T>,
        resolution: Resolution,
    ) -> Result<Self, GpuError> {
        let mut p = Self {
            mle: GpuMle::new(ctx, net, resolution)?,
            out: vec![[T::ZERO; 3]; resolution.len()],
        };
        p.run()?;
        Ok(p)
    }
    /// One evaluation including control-point upload and read-back into host memory.
    pub fn run(&mut self) -> Result<(), GpuError> {
        self.mle.evaluate_points_into(&mut self.out)
    }
    /// One evaluation left on the GPU, waited for (no read-back): kernel-plus-upload time.
    pub fn run_resident(&mut self) -> Result<(), GpuError> {
        self.mle.evaluate_resident()?;
        self.mle.context().wait()
    }
    /// Moves the control points (requirement A).
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        self.mle.set_control_points(points)
    }
    /// Result of the last [`GpuPrepared::run`].
    pub fn output(&self) -> &[P3<T>] {
        &self.out
    }
    /// The evaluator.
    pub fn evaluator(&mut self) -> &mut GpuMle<T> {
        &mut self.mle
    }
}
