//! Resected and remnant liver volumes of Bézier resections (thesis Sec. 7.3.5), sub-voxel
//! accurate, with incomplete cuts reported instead of wrong numbers; and the thesis' own
//! rasterise-and-grow method for comparison. See [`cut`] for the method.

pub mod cut;
pub mod error;
pub mod liver;
pub mod thesis;

pub use cut::{CutResult, IncompleteCut, MultiCut, Volumetry};
pub use error::VolumetryError;
pub use liver::LiverVoxels;
pub use thesis::{ThesisResult, thesis_volumetry};
