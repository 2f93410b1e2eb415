//! Resection planning (thesis ch. 7, Paper II): plans of Bézier, drawn-on-slices (DS) and
//! deformable-cutting-plane (CP) resections, the Bézier initialisation from a tumour and an end
//! point, edits with undo/redo and replay, live safety margins, slice
//! projections, label-map slices and volumetry, and the `resecta-plan/1` file format.

pub mod anatomy;
#[cfg(test)]
mod apply_once;
pub mod engine;
pub mod error;
pub mod history;
pub mod init;
mod inside;
pub mod label_slice;
pub mod metrics;
pub mod plan;
pub mod probe;
pub mod resection;
pub mod resectogram;
pub mod surface;
pub mod vascular;

pub use anatomy::{Anatomy, Tumour};
pub use engine::{
    DEFAULT_FLR_THRESHOLD_PCT, Planner, ResectionState, ResectionVolume, TargetModel, VolumeJob,
    VolumeReport,
};
pub use error::PlanError;
pub use history::{Change, History, LogEntry, Staged};
pub use init::{Initialisation, initialise, plane_from, slicing_plane};
pub use inside::InsideLayout;
pub use label_slice::{LabelSlice, SliceAxis, label_slice};
pub use metrics::{
    ResectionMetrics, VIOLATION_DEVIATION_MM, resection_metrics, volume_deviation_pct,
};
pub use plan::{FORMAT, MAX_RESECTIONS, Plan, PlanEvent};
pub use probe::{ComputeEngine, ProbeEngine, SampleProbe};
pub use resecta_margin::{MarginClass, Verdict};
pub use resecta_traces as traces;
pub use resecta_traces::{Deformation, SliceOrientation};
pub use resecta_volumetry::{IncompleteCut, Volumetry};
pub use resection::{Group, Resection, ResectionKind, Target};
pub use resectogram::Resectogram;
pub use surface::{LiveSurface, SlicePositions, SliceProjections, slice_projections};
pub use vascular::{CutVessel, RiskMap, RiskReport, Vascular, risk_class};
