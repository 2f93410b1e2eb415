//! The band and side components of a volumetry cut on the GPU: [`GpuVolumetry`] implements
//! `resecta_volumetry::CutAccelerator`, whose CPU twin is `Volumetry`'s own splat and
//! union–find (the seam's contract is in `resecta_volumetry::accel`).
//!
//! Design: the liver is uploaded once, bit-packed over its bounding box (per 32 cells their
//! liver bits and the compact index of the first: 8 bytes, a compact index by one popcount);
//! the samples' slab-discs (computed on the host by the CPU's code) once per cut. Per cut, one
//! submission runs: `band_min` and `band_arg` (one invocation per sample walking its slab-disc
//! as the CPU does: f64, the CPU's operations in its order, the squared distance rounded to
//! f32 ties-to-even by hand; the nearest sample by integer atomicMax on the complemented f32
//! bits, then on the complemented index — deterministic, ties to the smallest index, as the
//! CPU's strict `<` in sample order; a voxel's first index write lists it), `cc_init`,
//! `cc_union` and `cc_flatten` (union–find on the non-band liver voxels with atomicMin on
//! parents, each root its component's smallest compact index, as the CPU's; as there, runs
//! along x first, joined once per overlap; the roots listed) and `collect` (per listed band
//! voxel its nearest sample and the roots of its face neighbours); one read-back. The host then
//! computes fractions, sides, leaks and islands by the CPU's code, and `mark` writes the
//! resected voxels as a bit set: the second read-back.
//!
//! Exactness: membership and nearest samples are the CPU's as long as the device computes the
//! same IEEE f64 operations (lavapipe does; a device that fuses multiply-adds may differ at
//! exact ties, which the host catches where a band voxel falls outside its disc — the cut then
//! goes to the CPU). Volumes therefore equal the CPU's bit for bit in the tests. f64 only:
//! without `SHADER_F64` [`GpuVolumetry::new`] fails with [`GpuError::NoF64`] (an f32 band would
//! not match the CPU's decisions). Three per-voxel work arrays of 4 bytes per liver voxel must
//! each fit one storage binding (33 M liver voxels on lavapipe's 128 MiB); larger livers give
//! [`GpuError::TooLarge`], and the CPU computes their cuts.

use resecta_volumetry::{
    AcceleratorError, AcceleratorFactory, BandComponents, BandQuery, BandVoxel, CutAccelerator,
    LiverVoxels,
};
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};

#[cfg(test)]
mod tests;

/// The WGSL source.
pub const SOURCE: &str = include_str!("volumetry.wgsl");
/// Invocations per workgroup (`GROUP` in the WGSL).
const GROUP: u32 = 64;
/// Most workgroups along one dispatch dimension.
const MAX_GROUPS: u32 = 65_535;
/// f64 words per sample (`STRIDE` in the WGSL).
const STRIDE: usize = 18;
/// u32 words per band voxel in the output.
const BAND_WORDS: usize = 8;

/// Uniform block (192 bytes, no implicit padding). Mirrors `Params` in the WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    origin: [f64; 4],
    cols: [[f64; 4]; 3],
    lo: [u32; 4],
    dims: [u32; 4],
    caps: [u32; 4],
    pad: [u32; 4],
}

/// Entry points and the bindings each uses.
const ENTRIES: [(&str, &[u32]); 7] = [
    ("band_min", &[0, 1, 2, 3, 4, 6, 7]),
    ("band_arg", &[0, 1, 2, 3, 4, 6, 7]),
    ("cc_init", &[0, 1, 5, 11]),
    ("cc_union", &[0, 1, 5, 11]),
    ("cc_flatten", &[0, 5, 6, 8, 11]),
    ("collect", &[0, 1, 4, 6, 7, 11, 12]),
    ("mark", &[0, 9, 10, 11, 12]),
];

/// The liver resident on the device, with the per-voxel work buffers.
#[derive(Debug)]
struct Liver {
    /// `LiverVoxels::box_index` address and length, to notice another liver.
    key: (usize, usize),
    cells: u32,
    voxels: u32,
    /// Per 32 bounding-box cells: their liver bits, the compact index of the first.
    cell_words: wgpu::Buffer,
    dkey: wgpu::Buffer,
    kkey: wgpu::Buffer,
    parent: wgpu::Buffer,
    mask: wgpu::Buffer,
    mask_staging: wgpu::Buffer,
}

/// Per-cut buffers, grown as needed.
#[derive(Debug)]
struct Io {
    samples_cap: usize,
    band_cap: usize,
    roots_cap: usize,
    resected_cap: usize,
    samples: wgpu::Buffer,
    counts: wgpu::Buffer,
    band: wgpu::Buffer,
    roots: wgpu::Buffer,
    resected: wgpu::Buffer,
    staging: wgpu::Buffer,
}

/// A volumetry accelerator on the GPU (f64): install it with
/// `Volumetry::with_accelerator(Box::new(GpuVolumetry::new(&ctx)?))`, one per liver.
#[derive(Debug)]
pub struct GpuVolumetry {
    ctx: GpuContext,
    pipelines: Vec<wgpu::ComputePipeline>,
    uniform: wgpu::Buffer,
    params: Params,
    liver: Option<Liver>,
    io: Option<Io>,
    /// Band and roots capacities of the next cut (grown to what cuts needed).
    band_cap: usize,
    roots_cap: usize,
}

fn too_large(what: &'static str, bytes: usize, limit: u64) -> GpuError {
    GpuError::TooLarge {
        what,
        bytes: bytes as u64,
        limit,
    }
}

fn u32_of(what: &'static str, x: usize) -> Result<u32, GpuError> {
    crate::kernels::u32_index(what, x)
}

fn accel(e: GpuError) -> AcceleratorError {
    AcceleratorError(e.to_string())
}

impl GpuVolumetry {
    /// Compiles the kernels. Errors with [`GpuError::NoF64`] without `SHADER_F64`.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        if !ctx.caps.f64 {
            return Err(GpuError::NoF64);
        }
        ctx.check()?;
        let pipelines = ENTRIES
            .iter()
            .map(|(entry, _)| ctx.compute_pipeline("volumetry", SOURCE, entry))
            .collect::<Result<_, _>>()?;
        let uniform = ctx.buffer(
            "volumetry-params",
            std::mem::size_of::<Params>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        Ok(Self {
            ctx: ctx.clone(),
            pipelines,
            uniform,
            params: Params::default(),
            liver: None,
            io: None,
            band_cap: 4096,
            roots_cap: 256,
        })
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    fn buffer(&self, label: &str, bytes: usize, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.ctx
            .buffer(label, (bytes.max(4) as u64).next_multiple_of(4), usage)
    }

    /// Uploads `liver` unless it is resident.
    fn ensure_liver(&mut self, liver: &LiverVoxels) -> Result<(), GpuError> {
        let index = liver.box_index();
        let key = (index.as_ptr() as usize, index.len());
        if self.liver.as_ref().is_some_and(|l| l.key == key) {
            return Ok(());
        }
        self.liver = None;
        let limit = self.ctx.max_binding();
        let n = liver.len();
        let mut words = vec![[0u32; 2]; index.len().div_ceil(32)];
        let mut count = 0u32;
        for (w, chunk) in words.iter_mut().zip(index.chunks(32)) {
            w[1] = count;
            for (bit, &c) in chunk.iter().enumerate() {
                if c != u32::MAX {
                    w[0] |= 1 << bit;
                    count += 1;
                }
            }
        }
        for (what, bytes) in [
            ("volumetry cells", 8 * words.len()),
            ("volumetry voxels", 4 * n),
        ] {
            if bytes as u64 > limit {
                return Err(too_large(what, bytes, limit));
            }
        }
        let grid = liver.grid();
        let lin = grid.linear();
        let o = grid.origin();
        let lo = liver.box_lo();
        let dims = liver.bdims();
        self.params.origin = [o.x, o.y, o.z, 0.0];
        for (a, col) in self.params.cols.iter_mut().enumerate() {
            *col = [lin[(0, a)], lin[(1, a)], lin[(2, a)], 0.0];
        }
        for a in 0..3 {
            self.params.lo[a] = u32_of("volumetry box", lo[a])?;
            self.params.dims[a] = u32_of("volumetry box", dims[a])?;
        }
        let cells = u32_of("volumetry box", index.len())?;
        let voxels = u32_of("volumetry voxels", n)?;
        self.params.dims[3] = voxels;
        use wgpu::BufferUsages as U;
        let work = U::STORAGE | U::COPY_DST;
        let mask_bytes = 4 * n.div_ceil(32);
        let resident = Liver {
            key,
            cells,
            voxels,
            cell_words: self
                .ctx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("volumetry-cells"),
                    contents: bytemuck::cast_slice(&words),
                    usage: U::STORAGE,
                }),
            dkey: self.buffer("volumetry-dkey", 4 * n, work),
            kkey: self.buffer("volumetry-kkey", 4 * n, work),
            parent: self.buffer("volumetry-parent", 4 * n, work),
            mask: self.buffer("volumetry-mask", mask_bytes, work | U::COPY_SRC),
            mask_staging: self.buffer(
                "volumetry-mask-staging",
                mask_bytes,
                U::MAP_READ | U::COPY_DST,
            ),
        };
        self.liver = Some(resident);
        Ok(())
    }

    /// Per-cut buffers for `samples` samples and the current capacities.
    fn ensure_io(&mut self, samples: usize, resected: usize) -> Result<(), GpuError> {
        let fits = self.io.as_ref().is_some_and(|io| {
            io.samples_cap >= samples
                && io.band_cap >= self.band_cap
                && io.roots_cap >= self.roots_cap
                && io.resected_cap >= resected
        });
        if fits {
            return Ok(());
        }
        let old = self.io.take();
        let keep = |f: fn(&Io) -> usize| old.as_ref().map_or(0, f);
        let samples_cap = samples.max(keep(|io| io.samples_cap));
        let band_cap = self.band_cap.max(keep(|io| io.band_cap));
        let roots_cap = self.roots_cap.max(keep(|io| io.roots_cap));
        let resected_cap = resected.max(keep(|io| io.resected_cap)).max(1);
        let limit = self.ctx.max_binding();
        let sizes = [
            ("volumetry samples", 8 * STRIDE * samples_cap),
            ("volumetry band", 4 * BAND_WORDS * band_cap),
            ("volumetry roots", 4 * roots_cap),
        ];
        for (what, bytes) in sizes {
            if bytes as u64 > limit {
                return Err(too_large(what, bytes, limit));
            }
        }
        use wgpu::BufferUsages as U;
        let out = U::STORAGE | U::COPY_SRC | U::COPY_DST;
        let staging_bytes = 8 + sizes[1].1 + sizes[2].1;
        self.io = Some(Io {
            samples_cap,
            band_cap,
            roots_cap,
            resected_cap,
            samples: self.buffer("volumetry-samples", sizes[0].1, U::STORAGE | U::COPY_DST),
            counts: self.buffer("volumetry-counts", 8, out),
            band: self.buffer("volumetry-band", sizes[1].1, out),
            roots: self.buffer("volumetry-roots", sizes[2].1, out),
            resected: self.buffer(
                "volumetry-resected",
                4 * resected_cap,
                U::STORAGE | U::COPY_DST,
            ),
            staging: self.buffer(
                "volumetry-staging",
                staging_bytes,
                U::MAP_READ | U::COPY_DST,
            ),
        });
        Ok(())
    }

    /// Bind groups of the entry points `which` (indices into [`ENTRIES`]).
    fn bind_groups(&self, which: &[usize]) -> Result<Vec<wgpu::BindGroup>, GpuError> {
        let (Some(l), Some(io)) = (&self.liver, &self.io) else {
            return Err(GpuError::Pipeline("volumetry buffers missing".into()));
        };
        let buffers = [
            &self.uniform,
            &l.cell_words,
            &io.samples,
            &l.dkey,
            &l.kkey,
            &l.parent,
            &io.counts,
            &io.band,
            &io.roots,
            &io.resected,
            &l.mask,
            &l.dkey,
            &l.parent,
        ];
        Ok(which
            .iter()
            .map(|&e| {
                let entries: Vec<_> = ENTRIES[e]
                    .1
                    .iter()
                    .map(|&b| wgpu::BindGroupEntry {
                        binding: b,
                        resource: buffers[b as usize].as_entire_binding(),
                    })
                    .collect();
                self.ctx
                    .device
                    .create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some(ENTRIES[e].0),
                        layout: &self.pipelines[e].get_bind_group_layout(0),
                        entries: &entries,
                    })
            })
            .collect())
    }

    /// Records entry point `e` over `count` invocations.
    fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        e: usize,
        bind: &wgpu::BindGroup,
        count: u32,
    ) {
        if count == 0 {
            return;
        }
        let groups = count.div_ceil(GROUP);
        let gx = groups.min(MAX_GROUPS);
        pass.set_pipeline(&self.pipelines[e]);
        pass.set_bind_group(0, bind, &[]);
        pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
    }

    /// One try of the band and components at the current capacities; `Ok(None)` when an output
    /// overflowed (the capacities are then grown to fit).
    fn try_band(&mut self, q: &BandQuery<'_>) -> Result<Option<BandComponents>, GpuError> {
        let ns = q.discs.len();
        self.ensure_io(ns, 0)?;
        let mut words = Vec::with_capacity(STRIDE * ns);
        for d in q.discs {
            words.extend(d.point.iter().chain(&d.normal).chain(&d.g).chain(&d.n_idx));
            words.push(d.axis as f64);
            words.extend(d.outer.as_flattened().iter().map(|&x| x as f64));
            words.push(0.0);
        }
        let (band_cap, roots_cap) = self
            .io
            .as_ref()
            .map_or((0, 0), |io| (io.band_cap, io.roots_cap));
        self.params.origin[3] = q.hs;
        self.params.cols[0][3] = q.rho;
        self.params.lo[3] = u32_of("volumetry samples", ns)?;
        self.params.caps = [
            u32_of("volumetry band", band_cap)?,
            u32_of("volumetry roots", roots_cap)?,
            0,
            0,
        ];
        let (Some(l), Some(io)) = (&self.liver, &self.io) else {
            return Err(GpuError::Pipeline("volumetry buffers missing".into()));
        };
        let queue = &self.ctx.queue;
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        if !words.is_empty() {
            queue.write_buffer(&io.samples, 0, bytemuck::cast_slice(&words));
        }
        let binds = self.bind_groups(&[0, 1, 2, 3, 4, 5])?;
        let (band_bytes, roots_bytes) =
            ((4 * BAND_WORDS * band_cap) as u64, (4 * roots_cap) as u64);
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&l.dkey, 0, None);
        enc.clear_buffer(&l.kkey, 0, None);
        enc.clear_buffer(&io.counts, 0, None);
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            let rows = self.params.dims[1] * self.params.dims[2];
            let sizes = [
                ns as u32,
                ns as u32,
                rows,
                l.cells,
                l.voxels,
                band_cap as u32,
            ];
            for (e, (bind, count)) in binds.iter().zip(sizes).enumerate() {
                self.dispatch(&mut pass, e, bind, count);
            }
        }
        enc.copy_buffer_to_buffer(&io.counts, 0, &io.staging, 0, 8);
        enc.copy_buffer_to_buffer(&io.band, 0, &io.staging, 8, band_bytes);
        enc.copy_buffer_to_buffer(&io.roots, 0, &io.staging, 8 + band_bytes, roots_bytes);
        queue.submit([enc.finish()]);
        let mut words: Vec<u32> = Vec::new();
        let read = self
            .ctx
            .read_back(&[(&io.staging, 0..8 + band_bytes + roots_bytes)], |_, b| {
                words = bytemuck::cast_slice(b).to_vec();
            });
        self.ctx.check()?;
        read?;
        let [nb, nr] = match words.get(..2) {
            Some(&[nb, nr]) => [nb as usize, nr as usize],
            _ => return Err(GpuError::ReadBack("volumetry counts missing".into())),
        };
        if nb > band_cap || nr > roots_cap {
            self.band_cap = self.band_cap.max(nb + nb / 4);
            self.roots_cap = self.roots_cap.max(nr + nr / 4);
            return Ok(None);
        }
        let band_words = &words[2..2 + BAND_WORDS * nb];
        let roots_at = 2 + BAND_WORDS * band_cap;
        let band = band_words
            .chunks_exact(BAND_WORDS)
            .map(|w| BandVoxel {
                cell: w[0],
                sample: w[1],
                neighbours: [w[2], w[3], w[4], w[5], w[6], w[7]],
            })
            .collect();
        let roots = words[roots_at..roots_at + nr].to_vec();
        Ok(Some(BandComponents { band, roots }))
    }

    fn band(&mut self, liver: &LiverVoxels, q: &BandQuery<'_>) -> Result<BandComponents, GpuError> {
        self.ctx.check()?;
        self.ensure_liver(liver)?;
        // A second try fits: the counts do not change.
        for _ in 0..2 {
            if let Some(out) = self.try_band(q)? {
                return Ok(out);
            }
        }
        Err(GpuError::ReadBack(
            "volumetry output kept overflowing".into(),
        ))
    }

    fn mask(&mut self, roots: &[u32]) -> Result<Vec<u32>, GpuError> {
        self.ctx.check()?;
        let samples = self.io.as_ref().map_or(0, |io| io.samples_cap);
        self.ensure_io(samples, roots.len())?;
        self.params.caps[2] = u32_of("volumetry roots", roots.len())?;
        let (Some(l), Some(io)) = (&self.liver, &self.io) else {
            return Err(GpuError::Pipeline("volumetry: mask before band".into()));
        };
        let queue = &self.ctx.queue;
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        if !roots.is_empty() {
            queue.write_buffer(&io.resected, 0, bytemuck::cast_slice(roots));
        }
        let binds = self.bind_groups(&[6])?;
        let bytes = l.mask.size();
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&l.mask, 0, None);
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.dispatch(&mut pass, 6, &binds[0], l.voxels);
        }
        enc.copy_buffer_to_buffer(&l.mask, 0, &l.mask_staging, 0, bytes);
        queue.submit([enc.finish()]);
        let mut out = Vec::new();
        let read = self.ctx.read_back(&[(&l.mask_staging, 0..bytes)], |_, b| {
            out = bytemuck::cast_slice(b).to_vec();
        });
        self.ctx.check()?;
        read?;
        out.truncate((l.voxels as usize).div_ceil(32));
        Ok(out)
    }
}

/// The factory of [`GpuVolumetry`]s on `ctx` (backend `"wgpu"`), for planners to install one
/// per liver.
pub fn gpu_volumetry(ctx: &GpuContext) -> AcceleratorFactory {
    let ctx = ctx.clone();
    AcceleratorFactory::new("wgpu", move || {
        Ok(Box::new(GpuVolumetry::new(&ctx).map_err(accel)?) as Box<dyn CutAccelerator>)
    })
}

impl CutAccelerator for GpuVolumetry {
    fn band_components(
        &mut self,
        liver: &LiverVoxels,
        query: &BandQuery<'_>,
    ) -> Result<BandComponents, AcceleratorError> {
        self.band(liver, query).map_err(accel)
    }

    fn resected_mask(&mut self, roots: &[u32]) -> Result<Vec<u32>, AcceleratorError> {
        self.mask(roots).map_err(accel)
    }
}
