//! Live safety margins on a resection surface (thesis Sec. 7.3.4, Eq. 7.9): pure, synchronous.
//!
//! # API summary
//! - [`MarginField`]: `new(tumours, region_min, region_max, spacing_mm)` builds an oriented-box
//!   hierarchy over the tumour triangles and a grid of exact nearest-triangle hints over the
//!   region (at most [`MAX_HINT_NODES`] nodes). Exact queries (the brute-force distance to
//!   ~1e-14 mm), anywhere: `nearest(p)` → [`Nearest`] (distance, point, triangle);
//!   `nearest_into` / `distances_into` for many points; `distances_grid_into(ru, rv, ..)` for the
//!   samples of a surface grid (fastest: 4×4 blocks walked together). Bulk calls use rayon and
//!   return a [`MarginError`] only for mismatched lengths.
//! - [`MarginSettings`] (margin > 0, band ≥ 0; `validate`, `classify`), [`MarginClass`]
//!   {Outside, Safe, Warning, Violation} (`repr(u8)`), [`SurfaceOracle`] (the surface at any
//!   (u, v) and the liver's inside level: > 0 inside).
//! - [`evaluate`] / [`evaluate_into`] (reusing the output buffers): per-vertex distances and
//!   classes of an ru×rv sample grid ([`SurfaceMargins`], index `i·rv + j`, u along i) and the
//!   [`Verdict`]: the minimum margin inside the liver refined between samples (point and (u, v)),
//!   the violation flag, and the violating / warning / inside areas of the grid triangles clipped
//!   by the linear interpolants of distance and inside level.
//! - [`evaluate_exact_into`]: the same from exact distances computed elsewhere (a GPU).
//! - [`evaluate_reusing`] with a [`MarginMemo`] per surface: as `evaluate_into`, but samples that
//!   moved little since their last query keep their distance (1-Lipschitz bound) while it stays
//!   within tolerance — the live path of a drag.
//!
//! - [`MarginField::tree`] ([`ObbTree`]: nodes, triangles, prepared triangle data, reach) and
//!   [`MarginField::hints`]: the search structure, read-only, for accelerators that walk it
//!   themselves (`resecta-gpu`'s margin kernel).
//!
//! Threads: parallel loops run on the caller's current rayon pool; results do not depend on the
//! number of threads.

mod error;
mod evaluate;
mod field;
mod tree;

pub use error::MarginError;
pub use evaluate::{
    FAR_TOLERANCE_MM, MarginClass, MarginMemo, MarginSettings, OUTSIDE_TOLERANCE_MM,
    SurfaceMargins, SurfaceOracle, TOLERANCE_MM, Verdict, evaluate, evaluate_exact_into,
    evaluate_into, evaluate_reusing,
};
pub use field::{MAX_HINT_NODES, MarginField, Nearest};
pub use tree::{COUNT_BITS, ObbNode, ObbTree, PreparedTriangle, STACK};
