//! wgpu device set-up and compute kernels, each with a CPU twin.
//!
//! - [`device`]: [`GpuContext`] (device, queue, adapter info, [`Capabilities`]) from
//!   [`GpuContext::new`] (honours `WGPU_BACKEND`, requests `SHADER_F64` when offered; device
//!   errors and loss are recorded, not panicked on, and kernels return them as
//!   [`GpuError::DeviceLost`]); compute pipelines are compiled once per context and shared by
//!   its clones ([`GpuContext::compute_pipeline`]).
//! - [`kernels::bezier`]: multi-level Bézier evaluation (thesis ch. 8, Algorithms 7–8) as
//!   [`GpuMle`], mirroring `resecta_bezier::MleEvaluator`; [`BezierBackend`] picks GPU or CPU;
//!   [`GpuPrepared`] for benchmarks. Points only, or with ∂S/∂u, ∂S/∂v and unit normals
//!   ([`GpuMle::evaluate_normals_into`]); a moved control point uploads only itself.
//! - [`kernels::margin`]: exact point-to-tumour distances as [`GpuMarginField`], mirroring
//!   `resecta_margin::MarginField::distances_into`: the field's oriented-box tree, prepared
//!   triangles and hints resident, one invocation per point walking the tree (f64), classes by
//!   `MarginSettings::classify` on the host ([`GpuMarginField::margins_into`]).
//! - [`kernels::inside`]: the liver's inside level at many points as [`GpuInsideField`]
//!   (`resecta_plan::Anatomy::inside_level`'s bit bricks resident, f64).
//! - [`probe`]: the planner's edit path, [`GpuProbe`] (`resecta_plan::SampleProbe`): surface,
//!   inside levels and exact distances in one submission and one read-back per edit;
//!   [`gpu_compute_engine`] makes the planner's engine.
//! - [`kernels::volumetry`]: the band and side components of volumetry cuts as
//!   [`GpuVolumetry`], `resecta_volumetry::CutAccelerator` on the GPU (f64; the liver resident,
//!   bit-packed; two read-backs per cut), results equal to `Volumetry`'s CPU path;
//!   [`gpu_volumetry`] makes them for planners.
//! - [`kernels::isosurface`]: marching cubes' node classification as [`GpuClassifier`]
//!   (`resecta_isosurface::NodeClassifier`; classes identical to the CPU's).
//! - [`kernels::poisson`]: the screened Poisson multigrid of `resecta-poisson` resident on the
//!   device ([`GpuMultigrid`], f32) and the oriented points' Sobel pass ([`GpuSobel`]);
//!   [`gpu_poisson_solver`] for `resecta_recon`'s `*_with` calls.
//! - [`surface`]: [`GpuSurface`], the planner's `SurfaceEvaluator` on the GPU (f64 with
//!   `SHADER_F64`, f32 otherwise), and [`gpu_engine`], the `SurfaceEngine` that makes them.
//! - [`cooperation`]: CPU–GPU cooperation (Sec. 8.5.2), static (SDC) and dynamic (DDC) tiling.

pub mod cooperation;
pub mod device;
pub mod kernels;
pub mod probe;
pub mod surface;

pub use cooperation::{Cooperative, DdcReport, Profile};
pub use device::{Capabilities, GpuContext, GpuError, backends_from_env};
pub use kernels::GpuScalar;
pub use kernels::bezier::{BezierBackend, GpuMle, GpuPrepared, OutputBand};
pub use kernels::inside::GpuInsideField;
pub use kernels::isosurface::GpuClassifier;
pub use kernels::margin::GpuMarginField;
pub use kernels::poisson::{GpuMultigrid, GpuSobel, gpu_poisson_solver};
pub use kernels::volumetry::{GpuVolumetry, gpu_volumetry};
pub use probe::{GpuProbe, gpu_compute_engine};
pub use surface::{GpuSurface, gpu_engine};
