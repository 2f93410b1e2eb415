//! Node classification of iso-surface extraction on the GPU: the CPU twin is
//! `resecta_isosurface::CpuClassifier` (the first pass of marching cubes over every lattice
//! node), whose rule the WGSL transcribes with f32 comparisons only, so the classes are
//! identical. [`GpuClassifier`] implements `resecta_isosurface::NodeClassifier`: the lattice is
//! uploaded in slabs of z-planes within the device's storage binding, one invocation per node
//! row, classes packed four to a word, one read-back per slab. Triangles are then emitted on the
//! host, from the classes, as on the CPU (only the rows holding both classes are visited), so
//! meshes are the CPU's exactly. Device errors are `IsoError::Device`, on which
//! `extract_with` classifies on the CPU.

use resecta_isosurface::{IsoError, NodeClasses, NodeClassifier, Options};
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};
use crate::kernels::{dispatch_points, leading, u32_index};

#[cfg(test)]
mod tests;

/// The WGSL source.
pub const SOURCE: &str = include_str!("isosurface.wgsl");

/// Uniform block (32 bytes). Mirrors `Params` in the WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    dims: [u32; 4],
    rows: u32,
    words: u32,
    close: u32,
    iso: f32,
}

/// Marching cubes' node classification on a wgpu device.
#[derive(Debug, Clone)]
pub struct GpuClassifier {
    ctx: GpuContext,
    /// Largest slab of values uploaded at once (bytes); the device's binding limit by default.
    slab_bytes: Option<usize>,
}

impl GpuClassifier {
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            ctx: ctx.clone(),
            slab_bytes: None,
        }
    }

    /// Slabs of at most `bytes` of values (at least one plane each), below the device's limit.
    pub fn with_slab_bytes(mut self, bytes: usize) -> Self {
        self.slab_bytes = Some(bytes);
        self
    }

    /// [`NodeClassifier::classify`] with the device's errors typed.
    pub fn classes(
        &self,
        dims: [usize; 3],
        values: &[f32],
        iso: f32,
        options: Options,
    ) -> Result<NodeClasses, GpuError> {
        let ctx = &self.ctx;
        ctx.check()?;
        let [nx, ny, nz] = dims;
        let words = nx.div_ceil(4);
        let plane_bytes = nx * ny * 4;
        let limit = (ctx.max_binding() as usize).min(self.slab_bytes.unwrap_or(usize::MAX));
        if plane_bytes > limit {
            return Err(GpuError::TooLarge {
                what: "iso-surface lattice plane",
                bytes: plane_bytes as u64,
                limit: limit as u64,
            });
        }
        let planes = (limit / plane_bytes).min(nz).max(1);
        let pipeline = ctx.compute_pipeline("isosurface", SOURCE, "classify")?;
        let mut class = vec![0u8; values.len()];
        let mut rows = vec![0u8; ny * nz];
        use wgpu::BufferUsages as U;
        let buffer = |label, size: usize, usage| ctx.buffer(label, size as u64, usage);
        let slab_rows = ny * planes;
        let out_words = buffer(
            "iso-classes",
            slab_rows * words * 4,
            U::STORAGE | U::COPY_SRC,
        );
        let out_rows = buffer("iso-states", slab_rows * 4, U::STORAGE | U::COPY_SRC);
        let staging = buffer(
            "iso-staging",
            slab_rows * (words + 1) * 4,
            U::MAP_READ | U::COPY_DST,
        );
        for k0 in (0..nz).step_by(planes) {
            let k1 = (k0 + planes).min(nz);
            let n_rows = ny * (k1 - k0);
            let params = Params {
                dims: [
                    u32_index("lattice", nx)?,
                    u32_index("lattice", ny)?,
                    u32_index("lattice", nz)?,
                    u32_index("lattice", k0)?,
                ],
                rows: u32_index("lattice rows", n_rows)?,
                words: u32_index("lattice row words", words)?,
                close: u32::from(options.close_border),
                iso,
            };
            let init = |label, contents: &[u8], usage| {
                ctx.device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(label),
                        contents,
                        usage,
                    })
            };
            let uniform = init("iso-params", bytemuck::bytes_of(&params), U::UNIFORM);
            let slab = &values[k0 * nx * ny..k1 * nx * ny];
            let input = init("iso-values", bytemuck::cast_slice(slab), U::STORAGE);
            let (class_bytes, row_bytes) = (n_rows * words * 4, n_rows * 4);
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            let resources = vec![
                uniform.as_entire_binding(),
                input.as_entire_binding(),
                leading(&out_words, class_bytes),
                leading(&out_rows, row_bytes),
            ];
            dispatch_points(
                ctx,
                &mut enc,
                &pipeline,
                "isosurface",
                resources,
                params.rows,
            );
            enc.copy_buffer_to_buffer(&out_words, 0, &staging, 0, class_bytes as u64);
            enc.copy_buffer_to_buffer(&out_rows, 0, &staging, class_bytes as u64, row_bytes as u64);
            ctx.queue.submit([enc.finish()]);
            let range = 0..(class_bytes + row_bytes) as u64;
            let class_slab = &mut class[k0 * nx * ny..k1 * nx * ny];
            let rows_slab = &mut rows[k0 * ny..k1 * ny];
            ctx.read_back(&[(&staging, range)], |_, bytes| {
                let (cw, rw) = bytes.split_at(class_bytes);
                for (dst, src) in class_slab.chunks_mut(nx).zip(cw.chunks(words * 4)) {
                    dst.copy_from_slice(&src[..nx]);
                }
                for (dst, src) in rows_slab.iter_mut().zip(rw.chunks(4)) {
                    *dst = src[0];
                }
            })?;
            ctx.check()?;
        }
        Ok(NodeClasses { class, rows })
    }
}

impl NodeClassifier for GpuClassifier {
    fn backend(&self) -> &'static str {
        "wgpu"
    }
    fn classify(
        &self,
        dims: [usize; 3],
        values: &[f32],
        iso: f32,
        options: Options,
    ) -> Result<NodeClasses, IsoError> {
        self.classes(dims, values, iso, options)
            .map_err(|e| IsoError::Device(e.to_string()))
    }
}
