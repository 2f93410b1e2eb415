//! Compute kernels. Each kernel lives in `kernels/<name>/` with its WGSL source (included at
//! compile time), its Rust driver (`mod.rs`) and its GPU-vs-CPU tests (`tests.rs`).

pub mod bezier;
pub mod margin;
pub mod poisson;

use resecta_bezier::BezierScalar;

/// Scalar types the kernels are generated for: WGSL sources are written for `f32` with an
/// `alias real = f32;` line, which [`GpuScalar::specialise`] rewrites for `f64`.
pub trait GpuScalar: BezierScalar + bytemuck::Pod {
    /// WGSL type name.
    const WGSL: &'static str;
    /// Whether `ctx` can run kernels in this type.
    fn supported(ctx: &crate::GpuContext) -> bool;
    /// The template with `real` bound to this type.
    fn specialise(template: &str) -> String {
        template.replacen(
            "alias real = f32;",
            &format!("alias real = {};", Self::WGSL),
            1,
        )
    }
}

impl GpuScalar for f32 {
    const WGSL: &'static str = "f32";
    fn supported(_: &crate::GpuContext) -> bool {
        true
    }
}

impl GpuScalar for f64 {
    const WGSL: &'static str = "f64";
    fn supported(ctx: &crate::GpuContext) -> bool {
        ctx.caps.f64
    }
}
