//! Requests, answers and watch events of the operation layer: plain Rust values the gRPC and
//! HTTP edges translate to and from their wire types.

use std::collections::BTreeMap;

use resecta_geom::{Real, RoleMap};
use resecta_plan::{PlanEvent, Resection, Target, Verdict, VolumeReport};
pub use resecta_recon::{
    CloudReport, DEFAULT_CLOUD_DEPTH, DEFAULT_CLOUD_NEIGHBOURS, MAX_CLOUD_NEIGHBOURS,
    MIN_CLOUD_NEIGHBOURS, MIN_CLOUD_POINTS, NormalSource,
};

pub use crate::labelmap::{MAX_EXTENT_MM, MAX_ORIGIN_MM, SPACING_MM};
pub use crate::sessions::MAX_DISPLAY_NAME;

/// The API generation clients must speak.
pub const API_VERSION: &str = "resecta.v1";

/// Where clients reach the replica that holds a session (replicated servers).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplicaAddress {
    pub id: String,
    /// `host:port` of its gRPC face.
    pub grpc: String,
    /// Base URL of its HTTP face.
    pub http: String,
    /// Until its lease expires unless renewed.
    pub lease_remaining_ms: u64,
}

#[derive(Debug, Clone)]
pub struct ServerInfo {
    pub version: &'static str,
    pub api_version: &'static str,
    pub capabilities: Vec<String>,
    pub limits: Limits,
    pub compute: ComputeInfo,
}

/// Where the planners evaluate their surfaces, as chosen at start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ComputeInfo {
    /// `"cpu"` or `"wgpu"`.
    pub backend: String,
    /// The GPU adapter's name (empty on the CPU).
    pub adapter: String,
    /// Whether the GPU evaluates in f64 (`SHADER_F64`); f32 otherwise.
    pub f64: bool,
}

impl Default for ComputeInfo {
    fn default() -> Self {
        Self {
            backend: "cpu".into(),
            adapter: String::new(),
            f64: true,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Limits {
    pub max_sessions: usize,
    pub max_voxels: u64,
    pub max_upload_bytes: u64,
    pub max_memory_bytes: u64,
    pub max_cloud_points: usize,
    pub max_cloud_depth: u32,
}

/// Where a session is in the workflow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionState {
    /// Created, no label map yet.
    Empty,
    /// A label map is loaded: planning works.
    LabelMap,
    /// Surface models are built too.
    Ready,
    /// Stored, but it cannot be restored (its stored data is unreadable or out of bounds);
    /// only deleting it works.
    Damaged,
}

#[derive(Debug, Clone)]
pub struct SessionInfo {
    pub id: String,
    pub display_name: String,
    pub created_ms: i64,
    pub last_access_ms: i64,
    pub state: SessionState,
    /// Number of acknowledged plan changes (label-map loads, imports, edits, undo, redo).
    pub plan_version: u64,
    pub label_map: Option<LabelMapSummary>,
}

/// Geometry and contents of a loaded label map.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelMapSummary {
    pub dims: [usize; 3],
    pub spacing: [Real; 3],
    pub origin: [Real; 3],
    /// Row-major 3×3; column c is the RAS direction of index axis c.
    pub direction: [Real; 9],
    /// Voxels per non-zero label.
    pub labels: BTreeMap<u16, u64>,
    /// Functional liver volume (every liver role, tumours excluded), ml.
    pub liver_ml: Real,
    pub roles: RoleMap,
}

/// Voxel type of raw uploaded data (little-endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataType {
    U8,
    U16,
    I16,
    U32,
    I32,
}

impl DataType {
    pub fn size(self) -> usize {
        match self {
            Self::U8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 => 4,
        }
    }
}

/// A label map as raw voxels with its geometry.
#[derive(Debug, Clone)]
pub struct RawLabelMap {
    pub dims: [usize; 3],
    pub spacing: [Real; 3],
    pub origin: [Real; 3],
    /// Row-major 3×3; column c is the RAS direction of index axis c.
    pub direction: [Real; 9],
    pub data_type: DataType,
    /// `dims` voxels of `data_type`, i fastest.
    pub data: Vec<u8>,
}

impl RawLabelMap {
    /// A label map as an upload of its voxels (u16, little-endian) with its geometry.
    pub fn of(labels: &resecta_geom::LabelMap) -> Self {
        let g = labels.grid();
        let d = g.direction();
        Self {
            dims: g.dims(),
            spacing: g.spacing(),
            origin: g.origin().into(),
            direction: std::array::from_fn(|k| d[(k / 3, k % 3)]),
            data_type: DataType::U16,
            data: labels.data().iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
}

/// PSR depths a reconstruction may ask for (`ReconOptions::psr_depth`).
pub const PSR_DEPTHS: std::ops::RangeInclusive<u32> = 1..=10;
/// MCSD smoothing factors (`ReconOptions::smoothing`).
pub const SMOOTHING: std::ops::RangeInclusive<f64> = 0.0..=1.0;
/// MCSD decimation fractions (`ReconOptions::decimation`).
pub const DECIMATION: std::ops::Range<f64> = 0.0..1.0;

/// Image file formats accepted as label-map uploads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileFormat {
    Nifti,
    Nrrd,
    SegNrrd,
    MetaImage,
    /// From the bytes' magic.
    Auto,
}

#[derive(Debug, Clone)]
pub enum LabelMapSource {
    Raw(RawLabelMap),
    File { format: FileFormat, bytes: Vec<u8> },
}

/// One plan change.
#[derive(Debug, Clone, PartialEq)]
pub enum EditOp {
    /// Any plan event (set control points, move groups, translate, rotate, margins, ...).
    Event {
        event: PlanEvent,
    },
    /// A new resection initialised from its target tumour(s) and an end point (Alg. 1–2).
    InitFromEndPoint {
        name: String,
        target: Target,
        end_point: [Real; 3],
        grid: [usize; 2],
    },
    /// A new resection on the plane through `point` with `normal`.
    InitFromPlane {
        name: String,
        target: Target,
        point: [Real; 3],
        normal: [Real; 3],
        grid: [usize; 2],
    },
    Undo,
    Redo,
}

/// Control points per direction of a new resection when the edit names none.
pub const DEFAULT_GRID: [usize; 2] = [4, 4];

#[derive(Debug, Clone)]
pub struct EditOutcome {
    pub plan_version: u64,
    /// Resections the change added or changed, with their parameters and verdicts now.
    pub resections: Vec<ResectionStatus>,
    /// Resections the change deleted.
    pub removed: Vec<String>,
}

/// A resection's parameters and margin verdict.
#[derive(Debug, Clone)]
pub struct ResectionStatus {
    pub resection: Resection,
    pub verdict: Option<Verdict>,
}

/// A value read from a session with the plan version it belongs to.
#[derive(Debug, Clone)]
pub struct Versioned<T> {
    pub plan_version: u64,
    pub value: T,
}

/// Surface models of one reconstruction.
#[derive(Debug, Clone)]
pub struct ModelInfo {
    pub name: String,
    pub kind: SurfaceKind,
    /// The label value (segment) the model was built from; for the parenchyma its label when
    /// the role has one, 0 otherwise.
    pub label: u16,
    pub method: String,
    pub triangles: usize,
    pub vertices: usize,
    pub volume_ml: Real,
}

/// Reconstruction methods for the parenchyma (tumours and vessels always use MCSD).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReconMethod {
    /// Screened Poisson at the given depth (the thesis' preferred parenchyma model).
    #[default]
    Psr,
    /// Marching cubes, smoothing and decimation, as for the other models.
    Mcsd,
}

/// Options of one reconstruction; every field defaults to the server's choice (PSR at the
/// configured depth, MCSD smoothing 0.5 and no decimation, one model per vessel label, specks
/// below 10 mm³ left out).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReconOptions {
    pub method: ReconMethod,
    /// PSR depth, 1..=10; absent: the server's configured depth. Checked whatever the method.
    pub psr_depth: Option<u32>,
    /// MCSD smoothing factor in [0, 1]; 0 disables smoothing.
    pub smoothing: Option<Real>,
    /// MCSD fraction of triangles removed, in [0, 1); 0 disables decimation.
    pub decimation: Option<Real>,
    /// One vessel model per face-connected component instead of one per label (tumours are
    /// always one per component).
    pub split_components: bool,
    /// Vessel components smaller than this (mm³, ≥ 0) are left out and counted; absent: 10.
    /// Tumours always use 10 mm³, the planner's rule for targets.
    pub min_component_mm3: Option<Real>,
}

/// Components of one role left out of the models as specks.
#[derive(Debug, Clone, PartialEq)]
pub struct DroppedComponents {
    pub kind: SurfaceKind,
    pub count: usize,
    pub volume_ml: Real,
}

#[derive(Debug, Clone)]
pub enum ReconstructEvent {
    Progress {
        stage: String,
        fraction: Real,
    },
    Model {
        model: ModelInfo,
    },
    Done {
        models: usize,
        time_ms: Real,
        /// Specks left out, one entry per role with any.
        dropped: Vec<DroppedComponents>,
        /// The vessel speck volume used (mm³).
        min_component_mm3: Real,
    },
}

/// A point cloud to close into a surface (`ReconstructPoints`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// RAS mm.
    pub positions: Vec<[Real; 3]>,
    /// Outward normals, one per point, of any non-zero length; `None`: estimated.
    pub normals: Option<Vec<[Real; 3]>>,
    /// PSR depth, `1..=ServiceConfig::max_cloud_depth`; `None`: [`DEFAULT_CLOUD_DEPTH`].
    pub depth: Option<u32>,
    /// Neighbours per point for normals and areas,
    /// [`MIN_CLOUD_NEIGHBOURS`]`..=`[`MAX_CLOUD_NEIGHBOURS`] and fewer than the distinct
    /// points; `None`: [`DEFAULT_CLOUD_NEIGHBOURS`].
    pub neighbours: Option<usize>,
    /// The client decodes zstd-compressed mesh payloads (used when the server compresses).
    pub allow_zstd: bool,
    /// The client decodes quantised positions and normals (used when the server quantises).
    pub allow_quantized: bool,
}

/// The closed surface of a point cloud.
#[derive(Debug, Clone)]
pub struct CloudSurface {
    /// The mesh in the `resecta-delta` format (magic `RSMS`): positions, vertex normals,
    /// triangles.
    pub mesh: Vec<u8>,
    pub vertices: usize,
    pub triangles: usize,
    /// Volume enclosed by the mesh, ml.
    pub volume_ml: Real,
    /// Neighbours per point used.
    pub neighbours: usize,
    pub report: CloudReport,
}

/// What a surface shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfaceKind {
    Parenchyma,
    Tumor,
    Portal,
    Hepatic,
    Vessel,
    Resection,
}

impl SurfaceKind {
    /// Suggested display colour, after 3D Slicer's GenericAnatomyColors and Slicer-Liver (liver
    /// brown and translucent, tumour green, portal vein violet, hepatic vein blue, unsplit vessels
    /// red); `None` for resections, which clients colour by margin class.
    pub fn display_color(self) -> Option<[f32; 4]> {
        match self {
            Self::Parenchyma => Some([0.867, 0.510, 0.396, 0.35]),
            Self::Tumor => Some([0.306, 0.706, 0.306, 1.0]),
            Self::Portal => Some([0.788, 0.373, 0.733, 1.0]),
            Self::Hepatic => Some([0.0, 0.592, 0.808, 1.0]),
            Self::Vessel => Some([0.847, 0.396, 0.310, 1.0]),
            Self::Resection => None,
        }
    }
}

/// A whole surface: `mesh` is a `resecta-delta` mesh encoding (magic `RSMS`).
#[derive(Debug, Clone)]
pub struct Surface {
    pub name: String,
    pub kind: SurfaceKind,
    /// As [`ModelInfo::label`]; 0 for resections.
    pub label: u16,
    /// Suggested display colour (RGBA, 0–1): [`SurfaceKind::display_color`].
    pub color: Option<[f32; 4]>,
    pub mesh: Vec<u8>,
}

impl Surface {
    /// A surface of `kind` (label 0, the kind's colour).
    pub fn new(name: String, kind: SurfaceKind, mesh: Vec<u8>) -> Self {
        Self::labelled(name, kind, 0, mesh)
    }

    /// A model surface built from `label`.
    pub fn labelled(name: String, kind: SurfaceKind, label: u16, mesh: Vec<u8>) -> Self {
        Self {
            name,
            kind,
            label,
            color: kind.display_color(),
            mesh,
        }
    }
}

/// A resection surface after an edit: a delta against the previous frame (magic `RSDL`) when
/// the topology is unchanged, else the whole mesh.
#[derive(Debug, Clone)]
pub struct SurfaceUpdate {
    pub name: String,
    pub full: bool,
    pub bytes: Vec<u8>,
}

#[derive(Debug, Clone)]
pub enum WatchBody {
    /// Everything: models, resection surfaces with their verdicts, the last volumes.
    Snapshot {
        models: Vec<Surface>,
        resections: Vec<Surface>,
        verdicts: BTreeMap<String, Verdict>,
        /// Every resection's parameters (grid, control points, margin, ...).
        resection_params: BTreeMap<String, Resection>,
        volumes: Option<VolumeReport>,
    },
    /// Resection surfaces that changed, removed ones, and the verdicts of the changed ones.
    Delta {
        updates: Vec<SurfaceUpdate>,
        removed: Vec<String>,
        verdicts: BTreeMap<String, Verdict>,
        /// The changed resections' parameters, so every watcher sees control points move.
        resections: BTreeMap<String, Resection>,
    },
    /// New surface models (after a reconstruction).
    Models { models: Vec<Surface> },
    /// Volumes after the edits settled.
    Volumes { volumes: VolumeReport },
}

/// One message of a session's watch stream.
#[derive(Debug, Clone)]
pub struct WatchEvent {
    /// Increases by one per event of this session (since the server started).
    pub seq: u64,
    pub plan_version: u64,
    pub body: WatchBody,
}

impl WatchEvent {
    /// Payload bytes (for the replay ring's byte bound).
    pub fn weight(&self) -> usize {
        let surfaces = |s: &[Surface]| s.iter().map(|s| s.mesh.len() + 64).sum::<usize>();
        256 + match &self.body {
            WatchBody::Snapshot {
                models, resections, ..
            } => surfaces(models) + surfaces(resections),
            WatchBody::Delta { updates, .. } => updates.iter().map(|u| u.bytes.len() + 64).sum(),
            WatchBody::Models { models } => surfaces(models),
            WatchBody::Volumes { .. } => 512,
        }
    }
}
