//! Compute kernels. Each kernel lives in `kernels/<name>/` with its WGSL source (included at
//! compile time), its Rust driver (`mod.rs`) and its GPU-vs-CPU tests (`tests.rs`).

pub mod bezier;
pub mod inside;
pub mod isosurface;
pub mod margin;
pub mod poisson;
pub mod volumetry;

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

/// Invocations per workgroup of the per-point kernels (`@workgroup_size(64)`, invocation
/// `gid.x + gid.y · groups.x · 64`).
const POINT_GROUP: u32 = 64;
/// Most workgroups along one dispatch dimension.
const MAX_GROUPS: u32 = 65_535;

/// `x` as a kernel's u32 index or count; [`GpuError::TooLarge`] naming `what` beyond it.
pub(crate) fn u32_index(what: &'static str, x: usize) -> Result<u32, crate::GpuError> {
    u32::try_from(x).map_err(|_| crate::GpuError::TooLarge {
        what,
        bytes: x as u64,
        limit: u64::from(u32::MAX),
    })
}

/// The first `bytes` of `buffer` as a binding.
pub(crate) fn leading(buffer: &wgpu::Buffer, bytes: usize) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset: 0,
        size: wgpu::BufferSize::new(bytes as u64),
    })
}

/// Binds `resources` (at bindings 0, 1, …) to group 0 of `pipeline` and encodes one pass of
/// one invocation per point for `count` points.
pub(crate) fn dispatch_points(
    ctx: &crate::GpuContext,
    enc: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    label: &str,
    resources: Vec<wgpu::BindingResource<'_>>,
    count: u32,
) {
    let entries: Vec<_> = resources
        .into_iter()
        .enumerate()
        .map(|(k, resource)| wgpu::BindGroupEntry {
            binding: k as u32,
            resource,
        })
        .collect();
    let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    });
    let groups = count.div_ceil(POINT_GROUP);
    let gx = groups.min(MAX_GROUPS);
    let mut pass = enc.begin_compute_pass(&Default::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind, &[]);
    pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
}
