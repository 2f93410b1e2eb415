//! wgpu device set-up and compute kernels, each with a CPU twin.
