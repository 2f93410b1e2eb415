//! Resected and remnant liver volumes of Bézier resections (thesis Sec. 7.3.5), sub-voxel
//! accurate, with incomplete cuts reported instead of wrong numbers; and the thesis' own
//! rasterise-and-grow method for comparison. See [`cut`] for the method, and [`accel`] for the
//! seam through which an accelerator (the GPU) computes a cut's band and side components.

pub mod accel;
pub mod cut;
pub mod error;
pub mod liver;
pub mod thesis;

pub use accel::{
    AcceleratorError, AcceleratorFactory, BandComponents, BandQuery, BandVoxel, CutAccelerator,
    SlabDisc,
};
pub use cut::{CutResult, IncompleteCut, MultiCut, Volumetry};
pub use error::VolumetryError;
pub use liver::LiverVoxels;
pub use thesis::{ThesisResult, thesis_volumetry};
