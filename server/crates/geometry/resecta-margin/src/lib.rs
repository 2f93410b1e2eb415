//! Safety margins of a virtual resection (thesis Sec. 7.3.4, Eq. 7.9): for every vertex of the
//! sampled resection surface the exact distance to the nearest target-tumour surface, whether
//! it lies inside the liver, its class (outside / safe / warning / violation), and the global
//! verdict — minimum margin inside the liver refined over the continuous surface, where it
//! occurs, violating and warning areas.

pub mod error;
pub mod field;
pub mod verdict;

pub use error::MarginError;
pub use field::{MarginField, Nearest, TOLERANCE_MM};
pub use verdict::{MarginClass, MarginSettings, SurfaceMargins, SurfaceOracle, Verdict, evaluate};
