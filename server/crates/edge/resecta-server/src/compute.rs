//! The compute backend of the sessions' planners (`--gpu`, `RESECTA_GPU`, TOML `gpu`).

use resecta_gpu::{GpuContext, gpu_compute_engine};
use resecta_session::ServiceConfig;
use resecta_session::api::ComputeInfo;
use serde::Deserialize;

use crate::error::ServerError;

/// Whether planners evaluate their surfaces on a GPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum GpuMode {
    /// A hardware GPU adapter when one is found (which one is logged), else the CPU: a software
    /// rasteriser (lavapipe) would plan slower than the CPU path itself.
    Auto,
    /// The CPU (the default: a workstation starts without opening a GPU driver; the GPU
    /// container sets `auto`).
    #[default]
    Off,
    /// A GPU adapter, software ones included, or the server does not start.
    Required,
}

/// Sets `service`'s compute engine, compute report and `gpu` capability for `mode`: opens the
/// adapter `WGPU_BACKEND` names (any when unset) unless `mode` is off.
pub fn configure_compute(mode: GpuMode, service: &mut ServiceConfig) -> Result<(), ServerError> {
    if mode == GpuMode::Off {
        return Ok(());
    }
    match GpuContext::new() {
        Ok(ctx) if mode == GpuMode::Auto && ctx.is_software() => {
            tracing::info!(
                adapter = %ctx.info.name,
                "only a software GPU adapter: planning surfaces on the CPU (--gpu required uses it)"
            );
            Ok(())
        }
        Ok(ctx) => {
            tracing::info!(
                adapter = %ctx.info.name,
                backend = ?ctx.info.backend,
                device_type = ?ctx.info.device_type,
                f64 = ctx.caps.f64,
                "planning on the GPU: surfaces, inside levels and margins"
            );
            service.compute = ComputeInfo {
                backend: "wgpu".into(),
                adapter: ctx.info.name.clone(),
                f64: ctx.caps.f64,
            };
            service.compute_engine = gpu_compute_engine(&ctx);
            service.poisson_solver = resecta_gpu::gpu_poisson_solver(&ctx);
            service.capabilities.push("gpu".into());
            Ok(())
        }
        Err(e) if mode == GpuMode::Required => Err(ServerError::Gpu(format!(
            "--gpu required, but {e} (WGPU_BACKEND selects the backends searched)"
        ))),
        Err(e) => {
            tracing::info!(error = %e, "no GPU adapter: planning surfaces on the CPU");
            Ok(())
        }
    }
}
