//! Screened Poisson surface reconstruction, the implicit half (thesis Ch. 6.2): oriented points
//! from a binary mask ([`oriented_points`]) and a dense, deterministic multigrid solver for the
//! indicator field ([`solve`]). Marching cubes on [`PoissonField`] gives the mesh.
//!
//! The multigrid is a seam ([`MultigridSolver`], [`solve_with`]): the system is assembled here
//! and solved by the CPU ([`CpuMultigrid`], the default) or by a device solver of the same
//! schedule (`resecta-gpu`). Oriented points have the same seam for their Sobel pass
//! ([`SobelPass`], [`oriented_points_with`]); [`PoissonSolver`] carries both.
//!
//! Pure geometry: no I/O, parallel with rayon, bitwise identical results for any thread count.

mod error;
mod multigrid;
mod points;
mod solve;
mod system;

pub use error::PoissonError;
pub use points::{
    CpuSobel, MIN_POINTS, MaskBox, OrientedPoints, SobelPass, mask_box, oriented_points,
    oriented_points_with, sobel,
};
pub use solve::{
    MAX_DEPTH, PoissonField, PoissonParams, SolveReport, bytes_needed, solve, solve_with,
};
pub use system::{
    COARSEST_SWEEPS, CpuMultigrid, MultigridSolver, PoissonSolver, Solution, System, SystemLevel,
};
