//! Bézier tensor-product surfaces (thesis ch. 8, Sec. 7.3.3): pure, synchronous, no I/O.
//!
//! # API summary (names are stable)
//! - [`BezierScalar`]: `f32` / `f64` (consts `ZERO`, `ONE`, `EPSILON`, `NAME`; `from_f64`,
//!   `to_f64`, `sqrt`, …). Points are [`P3<T>`] = `[T; 3]`.
//! - [`ControlNet<T>`]: M×N control points, M along u, N along v (2 ≤ M, N ≤
//!   [`MAX_CONTROL_POINTS`] = 64), flat `points()[i·N + j]` = `P_ij`, all finite.
//!   `new(m, n, points)`, `from_fn`, `planar`, `get`/`set`/`set_points`, `bounds`, `cast`,
//!   `elevate_u`/`elevate_v`, `diff_u`/`diff_v`.
//! - [`Resolution`]: RU×RV samples (2 ≤ each ≤ [`MAX_RESOLUTION`] = 4096, RU·RV ≤
//!   [`MAX_SAMPLES`] = 2048²); sample (a, b) is at `u_a = a/(RU−1)`, `v_b = b/(RV−1)`
//!   ([`param`]).
//! - [`SurfaceGrid<T>`]: RU·RV points, index `a·RV + b` (u outer, v inner); optional `du()`,
//!   `dv()`, `normals()` per [`Outputs`] (`Points` < `Derivatives` < `Normals`).
//! - Level 3: [`binomial`]`(n, k) -> u64` (exact for n ≤ 63), [`binomial_row`]`(count)` =
//!   `C(count−1, k)` for k < count. Level 2: [`bernstein_table`]`(&binoms, r) -> Vec<T>` row-major
//!   `r × count` (B^u is RU×M, B^v is RV×N), [`basis_at`], [`bernstein`]`(degree, i, t)`.
//! - Evaluators, all for the same surface: [`evaluate_brf`]/[`brf_into`] (Eq. 8.1–8.2, everything
//!   recomputed), [`MatEvaluator`] (Eq. 8.4, power form, see its numerical caveat),
//!   [`MleEvaluator`] (Sec. 8.4; setters invalidate only affected levels, [`MleCounters`];
//!   `evaluate`, `evaluate_into`, `evaluate_points_into`, `evaluate_points_soa_into`,
//!   `basis_tables`).
//! - [`eval_point`]: S, ∂S/∂u, ∂S/∂v, ∂²S/∂u∂v at one (u, v). Normals: see [`normals`];
//!   [`NormalTolerance`] (the regular-normal test) and [`repair_normals`] (degenerate samples)
//!   for evaluators elsewhere.
//! - [`SurfaceEvaluator`]: the seam a planner evaluates through (points + unit normals, f64,
//!   fallible with [`BezierError::Device`]); [`MleEvaluator<f64>`] implements it; a
//!   [`SurfaceEngine`] makes one per surface ([`SurfaceEngine::cpu`] by default, GPU engines in
//!   `resecta-gpu`).
//! - [`to_trimesh`]: 2·(RU−1)·(RV−1) triangles oriented along ∂u×∂v ([`grid_triangles`]).
//! - Benchmarks: [`Method`] {Brf, Mat, Mle}, [`Prepared`] (`new`, `run`, `output`),
//!   [`write_ceiling`].
//!
//! Threads: the parallel loops (rayon) run on the caller's current pool; install a sized pool
//! with `ThreadPool::install` to control the thread count.

pub mod basis;
pub mod brf;
pub mod curvature;
pub mod error;
pub mod evaluator;
pub mod mat;
pub mod mesh;
pub mod method;
pub mod mle;
pub mod normals;
pub mod scalar;
pub mod types;

pub use basis::{basis_at, bernstein, bernstein_table, binomial, binomial_row, powi};
pub use brf::{brf_into, evaluate_brf};
pub use curvature::mean_curvature;
pub use error::BezierError;
pub use evaluator::{SurfaceEngine, SurfaceEvaluator, cpu_evaluator};
pub use mat::{MatEvaluator, power_basis_matrix};
pub use mesh::{grid_triangles, to_trimesh};
pub use method::{Method, Prepared, write_ceiling};
pub use mle::{MleCounters, MleEvaluator};
pub use normals::{NormalTolerance, PointEval, eval_point, repair_normals};
pub use scalar::{BezierScalar, P3};
pub use types::{
    ControlNet, MAX_CONTROL_POINTS, MAX_RESOLUTION, MAX_SAMPLES, Outputs, Resolution, SurfaceGrid,
    param,
};
