//! Screened Poisson surface reconstruction, the implicit half (thesis Ch. 6.2): oriented points
//! from a binary mask ([`oriented_points`]) and a dense, deterministic multigrid solver for the
//! indicator field ([`solve`]). Marching cubes on [`PoissonField`] gives the mesh.
//!
//! Pure geometry: no I/O, parallel with rayon, bitwise identical results for any thread count.

mod error;
mod multigrid;
mod points;
mod solve;

pub use error::PoissonError;
pub use points::{MIN_POINTS, OrientedPoints, oriented_points};
pub use solve::{MAX_DEPTH, PoissonField, PoissonParams, SolveReport, bytes_needed, solve};
