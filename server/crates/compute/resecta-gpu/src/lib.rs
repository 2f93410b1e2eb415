//! wgpu device set-up and compute kernels, each with a CPU twin.
//!
//! - [`device`]: [`GpuContext`] (device, queue, adapter info, [`Capabilities`]) from
//!   [`GpuContext::new`] (honours `WGPU_BACKEND`, requests `SHADER_F64` when offered).
//! - [`kernels::bezier`]: multi-level Bézier evaluation (thesis ch. 8, Algorithms 7–8) as
//!   [`GpuMle`], mirroring `resecta_bezier::MleEvaluator`; [`BezierBackend`] picks GPU or CPU;
//!   [`GpuPrepared`] for benchmarks.
//! - [`cooperation`]: CPU–GPU cooperation (Sec. 8.5.2), static (SDC) and dynamic (DDC) tiling.

pub mod cooperation;
pub mod device;
pub mod kernels;

pub use cooperation::{Cooperative, DdcReport, Profile};
pub use device::{Capabilities, GpuContext, GpuError, backends_from_env};
pub use kernels::GpuScalar;
pub use kernels::bezier::{BezierBackend, GpuMle, GpuPrepared, OutputBand};
