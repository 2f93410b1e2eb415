//! Device set-up, separate from the kernels: one [`GpuContext`] (device, queue, adapter info,
//! capabilities) created by [`GpuContext::new`], which honours `WGPU_BACKEND` and asks for
//! `SHADER_F64` whenever the adapter offers it. Kernels borrow the context, so tests inject it.
//! Errors the device raises outside an error scope, and its loss, are recorded rather than
//! panicking (wgpu's default): [`GpuContext::check`] turns them into [`GpuError::DeviceLost`],
//! which kernels return, so that callers can go on without the device.
//! Compiled compute pipelines are cached on the context ([`GpuContext::compute_pipeline`]), so
//! that every evaluator made on it (or on a clone) after the first compiles nothing.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, mpsc};

/// What the device can do that the kernels care about.
#[derive(Debug, Clone)]
pub struct Capabilities {
    /// `SHADER_F64` was granted (64-bit float kernels available).
    pub f64: bool,
    /// The device's limits (the adapter's own limits were requested).
    pub limits: wgpu::Limits,
}

/// A wgpu device and queue with what is known about them. Cheap to clone (handles are shared).
#[derive(Debug, Clone)]
pub struct GpuContext {
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name, driver, backend, device type.
    pub info: wgpu::AdapterInfo,
    /// Features and limits in use.
    pub caps: Capabilities,
    faults: Arc<Faults>,
    pipelines: Arc<Pipelines>,
}

/// Compiled compute pipelines by WGSL source and entry point (shared by the context's clones),
/// with the count of compilations: a shader module per source, a pipeline per entry point.
#[derive(Debug, Default)]
struct Pipelines {
    by_source: Mutex<HashMap<String, Module>>,
    compiled: AtomicU64,
}

#[derive(Debug)]
struct Module {
    module: wgpu::ShaderModule,
    entries: HashMap<String, wgpu::ComputePipeline>,
}

/// What went wrong with a device outside any error scope (shared by the context's clones).
#[derive(Debug, Default)]
struct Faults {
    failed: AtomicBool,
    first: Mutex<Option<String>>,
}

impl Faults {
    fn record(&self, what: String) {
        if let Ok(mut first) = self.first.lock() {
            first.get_or_insert(what);
        }
        self.failed.store(true, Ordering::Release);
    }
}

/// Errors of device set-up and GPU evaluation.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter for the requested backends (`WGPU_BACKEND`, or all of them when unset).
    #[error("no GPU adapter for backends {backends:?}: {reason}")]
    NoAdapter {
        /// Backends that were searched.
        backends: wgpu::Backends,
        /// wgpu's reason.
        reason: String,
    },
    /// The adapter refused to create a device.
    #[error("device request failed: {0}")]
    RequestDevice(#[from] wgpu::RequestDeviceError),
    /// A 64-bit kernel was asked for on a device without `SHADER_F64`.
    #[error("the device lacks SHADER_F64; f64 kernels are unavailable")]
    NoF64,
    /// A buffer would exceed the device limits even after splitting.
    #[error("{what} needs {bytes} bytes; the device allows {limit}")]
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        bytes: u64,
        /// Device limit.
        limit: u64,
    },
    /// Shader or pipeline creation failed validation.
    #[error("pipeline creation failed: {0}")]
    Pipeline(String),
    /// Waiting for the queue or mapping a buffer failed.
    #[error("GPU read-back failed: {0}")]
    ReadBack(String),
    /// The device was lost or raised an error outside any error scope; it stays unusable.
    #[error("the GPU device failed: {0}")]
    DeviceLost(String),
    /// Invalid surface input (net, resolution, buffer length).
    #[error(transparent)]
    Bezier(#[from] resecta_bezier::BezierError),
    /// Invalid margin input (buffer length, settings).
    #[error(transparent)]
    Margin(#[from] resecta_margin::MarginError),
}

/// Backends from `WGPU_BACKEND` (e.g. `vulkan`, `gl`, `metal`), or `None` when unset.
pub fn backends_from_env() -> Option<wgpu::Backends> {
    wgpu::Backends::from_env()
}

impl GpuContext {
    /// Creates a device on the first adapter of the backends in `WGPU_BACKEND` (all primary
    /// and secondary backends when unset). Requests `SHADER_F64` when the adapter has it, and
    /// the adapter's full limits.
    pub fn new() -> Result<Self, GpuError> {
        Self::with_backends(backends_from_env().unwrap_or(wgpu::Backends::all()))
    }

    /// Like [`GpuContext::new`], `None` instead of an error (callers fall back to the CPU).
    pub fn try_new() -> Option<Self> {
        Self::new().ok()
    }

    /// Whether the adapter is a software rasteriser on the CPU (lavapipe, llvmpipe, WARP).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Creates a device on the first adapter of `backends`.
    pub fn with_backends(backends: wgpu::Backends) -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle().with_env();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter {
            backends,
            reason: e.to_string(),
        })?;
        let info = adapter.get_info();
        let f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        let required_features = if f64 {
            wgpu::Features::SHADER_F64
        } else {
            wgpu::Features::empty()
        };
        let limits = adapter.limits();
        let (device, queue) =
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                label: Some("resecta-gpu"),
                required_features,
                required_limits: limits.clone(),
                ..Default::default()
            }))?;
        let faults = Arc::new(Faults::default());
        let f = Arc::clone(&faults);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| f.record(e.to_string())));
        let f = Arc::clone(&faults);
        device.set_device_lost_callback(move |reason, message| {
            f.record(format!("device lost ({reason:?}): {message}"));
        });
        Ok(Self {
            device,
            queue,
            info,
            caps: Capabilities { f64, limits },
            faults,
            pipelines: Arc::default(),
        })
    }

    /// [`GpuError::DeviceLost`] once the device was lost or raised an error outside an error
    /// scope (the first such error is named); every later check fails too.
    pub fn check(&self) -> Result<(), GpuError> {
        if !self.faults.failed.load(Ordering::Acquire) {
            return Ok(());
        }
        let first = self.faults.first.lock().ok().and_then(|f| f.clone());
        Err(GpuError::DeviceLost(first.unwrap_or_default()))
    }

    /// Whether `other` is this context or a clone of it (the same device and queue).
    pub fn same_device(&self, other: &GpuContext) -> bool {
        Arc::ptr_eq(&self.pipelines, &other.pipelines)
    }

    /// An uninitialised buffer of `size` bytes.
    pub fn buffer(&self, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    }

    /// Largest storage binding in bytes (128 MiB on lavapipe).
    pub fn max_binding(&self) -> u64 {
        self.caps
            .limits
            .max_storage_buffer_binding_size
            .min(self.caps.limits.max_buffer_size)
    }

    /// Blocks until all submitted work is done.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::ReadBack(e.to_string()))
    }

    /// The compute pipeline of `source`'s `entry_point` with an automatic layout: compiled on
    /// first use (validation errors captured as [`GpuError::Pipeline`] instead of wgpu's default
    /// panic, and not cached), then shared by every caller on this context and its clones.
    /// `label` names the pipeline compiled first.
    pub fn compute_pipeline(
        &self,
        label: &str,
        source: &str,
        entry_point: &str,
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        // Held while compiling: two threads asking for the same pipeline compile it once.
        let mut cache = self
            .pipelines
            .by_source
            .lock()
            .map_err(|_| GpuError::Pipeline("pipeline cache poisoned".into()))?;
        if let Some(p) = cache.get(source).and_then(|m| m.entries.get(entry_point)) {
            return Ok(p.clone());
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = cache.get(source).map_or_else(
            || {
                self.device
                    .create_shader_module(wgpu::ShaderModuleDescriptor {
                        label: Some(label),
                        source: wgpu::ShaderSource::Wgsl(source.into()),
                    })
            },
            |m| m.module.clone(),
        );
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some(entry_point),
                compilation_options: Default::default(),
                cache: None,
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Pipeline(e.to_string()));
        }
        self.pipelines.compiled.fetch_add(1, Ordering::Relaxed);
        cache
            .entry(source.to_owned())
            .or_insert_with(|| Module {
                module,
                entries: HashMap::new(),
            })
            .entries
            .insert(entry_point.to_owned(), pipeline.clone());
        Ok(pipeline)
    }

    /// Compute pipelines compiled on this context and its clones so far (cache misses of
    /// [`GpuContext::compute_pipeline`] that succeeded).
    pub fn pipelines_compiled(&self) -> u64 {
        self.pipelines.compiled.load(Ordering::Relaxed)
    }

    /// Maps `ranges` of MAP_READ buffers, waits, and hands each mapped byte slice to `sink`
    /// (in order); unmaps afterwards.
    pub fn read_back(
        &self,
        ranges: &[(&wgpu::Buffer, std::ops::Range<u64>)],
        mut sink: impl FnMut(usize, &[u8]),
    ) -> Result<(), GpuError> {
        let (tx, rx) = mpsc::channel();
        for (k, (buf, range)) in ranges.iter().enumerate() {
            let tx = tx.clone();
            buf.map_async(wgpu::MapMode::Read, range.clone(), move |r| {
                let _ = tx.send((k, r.is_ok()));
            });
        }
        drop(tx);
        self.wait()?;
        let mut ok = true;
        for (_, good) in rx.iter() {
            ok &= good;
        }
        let result = if ok {
            let mut res = Ok(());
            for (k, (buf, range)) in ranges.iter().enumerate() {
                match buf.get_mapped_range(range.clone()) {
                    Ok(view) => sink(k, &view),
                    Err(e) => {
                        res = Err(GpuError::ReadBack(e.to_string()));
                        break;
                    }
                }
            }
            res
        } else {
            Err(GpuError::ReadBack("buffer mapping failed".into()))
        };
        for (buf, _) in ranges {
            buf.unmap();
        }
        result
    }
}

#[cfg(test)]
pub(crate) mod testing {
    //! Test device: fails when `WGPU_BACKEND` is set but no adapter exists, skips otherwise.
    use super::GpuContext;

    /// The shared test context, or `None` (with a visible `SKIP:`) when no adapter exists and
    /// `WGPU_BACKEND` is unset. Panics (fails the test) when `WGPU_BACKEND` is set and there is
    /// no adapter, or when it asks for Vulkan and another backend answered (e.g. GL fallback).
    pub(crate) fn context() -> Option<GpuContext> {
        static CTX: std::sync::OnceLock<Option<GpuContext>> = std::sync::OnceLock::new();
        CTX.get_or_init(|| {
            let env = std::env::var("WGPU_BACKEND").ok();
            match GpuContext::new() {
                Ok(ctx) => {
                    if env
                        .as_deref()
                        .is_some_and(|b| b.eq_ignore_ascii_case("vulkan"))
                    {
                        assert_eq!(
                            ctx.info.backend,
                            wgpu::Backend::Vulkan,
                            "WGPU_BACKEND=vulkan but got {:?}",
                            ctx.info
                        );
                    }
                    Some(ctx)
                }
                Err(e) => {
                    assert!(
                        env.is_none(),
                        "WGPU_BACKEND={env:?} is set but no adapter was found: {e}"
                    );
                    eprintln!("SKIP: no GPU adapter ({e}); set WGPU_BACKEND=vulkan with lavapipe");
                    None
                }
            }
        })
        .clone()
    }
}

#[cfg(test)]
mod tests {
    use super::testing::context;

    #[test]
    fn adapter_matches_env_and_reports_caps() {
        let Some(ctx) = context() else { return };
        eprintln!("adapter: {:?}, f64: {}", ctx.info, ctx.caps.f64);
        assert!(ctx.max_binding() >= 1 << 20);
        assert!(ctx.caps.limits.max_compute_invocations_per_workgroup >= 256);
        // Lavapipe (llvmpipe) exposes shaderFloat64; losing it means a wrong driver/backend.
        if ctx.info.name.contains("llvmpipe") && ctx.info.backend == wgpu::Backend::Vulkan {
            assert!(ctx.caps.f64, "lavapipe should grant SHADER_F64");
        }
    }

    #[test]
    fn bad_pipeline_is_a_typed_error() {
        let Some(ctx) = context() else { return };
        let r = ctx.compute_pipeline(
            "bad",
            "@compute @workgroup_size(1) fn main() { let x: u32 = 1.5; }",
            "main",
        );
        assert!(matches!(r, Err(super::GpuError::Pipeline(_))), "{r:?}");
    }
}
