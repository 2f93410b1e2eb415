//! The liver's inside level on the GPU: the CPU twin is `resecta_plan::Anatomy::inside_level`
//! (`InsideField::level` − ½), whose bit bricks ([`resecta_plan::InsideLayout`]) this kernel
//! keeps resident (one upload per anatomy, 1/8 byte per voxel: 9.8 MB at 512×512×300) and
//! looks up, one invocation per point, in f64. The WGSL transcribes the CPU's arithmetic
//! (world → index, floor, trilinear weights in the same order), so levels equal the CPU's to
//! rounding (the device may fuse multiply-adds): at most 1e-12 in the tests, and a level is
//! continuous, so the inside/outside decision differs only for points within that of the
//! liver's level set. f64 only ([`GpuError::NoF64`] otherwise).

use resecta_plan::InsideLayout;
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};
use crate::kernels::{dispatch_points, leading, u32_index};

#[cfg(test)]
mod tests;

/// The WGSL source.
pub const SOURCE: &str = include_str!("inside.wgsl");

/// Uniform block (112 bytes). Mirrors `Params` in the WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct Params {
    rows: [[f64; 4]; 3],
    dims: [u32; 4],
    bricks: [u32; 4],
}

/// A liver envelope's bit bricks resident on the GPU, shared by the probes of every resection
/// on that anatomy (each brings its own parameter block: [`GpuInsideField::uniform`]).
#[derive(Debug)]
pub struct GpuInsideField {
    ctx: GpuContext,
    pipeline: wgpu::ComputePipeline,
    params: Params,
    words: wgpu::Buffer,
}

impl GpuInsideField {
    /// Compiles the kernel and uploads the bricks. [`GpuError::NoF64`] without `SHADER_F64`,
    /// [`GpuError::TooLarge`] beyond the device's storage binding.
    pub fn new(ctx: &GpuContext, layout: &InsideLayout<'_>) -> Result<Self, GpuError> {
        if !ctx.caps.f64 {
            return Err(GpuError::NoF64);
        }
        ctx.check()?;
        let bytes = std::mem::size_of_val(layout.words) as u64;
        let limit = ctx.max_binding();
        if bytes > limit {
            return Err(GpuError::TooLarge {
                what: "inside-level bricks",
                bytes,
                limit,
            });
        }
        let pipeline = ctx.compute_pipeline("inside", SOURCE, "levels")?;
        let (inv, origin) = (layout.grid.inverse_linear(), layout.grid.origin());
        let row = |r: usize| [inv[(r, 0)], inv[(r, 1)], inv[(r, 2)], origin[r]];
        let params = Params {
            rows: [row(0), row(1), row(2)],
            dims: [
                u32_index("inside grid", layout.dims[0])?,
                u32_index("inside grid", layout.dims[1])?,
                u32_index("inside grid", layout.dims[2])?,
                0,
            ],
            bricks: [
                u32_index("inside bricks", layout.bricks[0])?,
                u32_index("inside bricks", layout.bricks[1])?,
                0,
                0,
            ],
        };
        // Never an empty binding: one zero word for an empty mask.
        let words: &[u64] = if layout.words.is_empty() {
            &[0]
        } else {
            layout.words
        };
        let words = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("inside-bricks"),
                contents: bytemuck::cast_slice(words),
                usage: wgpu::BufferUsages::STORAGE,
            });
        ctx.check()?;
        Ok(Self {
            ctx: ctx.clone(),
            pipeline,
            params,
            words,
        })
    }

    /// A parameter block for one user's encodings (one encoding per submission each).
    pub(crate) fn uniform(&self) -> wgpu::Buffer {
        self.ctx.buffer(
            "inside-params",
            std::mem::size_of::<Params>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )
    }

    /// Encodes the inside levels of the `count` points stored as f64 xyz triples at the start
    /// of `points` into the start of `out` (f64 each), with the parameter block `uniform`.
    pub(crate) fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        uniform: &wgpu::Buffer,
        points: &wgpu::Buffer,
        count: usize,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let n = u32_index("inside query points", count)?;
        if n == 0 {
            return Ok(());
        }
        let mut params = self.params;
        params.dims[3] = n;
        self.ctx
            .queue
            .write_buffer(uniform, 0, bytemuck::bytes_of(&params));
        let resources = vec![
            uniform.as_entire_binding(),
            self.words.as_entire_binding(),
            leading(points, count * std::mem::size_of::<[f64; 3]>()),
            leading(out, count * std::mem::size_of::<f64>()),
        ];
        dispatch_points(&self.ctx, enc, &self.pipeline, "inside", resources, n);
        Ok(())
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
}
