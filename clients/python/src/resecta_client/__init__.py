"""Python client of the resecta liver-resection planning server (gRPC, `resecta.v1`).

    from resecta_client import Client

    with Client("127.0.0.1:50051", token=None) as client:
        session = client.create_session("case 12")
        session.upload_label_map(labels_kji, ijk_to_ras, {"parenchyma": [1], "tumor": [2]})
        models = session.reconstruct("psr", progress=lambda f, stage: print(f, stage))
        r = session.init_from_end_point("r1", end_point=(-30, 0, 0))
        print(r["r1"].verdict.min_margin_mm, session.volumes().remnant_pct)

See README.md for the API, the array convention and the exceptions.
"""

from .client import API_VERSION, CHUNK_BYTES, Client, Session, Watch
from .errors import (
    AuthError,
    Cancelled,
    DeadlineExceeded,
    FailedPrecondition,
    InvalidArgument,
    NotFound,
    QuotaExceeded,
    ResectaError,
    ServerError,
    ServerUnavailable,
    SessionNotFound,
    StaleVersion,
    Unsupported,
    VersionMismatch,
)
from .geometry import compose, decompose, label_bytes
from .scene import LiveScene, SceneUpdate, SurfaceState
from .types import (
    ComputeInfo,
    ControlGroup,
    CutVessel,
    Deformation,
    DroppedComponents,
    EditResult,
    LabelCount,
    LabelMapSummary,
    LabelSlice,
    MarginClass,
    Method,
    ModelFormat,
    ModelInfo,
    NormalSource,
    PointCloudReport,
    PointCloudSurface,
    Polyline,
    Reconstruction,
    Resection,
    ResectionKind,
    ResectionMetrics,
    ResectionStatus,
    ResectionVolume,
    Resectogram,
    Risk,
    RiskClass,
    RiskMap,
    ServerInfo,
    ServerLimits,
    SessionInfo,
    SessionState,
    SliceAxis,
    Slices,
    SurfaceKind,
    Target,
    Verdict,
    Volumes,
)
from .vtk_adapter import to_vtk_polydata, vtk_available
from .wire import WireError

__version__ = "0.1.0"

__all__ = [
    "API_VERSION",
    "CHUNK_BYTES",
    "AuthError",
    "Cancelled",
    "Client",
    "ComputeInfo",
    "ControlGroup",
    "CutVessel",
    "DeadlineExceeded",
    "Deformation",
    "DroppedComponents",
    "EditResult",
    "FailedPrecondition",
    "InvalidArgument",
    "LabelCount",
    "LabelMapSummary",
    "LabelSlice",
    "LiveScene",
    "MarginClass",
    "Method",
    "ModelFormat",
    "ModelInfo",
    "NormalSource",
    "PointCloudReport",
    "PointCloudSurface",
    "NotFound",
    "Polyline",
    "QuotaExceeded",
    "Reconstruction",
    "ResectaError",
    "Resection",
    "ResectionKind",
    "ResectionMetrics",
    "ResectionStatus",
    "Resectogram",
    "Risk",
    "RiskClass",
    "RiskMap",
    "ResectionVolume",
    "SceneUpdate",
    "ServerError",
    "ServerInfo",
    "ServerLimits",
    "ServerUnavailable",
    "Session",
    "SessionInfo",
    "SessionNotFound",
    "SessionState",
    "SliceAxis",
    "Slices",
    "StaleVersion",
    "SurfaceKind",
    "SurfaceState",
    "Target",
    "Unsupported",
    "Verdict",
    "VersionMismatch",
    "Volumes",
    "Watch",
    "WireError",
    "compose",
    "decompose",
    "label_bytes",
    "to_vtk_polydata",
    "vtk_available",
]
