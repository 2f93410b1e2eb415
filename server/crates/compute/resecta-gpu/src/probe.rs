//! The planner's edit path on the GPU: [`GpuProbe`] implements `resecta_plan::SampleProbe`.
//! Per edit, one submission evaluates the Bézier surface with normals ([`GpuSurface`]'s
//! resident net, only moved control points uploaded), then the inside level
//! ([`GpuInsideField`], shared per anatomy) and the exact tumour distance ([`GpuMarginField`])
//! of every sample, reading the samples where the surface pass left them; one read-back brings
//! points, derivatives, normals, levels and squared distances. The host takes the roots and
//! `resecta_margin::evaluate_exact_into` gives classes, areas and the refined minimum.
//! A surface not on this device (or in several output bands) is evaluated first and its points
//! uploaded: two round trips. [`gpu_compute_engine`] makes the planner's engine.

use std::ops::Range;
use std::sync::{Arc, Mutex, Weak};

use resecta_bezier::{BezierError, SurfaceEvaluator, SurfaceGrid};
use resecta_geom::Real;
use resecta_plan::{Anatomy, ComputeEngine, ProbeEngine, SampleProbe, TargetModel};

use crate::device::{GpuContext, GpuError};
use crate::kernels::bezier::Chained;
use crate::kernels::inside::GpuInsideField;
use crate::kernels::margin::GpuMarginField;
use crate::kernels::volumetry::gpu_volumetry;
use crate::surface::{GpuSurface, gpu_engine};

/// Per-sample buffers, sized for `capacity` samples and kept while large enough.
#[derive(Debug)]
struct Io {
    capacity: usize,
    /// Sample points for the unchained path (f64 xyz).
    points: wgpu::Buffer,
    inside: wgpu::Buffer,
    distance: wgpu::Buffer,
    /// Inside levels, then squared distances.
    staging: wgpu::Buffer,
}

/// Measures one resection's samples on the GPU (see the module docs).
#[derive(Debug)]
pub struct GpuProbe {
    ctx: GpuContext,
    inside: Arc<GpuInsideField>,
    uniform: wgpu::Buffer,
    margin: GpuMarginField,
    io: Option<Io>,
    /// Samples of the current measurement.
    count: usize,
    levels: Vec<Real>,
    squared: Vec<Real>,
    /// Measurements chained onto the surface evaluation, and with the points uploaded.
    chained: u64,
    uploaded: u64,
}

impl GpuProbe {
    /// A probe for `target`'s tumours (uploaded now) in the liver of `inside`.
    pub fn new(inside: Arc<GpuInsideField>, target: &TargetModel) -> Result<Self, GpuError> {
        let ctx = inside.context().clone();
        Ok(Self {
            margin: GpuMarginField::new(&ctx, &target.field)?,
            uniform: inside.uniform(),
            inside,
            ctx,
            io: None,
            count: 0,
            levels: Vec::new(),
            squared: Vec::new(),
            chained: 0,
            uploaded: 0,
        })
    }

    /// Measurements so far: chained onto the surface's submission (one round trip per edit),
    /// and with the points uploaded after it.
    pub fn round_trips(&self) -> (u64, u64) {
        (self.chained, self.uploaded)
    }

    fn ensure_io(&mut self, n: usize) -> Result<&Io, GpuError> {
        if self.io.as_ref().is_none_or(|io| io.capacity < n) {
            let bytes = (n * std::mem::size_of::<[f64; 3]>()) as u64;
            let limit = self.ctx.max_binding();
            if bytes > limit {
                return Err(GpuError::TooLarge {
                    what: "probe sample points",
                    bytes,
                    limit,
                });
            }
            let each = (n * std::mem::size_of::<f64>()) as u64;
            use wgpu::BufferUsages as U;
            let buffer = |label, size, usage| self.ctx.buffer(label, size, usage);
            self.io = Some(Io {
                capacity: n,
                points: buffer("probe-points", bytes, U::STORAGE | U::COPY_DST),
                inside: buffer("probe-inside", each, U::STORAGE | U::COPY_SRC),
                distance: buffer("probe-distance", each, U::STORAGE | U::COPY_SRC),
                staging: buffer("probe-staging", 2 * each, U::MAP_READ | U::COPY_DST),
            });
        }
        self.io
            .as_ref()
            .ok_or_else(|| GpuError::Pipeline("probe buffers missing".into()))
    }

    /// Inside levels and exact distances of `points` (finite, RAS mm), uploaded: the unchained
    /// path, also the kernels' comparison with their CPU twins.
    pub fn measure_points(
        &mut self,
        points: &[[Real; 3]],
        inside: &mut Vec<Real>,
        distance: &mut Vec<Real>,
    ) -> Result<(), GpuError> {
        self.ctx.check()?;
        let n = points.len();
        if n == 0 {
            self.levels.clear();
            self.squared.clear();
            self.results(inside, distance);
            return Ok(());
        }
        let uploaded = self.ensure_io(n)?.points.clone();
        let ctx = self.ctx.clone();
        ctx.queue
            .write_buffer(&uploaded, 0, bytemuck::cast_slice(points));
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        self.encode(&mut enc, &uploaded, n)?;
        ctx.queue.submit([enc.finish()]);
        let (buffer, range) = self.staging();
        ctx.read_back(&[(&buffer, range)], |_, bytes| self.read(bytes))?;
        ctx.check()?;
        self.results(inside, distance);
        Ok(())
    }

    /// The last measurement's levels and distances (roots of the squared ones).
    fn results(&self, inside: &mut Vec<Real>, distance: &mut Vec<Real>) {
        inside.clear();
        inside.extend_from_slice(&self.levels);
        distance.clear();
        distance.extend(self.squared.iter().map(|d| d.sqrt()));
    }
}

impl Chained for GpuProbe {
    fn encode(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        points: &wgpu::Buffer,
        count: usize,
    ) -> Result<(), GpuError> {
        self.ensure_io(count)?;
        let Some(io) = self.io.take() else {
            return Err(GpuError::Pipeline("probe buffers missing".into()));
        };
        let encoded = self
            .inside
            .encode(enc, &self.uniform, points, count, &io.inside)
            .and_then(|()| self.margin.encode(enc, points, count, &io.distance));
        let each = (count * std::mem::size_of::<f64>()) as u64;
        enc.copy_buffer_to_buffer(&io.inside, 0, &io.staging, 0, each);
        enc.copy_buffer_to_buffer(&io.distance, 0, &io.staging, each, each);
        self.io = Some(io);
        self.count = count;
        encoded
    }

    fn staging(&self) -> (wgpu::Buffer, Range<u64>) {
        let bytes = (2 * self.count * std::mem::size_of::<f64>()) as u64;
        match &self.io {
            Some(io) => (io.staging.clone(), 0..bytes),
            // Not reached: `encode` made the buffers.
            None => (self.uniform.clone(), 0..0),
        }
    }

    fn read(&mut self, bytes: &[u8]) {
        let values: &[f64] = bytemuck::cast_slice(bytes);
        let (levels, squared) = values.split_at(values.len() / 2);
        self.levels.clear();
        self.levels.extend_from_slice(levels);
        self.squared.clear();
        self.squared.extend_from_slice(squared);
    }
}

impl SampleProbe for GpuProbe {
    fn measure(
        &mut self,
        surface: &mut dyn SurfaceEvaluator,
        grid: &mut SurfaceGrid<Real>,
        inside: &mut Vec<Real>,
        distance: &mut Vec<Real>,
    ) -> Result<(), BezierError> {
        let ctx = self.ctx.clone();
        let chained = match surface
            .as_any_mut()
            .and_then(|a| a.downcast_mut::<GpuSurface>())
        {
            Some(GpuSurface::F64(mle)) if mle.context().same_device(&ctx) => {
                mle.evaluate_normals_chained(grid, self)?
            }
            _ => {
                surface.evaluate_into(grid)?;
                false
            }
        };
        if chained {
            self.chained += 1;
            self.results(inside, distance);
        } else {
            self.uploaded += 1;
            self.measure_points(grid.points(), inside, distance)?;
        }
        Ok(())
    }
}

/// The probes of a device: one [`GpuInsideField`] per anatomy (kept while the anatomy lives),
/// one [`GpuMarginField`] per probe.
#[derive(Debug)]
struct Probes {
    ctx: GpuContext,
    insides: Mutex<Vec<(Weak<Anatomy>, Arc<GpuInsideField>)>>,
}

impl Probes {
    fn inside(&self, anatomy: &Arc<Anatomy>) -> Result<Arc<GpuInsideField>, GpuError> {
        let mut insides = self
            .insides
            .lock()
            .map_err(|_| GpuError::Pipeline("inside-field cache poisoned".into()))?;
        insides.retain(|(a, _)| a.strong_count() > 0);
        if let Some((_, f)) = insides
            .iter()
            .find(|(a, _)| std::ptr::eq(a.as_ptr(), Arc::as_ptr(anatomy)))
        {
            return Ok(Arc::clone(f));
        }
        let field = Arc::new(GpuInsideField::new(&self.ctx, &anatomy.inside_layout())?);
        insides.push((Arc::downgrade(anatomy), Arc::clone(&field)));
        Ok(field)
    }
}

/// The planner's engine on `ctx`: surfaces by [`gpu_engine`], and with `SHADER_F64` their
/// samples measured by [`GpuProbe`]s and volumetry's cuts by `GpuVolumetry` (without it, both
/// on the CPU).
pub fn gpu_compute_engine(ctx: &GpuContext) -> ComputeEngine {
    let probes = ctx.caps.f64.then(|| {
        let probes = Arc::new(Probes {
            ctx: ctx.clone(),
            insides: Mutex::new(Vec::new()),
        });
        ProbeEngine::new("wgpu", move |anatomy, target| {
            let inside = probes.inside(anatomy)?;
            Ok(Box::new(GpuProbe::new(inside, target)?) as Box<dyn SampleProbe>)
        })
    });
    ComputeEngine {
        surfaces: gpu_engine(ctx),
        probes,
        volumetry: ctx.caps.f64.then(|| gpu_volumetry(ctx)),
        host_bytes_per_sample: host_bytes_per_sample(ctx),
        // GpuVolumetry's three u32 arrays over the liver's bounding box and its bit-packed copy.
        host_bytes_per_voxel: if ctx.is_software() { 13 } else { 0 },
    }
}

/// Host memory per surface sample of a [`GpuSurface`] with normals and its [`GpuProbe`]: the
/// mapped staging buffers (surface 96 B, probe 16 B), and on a software device, whose memory is
/// host memory, the storage buffers too (surface 96 B, probe 40 B); rounded up.
fn host_bytes_per_sample(ctx: &GpuContext) -> u64 {
    if ctx.is_software() { 256 } else { 128 }
}
