//! Paper IV (thesis ch. 9): how many points, and where, a cardiologist must collect on the
//! left atrium for Poisson reconstruction to recover it. This is a simulation, as in the
//! thesis:
//! - [`StudyAtrium`]: a reference atrium from the phantom, a label map or a mesh. It holds a
//!   dense pool of oriented surface samples to draw "catheter points" from, the reference
//!   points the error is measured from, and the [`Split`] into an upper part that holds the
//!   pulmonary veins and a lower part.
//! - [`run_study`]: for every condition (n points, fraction u from the upper part, with or
//!   without tracking noise) and repeat:
//!   1. draw round(n·u) points from the upper part and the rest from the lower;
//!   2. reconstruct by PSR at the given depth;
//!   3. take the median distance from the reference to the reconstruction.
//!
//! Pure geometry: no I/O; seeded (ChaCha8 per run), so results are the same for any thread
//! count.

mod atrium;
mod split;
mod study;

pub use atrium::{MeshSplit, StudyAtrium, sample_mesh};
pub use split::{Split, SplitSource};
pub use study::{
    ConditionResult, NoiseModel, RunResult, StudyConfig, StudyNormals, StudyResults, add_noise,
    draw, median_error, reconstruct_sample, run_sample, run_study,
};

use resecta_geom::GeomError;

/// What can go wrong setting up or running the study. Messages name the offending input.
#[derive(Debug, thiserror::Error)]
pub enum EamError {
    #[error("label(s) {labels:?} do not occur in the label map")]
    LabelsAbsent { labels: Vec<u16> },
    #[error("no vein label borders the body: the upper part cannot be found; give a plane")]
    NoOstia,
    #[error(
        "the mesh has {loops} boundary loop(s): the automatic split needs the mitral opening \
         and at least two vein openings; give a plane"
    )]
    NoVeinOpenings { loops: usize },
    #[error(
        "the split plane leaves {upper} pool points above and {lower} below; both parts need points"
    )]
    EmptyPart { upper: usize, lower: usize },
    #[error("{name} {reason}")]
    InvalidParameter { name: &'static str, reason: String },
    #[error("reconstruction: {0}")]
    Recon(#[from] resecta_recon::ReconError),
    #[error("phantom: {0}")]
    Phantom(#[from] resecta_phantom::PhantomError),
    #[error(transparent)]
    Geometry(#[from] GeomError),
}
