//! Exact point-to-tumour distances on the GPU: the CPU twin is
//! `resecta_margin::MarginField::distances_into`, whose search structure this kernel walks.
//!
//! Design: [`GpuMarginField::new`] uploads the field's oriented-box tree
//! (`resecta_margin::ObbTree`: nodes and per-triangle boxes, f32, 64 bytes each), its prepared
//! triangles (f64, 288 bytes each) and its hint grid (one triangle slot per node) once; they
//! stay resident and serve every later call. [`GpuMarginField::distances_into`] uploads the
//! points (f64 RAS mm), runs one invocation per point and reads the squared distances back in
//! one transfer; the host takes the roots, as the CPU does. An invocation seeds its bound with
//! the hint triangle of the grid node nearest to the point and walks the tree depth first
//! (explicit stack of `resecta_margin::STACK` entries, nearer child first), opening a box only
//! when its f32 lower bound is strictly below the f32-rounded best so far, and measuring a leaf
//! triangle exactly when its own box is: `ObbTree::closest` for one lane. The boxes' padding
//! covers the f32 rounding of the bound (with room for WGSL's f64→f32 conversions, which may
//! round either way), so the walk finds the nearest triangle, not an approximation; points
//! beyond the tree's reach (where the padding no longer covers it; the CPU uses a plain BVH
//! there) are measured against every triangle, which is slow for large meshes but rare (more
//! than 250 mm beyond the hint region).
//!
//! Shared math: the WGSL transcribes `PreparedTriangle::distance_squared` (operation for
//! operation, on the host's prepared data) and, for triangles flat at corner 0,
//! `resecta_geom::bvh::closest_point_on_triangle`'s flat branch; the box bound is
//! `ObbNode::distance_squared`. Distances therefore equal the CPU's to rounding (the device may
//! fuse multiply-adds, and points beyond the reach meet the CPU's BVH answer): measured on
//! lavapipe at most 1.2e-13 mm (tests: phantom, triangle soups with flat slivers; 0 on a
//! 200×200 grid), so classes from [`MarginSettings::classify`] on the host are identical unless
//! a distance lies within that of a threshold. Non-finite points give NaN, as on the CPU.
//!
//! f64 only: a device without `SHADER_F64` gets [`GpuError::NoF64`]; there is no f32 variant
//! (its tolerance would need its own analysis), so callers stay on the CPU there.
//! Timings on lavapipe (`examples/margin_timing.rs`) are correctness runs, not performance.

use resecta_geom::{Real, Vec3};
use resecta_margin::{COUNT_BITS, MarginClass, MarginError, MarginField, MarginSettings, ObbNode};
use wgpu::util::DeviceExt;

use crate::device::{GpuContext, GpuError};
use crate::kernels::{dispatch_points, leading, u32_index};

#[cfg(test)]
mod tests;

/// The WGSL source without its header (see [`shader_source`]).
pub const TEMPLATE: &str = include_str!("margin.wgsl");
/// f64 words per prepared triangle (`TRI` in the WGSL).
const TRI: usize = 36;

/// The WGSL source with resecta-margin's stack size and link layout prepended.
pub fn shader_source() -> String {
    format!(
        "const STACK: u32 = {}u;\nconst COUNT_BITS: u32 = {COUNT_BITS}u;\n{TEMPLATE}",
        resecta_margin::STACK
    )
}

/// Uniform block (96 bytes, no implicit padding). Mirrors `Params` in the WGSL.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    /// Tree origin, reach².
    origin: [f64; 4],
    /// Hint-grid origin, 1 / spacing.
    grid: [f64; 4],
    /// Hint nodes along x, y, z; index of the first triangle box.
    dims: [u32; 4],
    count: u32,
    slots: u32,
    pad: [u32; 2],
}

/// Buffers sized for up to `capacity` points, and their bind group.
#[derive(Debug)]
struct Io {
    capacity: usize,
    points: wgpu::Buffer,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
}

/// A [`MarginField`] resident on the GPU: exact distances of many points per call.
#[derive(Debug)]
pub struct GpuMarginField {
    ctx: GpuContext,
    pipeline: wgpu::ComputePipeline,
    params: Params,
    uniform: wgpu::Buffer,
    boxes: wgpu::Buffer,
    tris: wgpu::Buffer,
    hints: wgpu::Buffer,
    io: Option<Io>,
    /// Points as uploaded (non-finite ones replaced by the origin).
    scratch: Vec<[f64; 3]>,
    field_id: u64,
}

fn words(n: &ObbNode) -> [f32; 16] {
    let mut w = [0.0f32; 16];
    w[..3].copy_from_slice(&n.c);
    w[3..12].copy_from_slice(n.a.as_flattened());
    w[12..15].copy_from_slice(&n.h);
    w[15] = f32::from_bits(n.link);
    w
}

fn u32_of(x: usize) -> Result<u32, GpuError> {
    u32_index("margin index", x)
}

impl GpuMarginField {
    /// Compiles the kernel and uploads `field`'s tree, triangles and hints.
    /// Errors with [`GpuError::NoF64`] without `SHADER_F64`, [`GpuError::TooLarge`] when a
    /// buffer exceeds the device's storage binding.
    pub fn new(ctx: &GpuContext, field: &MarginField) -> Result<Self, GpuError> {
        if !ctx.caps.f64 {
            return Err(GpuError::NoF64);
        }
        ctx.check()?;
        let tree = field.tree();
        let boxes: Vec<[f32; 16]> = tree
            .nodes()
            .iter()
            .chain(tree.triangle_boxes())
            .map(words)
            .collect();
        let tris: Vec<[f64; TRI]> = tree
            .prepared()
            .iter()
            .zip(tree.triangles())
            .map(|(prep, corners)| {
                let mut w = [0.0; TRI];
                match prep {
                    Some(t) => {
                        w[..9].copy_from_slice(t.v.as_flattened());
                        w[9..18].copy_from_slice(t.e.as_flattened());
                        w[18..27].copy_from_slice(t.m.as_flattened());
                        w[27..30].copy_from_slice(&t.n);
                        w[30..33].copy_from_slice(&t.inv_ee);
                        w[33] = t.inv_nn;
                    }
                    None => {
                        for (k, c) in corners.iter().enumerate() {
                            w[3 * k..3 * k + 3].copy_from_slice(c.as_slice());
                        }
                        w[34] = 1.0;
                    }
                }
                w
            })
            .collect();
        let limit = ctx.max_binding();
        let check = |what: &'static str, bytes: usize| {
            let bytes = bytes as u64;
            if bytes > limit {
                return Err(GpuError::TooLarge { what, bytes, limit });
            }
            Ok(())
        };
        check("margin tree boxes", std::mem::size_of_val(boxes.as_slice()))?;
        check("margin triangles", std::mem::size_of_val(tris.as_slice()))?;
        check("margin hints", std::mem::size_of_val(field.hints()))?;
        let pipeline = ctx.compute_pipeline("margin", &shader_source(), "distances")?;
        let (grid_origin, _) = field.region();
        let [nx, ny, nz] = field.dims();
        let origin = tree.origin();
        let params = Params {
            origin: [origin.x, origin.y, origin.z, tree.reach() * tree.reach()],
            grid: [
                grid_origin.x,
                grid_origin.y,
                grid_origin.z,
                1.0 / field.spacing(),
            ],
            dims: [
                u32_of(nx)?,
                u32_of(ny)?,
                u32_of(nz)?,
                u32_of(tree.nodes().len())?,
            ],
            count: 0,
            slots: u32_of(tris.len())?,
            pad: [0; 2],
        };
        let storage = |label, contents: &[u8]| {
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage: wgpu::BufferUsages::STORAGE,
                })
        };
        let boxes = storage("margin-boxes", bytemuck::cast_slice(&boxes));
        let tris = storage("margin-triangles", bytemuck::cast_slice(&tris));
        let hints = storage("margin-hints", bytemuck::cast_slice(field.hints()));
        let uniform = ctx.buffer(
            "margin-params",
            std::mem::size_of::<Params>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        ctx.check()?;
        Ok(Self {
            ctx: ctx.clone(),
            pipeline,
            params,
            uniform,
            boxes,
            tris,
            hints,
            io: None,
            scratch: Vec::new(),
            field_id: field.id(),
        })
    }

    /// [`MarginField::id`] of the field uploaded.
    pub fn field_id(&self) -> u64 {
        self.field_id
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Point buffers for at least `n` points (kept and reused while large enough).
    fn ensure_io(&mut self, n: usize) -> Result<(), GpuError> {
        if self.io.as_ref().is_some_and(|io| io.capacity >= n) {
            return Ok(());
        }
        let limit = self.ctx.max_binding();
        let bytes = (n * std::mem::size_of::<[f64; 3]>()) as u64;
        if bytes > limit {
            return Err(GpuError::TooLarge {
                what: "margin query points",
                bytes,
                limit,
            });
        }
        let buffer = |label, size, usage| self.ctx.buffer(label, size, usage);
        use wgpu::BufferUsages as U;
        let out_bytes = (n * std::mem::size_of::<f64>()) as u64;
        let points = buffer("margin-points", bytes, U::STORAGE | U::COPY_DST);
        let out = buffer("margin-out", out_bytes, U::STORAGE | U::COPY_SRC);
        let staging = buffer("margin-staging", out_bytes, U::MAP_READ | U::COPY_DST);
        self.io = Some(Io {
            capacity: n,
            points,
            out,
            staging,
        });
        Ok(())
    }

    /// Encodes the squared distances of the `count` points stored as f64 xyz triples at the
    /// start of `points` into the start of `out` (f64 each; the host takes the roots). Points
    /// must be finite. Writes this field's parameter block: one encoding per submission.
    pub(crate) fn encode(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        points: &wgpu::Buffer,
        count: usize,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let n = u32_of(count)?;
        if n == 0 {
            return Ok(());
        }
        self.params.count = n;
        self.ctx
            .queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        let resources = vec![
            self.uniform.as_entire_binding(),
            self.boxes.as_entire_binding(),
            self.tris.as_entire_binding(),
            self.hints.as_entire_binding(),
            leading(points, count * std::mem::size_of::<[f64; 3]>()),
            leading(out, count * std::mem::size_of::<f64>()),
        ];
        dispatch_points(&self.ctx, enc, &self.pipeline, "margin", resources, n);
        Ok(())
    }

    /// Exact distance (mm) from every point to the tumour mesh into `out` (one upload, one
    /// dispatch, one read-back); NaN for a non-finite point. Equals the uploaded field's
    /// [`MarginField::distances_into`] to rounding.
    pub fn distances_into(&mut self, points: &[Vec3], out: &mut [Real]) -> Result<(), GpuError> {
        if points.len() != out.len() {
            return Err(MarginError::LengthMismatch {
                what: "distance output",
                expected: points.len(),
                got: out.len(),
            }
            .into());
        }
        self.ctx.check()?;
        let n = points.len();
        if n == 0 {
            return Ok(());
        }
        u32_of(n)?;
        self.ensure_io(n)?;
        let Some(io) = self.io.take() else {
            return Err(GpuError::Pipeline("margin buffers missing".into()));
        };
        let finite = |p: &Vec3| p.iter().all(|c| c.is_finite());
        let origin = [
            self.params.origin[0],
            self.params.origin[1],
            self.params.origin[2],
        ];
        self.scratch.clear();
        self.scratch.extend(
            points
                .iter()
                .map(|p| if finite(p) { [p.x, p.y, p.z] } else { origin }),
        );
        self.ctx
            .queue
            .write_buffer(&io.points, 0, bytemuck::cast_slice(&self.scratch));
        let out_bytes = (n * std::mem::size_of::<f64>()) as u64;
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        let encoded = self.encode(&mut enc, &io.points, n, &io.out);
        let io = self.io.insert(io);
        encoded?;
        enc.copy_buffer_to_buffer(&io.out, 0, &io.staging, 0, out_bytes);
        self.ctx.queue.submit([enc.finish()]);
        let dst: &mut [u8] = bytemuck::cast_slice_mut(out);
        let read = self
            .ctx
            .read_back(&[(&io.staging, 0..out_bytes)], |_, bytes| {
                dst.copy_from_slice(bytes);
            });
        // A failed read-back of a lost device names the loss.
        self.ctx.check()?;
        read?;
        for (d, p) in out.iter_mut().zip(points) {
            *d = if finite(p) { d.sqrt() } else { Real::NAN };
        }
        Ok(())
    }

    /// [`Self::distances_into`], then each point's class by [`MarginSettings::classify`] with
    /// its inside level `inside[k]` (> 0 inside the liver), as the CPU's evaluation does.
    pub fn margins_into(
        &mut self,
        settings: &MarginSettings,
        points: &[Vec3],
        inside: &[Real],
        distances: &mut [Real],
        classes: &mut [MarginClass],
    ) -> Result<(), GpuError> {
        settings.validate()?;
        for (what, got) in [("inside levels", inside.len()), ("classes", classes.len())] {
            if got != points.len() {
                return Err(MarginError::LengthMismatch {
                    what,
                    expected: points.len(),
                    got,
                }
                .into());
            }
        }
        self.distances_into(points, distances)?;
        for ((c, &d), &s) in classes.iter_mut().zip(distances.iter()).zip(inside) {
            *c = settings.classify(d, s);
        }
        Ok(())
    }
}
