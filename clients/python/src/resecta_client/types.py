"""The results and parameters of the client API as plain dataclasses (no protobuf), with the
conversions from and to the `resecta.v1` messages. Coordinates are RAS millimetres, volumes ml,
areas mm², angles degrees, times milliseconds since the Unix epoch."""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

from ._gen import (
    common_pb2,
    label_map_pb2,
    planning_service_pb2,
    reconstruction_pb2,
    resection_pb2,
    session_pb2,
    surface_pb2,
    volumes_pb2,
)
from . import wire
from .geometry import compose

F64: TypeAlias = npt.NDArray[np.float64]
F32: TypeAlias = npt.NDArray[np.float32]
Point: TypeAlias = Sequence[float] | npt.ArrayLike
"""Anything of 3 numbers: a tuple, a list, a numpy array (RAS mm)."""

ROLES = ("parenchyma", "tumor", "portal", "hepatic", "vessel")
"""The roles of a role map (`RoleMap` in proto/resecta/v1/common.proto)."""


class _Named(enum.StrEnum):
    """A str enum mapped onto a protobuf enum `<PREFIX>_<VALUE>`."""

    @classmethod
    def parse(cls, value: str | _Named) -> Any:
        try:
            return cls(value.lower() if isinstance(value, str) else value)
        except ValueError:
            allowed = ", ".join(m.value for m in cls)
            raise ValueError(f"unknown {cls.__name__} {value!r} (one of {allowed})") from None

    def to_pb(self) -> int:
        pb_enum, prefix = self._pb()
        return int(pb_enum.Value(f"{prefix}_{self.name}"))

    @classmethod
    def from_pb(cls, number: int) -> Any:
        pb_enum, prefix = cls._pb()
        return cls[pb_enum.Name(number).removeprefix(f"{prefix}_")]

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        """The protobuf enum and its value prefix."""
        raise NotImplementedError


class SessionState(_Named):
    """What a session holds: nothing yet, a label map, or built models (ready to plan); or
    damaged: stored but not restorable (only deleting it works)."""

    UNSPECIFIED = "unspecified"
    EMPTY = "empty"
    LABEL_MAP = "label_map"
    READY = "ready"
    DAMAGED = "damaged"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return session_pb2.SessionState, "SESSION_STATE"


class SurfaceKind(_Named):
    """What a surface shows."""

    UNSPECIFIED = "unspecified"
    PARENCHYMA = "parenchyma"
    TUMOR = "tumor"
    PORTAL = "portal"
    HEPATIC = "hepatic"
    VESSEL = "vessel"
    RESECTION = "resection"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return surface_pb2.SurfaceKind, "SURFACE_KIND"


class Method(_Named):
    """Reconstruction method: MCSD for every model, or PSR for the liver (tumours and vessels by
    MCSD)."""

    MCSD = "mcsd"
    PSR = "psr"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return reconstruction_pb2.ReconstructionMethod, "RECONSTRUCTION_METHOD"


class ModelFormat(_Named):
    """File format of an exported mesh."""

    VTP = "vtp"
    VTK = "vtk"
    STL = "stl"
    PLY = "ply"
    OBJ = "obj"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return surface_pb2.ModelFormat, "MODEL_FORMAT"


class ControlGroup(_Named):
    """A named group of control points: the inner points, the border ring, or all."""

    INNER = "inner"
    OUTER = "outer"
    ALL = "all"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return resection_pb2.ControlGroup, "CONTROL_GROUP"


class SliceAxis(_Named):
    """The RAS axis a label slice's plane is normal to: axial (z; columns +x, rows +y), coronal
    (y; columns +x, rows +z), sagittal (x; columns +y, rows +z)."""

    AXIAL = "axial"
    CORONAL = "coronal"
    SAGITTAL = "sagittal"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return planning_service_pb2.SliceAxis, "SLICE_AXIS"


class ResectionKind(_Named):
    """The kind of a resection's surface (thesis Table 7.1): a Bézier surface given by control
    points, a surface drawn on slices (DS) or a deformable cutting plane (CP), both given by
    traces."""

    BEZIER = "bezier"
    DS = "ds"
    CP = "cp"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return resection_pb2.ResectionKind, "RESECTION_KIND"

    @classmethod
    def from_pb(cls, number: int) -> Any:
        # UNSPECIFIED (never sent by the server) means a Bézier resection, as the server reads it.
        return cls.BEZIER if number == 0 else super().from_pb(number)


class MarginClass(enum.IntEnum):
    """Per-vertex margin class of a resection surface (`SurfaceState.classes`)."""

    OUTSIDE = 0
    """Outside the liver (does not count)."""
    SAFE = 1
    WARNING = 2
    """Within the warning band beyond the margin."""
    VIOLATION = 3
    """Closer to a target tumour than the margin."""


# --- conversions of small geometry ---------------------------------------------------------


def vec3(p: Point) -> common_pb2.Vec3:
    """A `Vec3` of 3 finite numbers (ValueError otherwise)."""
    a = np.asarray(p, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"a point needs 3 coordinates, got {a.size}")
    return common_pb2.Vec3(x=float(a[0]), y=float(a[1]), z=float(a[2]))


def _xyz(v: common_pb2.Vec3) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def role_map(roles: Mapping[str, Iterable[int] | int]) -> common_pb2.RoleMap:
    """A `RoleMap` from a dict role → label value(s), e.g. ``{"parenchyma": [1], "tumor": 2}``."""
    unknown = set(roles) - set(ROLES)
    if unknown:
        raise ValueError(f"unknown roles {sorted(unknown)} (known: {', '.join(ROLES)})")
    return common_pb2.RoleMap(
        **{r: [v] if isinstance(v, int) else [int(x) for x in v] for r, v in roles.items()}
    )


def _roles(m: common_pb2.RoleMap) -> dict[str, list[int]]:
    return {r: list(getattr(m, r)) for r in ROLES if getattr(m, r)}


# --- server, sessions, label maps ----------------------------------------------------------


@dataclass(frozen=True)
class ServerLimits:
    """Limits the server enforces (0: no limit of that kind)."""

    max_voxels: int
    max_sessions: int
    max_upload_bytes: int
    max_chunk_bytes: int
    max_message_bytes: int
    max_resections: int
    max_control_points: int
    max_resolution: int
    session_idle_timeout_s: int
    max_resectogram_side: int = 0
    max_cloud_points: int = 0
    max_cloud_depth: int = 0


@dataclass(frozen=True)
class ComputeInfo:
    """Where the server's planners evaluate surfaces: backend ``"cpu"`` or ``"wgpu"``, the GPU
    adapter's name (empty on the CPU), and whether in 64-bit floats."""

    backend: str
    adapter: str
    f64: bool


@dataclass(frozen=True)
class ServerInfo:
    """The server's identity, the API it speaks (``"resecta.v1"``), capabilities (``gpu``,
    ``tls``, ``auth``, ``zstd``, ``quantized``, ``psr``), limits and compute backend."""

    server_version: str
    api_version: str
    capabilities: tuple[str, ...]
    limits: ServerLimits
    compute: ComputeInfo

    @classmethod
    def from_pb(cls, m: planning_service_pb2.GetServerInfoResponse) -> ServerInfo:
        lim = m.limits
        limits = ServerLimits(**{f: getattr(lim, f) for f in ServerLimits.__dataclass_fields__})
        c = m.compute
        compute = ComputeInfo(c.backend or "cpu", c.adapter, c.f64 if c.backend else True)
        return cls(m.server_version, m.api_version, tuple(m.capabilities), limits, compute)


@dataclass(frozen=True)
class LabelCount:
    """Voxels of one label value, and their volume."""

    label: int
    voxels: int
    volume_ml: float


@dataclass(frozen=True, eq=False)
class LabelMapSummary:
    """What the server made of an uploaded label map: its grid (`direction` has unit columns,
    the RAS directions of i, j, k), roles and label counts."""

    dims: tuple[int, int, int]
    spacing: tuple[float, float, float]
    origin: tuple[float, float, float]
    direction: F64  # (3, 3)
    roles: dict[str, list[int]]
    labels: tuple[LabelCount, ...]
    liver_volume_ml: float

    @property
    def ijk_to_ras(self) -> F64:
        """The 4×4 IJK→RAS matrix (Slicer's IJKToRAS): ``direction · diag(spacing)``, origin."""
        return compose(self.origin, self.spacing, self.direction)

    @classmethod
    def from_pb(cls, m: label_map_pb2.LabelMapSummary) -> LabelMapSummary:
        return cls(
            dims=(m.dims[0], m.dims[1], m.dims[2]),
            spacing=(m.spacing[0], m.spacing[1], m.spacing[2]),
            origin=(m.origin[0], m.origin[1], m.origin[2]),
            direction=np.array(m.direction, dtype=np.float64).reshape(3, 3),
            roles=_roles(m.roles),
            labels=tuple(LabelCount(c.label, c.voxels, c.volume_ml) for c in m.labels),
            liver_volume_ml=m.liver_volume_ml,
        )


@dataclass(frozen=True)
class SessionInfo:
    """One session's metadata."""

    id: str
    display_name: str
    created_ms: int
    last_access_ms: int
    state: SessionState
    plan_version: int
    label_map: LabelMapSummary | None

    @classmethod
    def from_pb(cls, m: session_pb2.Session) -> SessionInfo:
        return cls(
            id=m.id,
            display_name=m.display_name,
            created_ms=m.created_ms,
            last_access_ms=m.last_access_ms,
            state=SessionState.from_pb(m.state),
            plan_version=m.plan_version,
            label_map=LabelMapSummary.from_pb(m.label_map) if m.HasField("label_map") else None,
        )


# --- reconstruction --------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelInfo:
    """One surface model a reconstruction built (its mesh comes with `watch` or
    `export_model`)."""

    name: str
    kind: SurfaceKind
    label: int
    triangle_count: int
    vertex_count: int
    volume_ml: float

    @classmethod
    def from_pb(cls, m: reconstruction_pb2.ModelInfo) -> ModelInfo:
        kind = SurfaceKind.from_pb(m.kind)
        return cls(m.name, kind, m.label, m.triangle_count, m.vertex_count, m.volume_ml)


@dataclass(frozen=True)
class DroppedComponents:
    """Components of one role too small to model (below the speck volume)."""

    kind: SurfaceKind
    count: int
    volume_ml: float

    @classmethod
    def from_pb(cls, m: reconstruction_pb2.DroppedComponents) -> DroppedComponents:
        return cls(SurfaceKind.from_pb(m.kind), m.count, m.volume_ml)


@dataclass(frozen=True)
class Reconstruction(Sequence[ModelInfo]):
    """The models a reconstruction built, in order (a sequence of `ModelInfo`), with the specks
    it left out (`dropped`, one entry per role with any), the vessel speck volume it used (mm³)
    and its wall time on the server."""

    models: tuple[ModelInfo, ...]
    dropped: tuple[DroppedComponents, ...]
    min_component_mm3: float
    elapsed_s: float

    @classmethod
    def from_pb(
        cls, models: Iterable[ModelInfo], done: reconstruction_pb2.ReconstructDone
    ) -> Reconstruction:
        dropped = tuple(DroppedComponents.from_pb(d) for d in done.dropped)
        return cls(tuple(models), dropped, done.min_component_mm3, done.elapsed_s)

    def __len__(self) -> int:
        return len(self.models)

    def __getitem__(self, index: Any) -> Any:
        return self.models[index]


# --- point clouds ---------------------------------------------------------------------------


class NormalSource(_Named):
    """Where a point cloud's normals came from: given with the points, or estimated (local
    PCA, oriented outward over the neighbour graph)."""

    UNSPECIFIED = "unspecified"
    GIVEN = "given"
    ESTIMATED = "estimated"

    @classmethod
    def _pb(cls) -> tuple[Any, str]:
        return reconstruction_pb2.NormalSource, "NORMAL_SOURCE"


def _opt(m: Any, name: str) -> Any:
    """An optional field's value, None when absent."""
    return getattr(m, name) if m.HasField(name) else None


@dataclass(frozen=True)
class PointCloudReport:
    """How the server read and solved a point cloud: `points` given, `distinct` positions,
    where the `normals` came from; with estimated normals the neighbour graph's `components`,
    the `degenerate` points (collinear neighbourhoods) and the median nearest-point `spacing_mm`
    (None with given normals); the summed point areas `sampled_area_mm2` (an estimate of the
    surface's area), the PSR `depth` and `neighbours` used, the finest Poisson cell `cell_mm`,
    and the server's wall times in seconds."""

    points: int
    distinct: int
    normals: NormalSource
    components: int | None
    degenerate: int | None
    spacing_mm: float | None
    sampled_area_mm2: float
    depth: int
    neighbours: int
    cell_mm: float
    normals_s: float
    solve_s: float
    surface_s: float

    @classmethod
    def from_pb(cls, m: reconstruction_pb2.PointCloudReport) -> PointCloudReport:
        return cls(
            m.points,
            m.distinct,
            NormalSource.from_pb(m.normals),
            _opt(m, "components"),
            _opt(m, "degenerate"),
            _opt(m, "spacing_mm"),
            m.sampled_area_mm2,
            m.depth,
            m.neighbours,
            m.cell_mm,
            m.normals_s,
            m.solve_s,
            m.surface_s,
        )


@dataclass(frozen=True, eq=False)
class PointCloudSurface:
    """The closed surface of a point cloud (`Client.reconstruct_points`): `positions` (n, 3)
    float32 RAS mm, outward unit `normals` (n, 3) float32, `triangles` (m, 3) uint32 (decoded
    with `wire.decode_mesh`), the enclosed `volume_ml`, and the server's `report`."""

    positions: F32
    normals: F32 | None
    triangles: wire.U32
    volume_ml: float
    report: PointCloudReport

    @classmethod
    def from_pb(cls, m: planning_service_pb2.ReconstructPointsResponse) -> PointCloudSurface:
        mesh = wire.decode_mesh(m.mesh)
        if mesh["vertex_count"] != m.vertex_count or mesh["triangle_count"] != m.triangle_count:
            raise wire.WireError(
                f"the mesh holds {mesh['vertex_count']} vertices and {mesh['triangle_count']} "
                f"triangles, the answer says {m.vertex_count} and {m.triangle_count}"
            )
        return cls(
            mesh["positions"], mesh["normals"], mesh["triangles"], m.volume_ml,
            PointCloudReport.from_pb(m.report),
        )


# --- resections ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Target:
    """Which tumours a resection keeps its margin from and removes: tumour `labels` (empty: all)
    and `points` picking single components (empty: every component of the labels)."""

    labels: tuple[int, ...] = ()
    points: tuple[tuple[float, float, float], ...] = ()

    def to_pb(self) -> resection_pb2.Target:
        return resection_pb2.Target(labels=list(self.labels), points=[vec3(p) for p in self.points])

    @classmethod
    def from_pb(cls, m: resection_pb2.Target) -> Target:
        return cls(tuple(m.labels), tuple((p.x, p.y, p.z) for p in m.points))


def trace_pb(points: Any) -> resection_pb2.Trace:
    """A `Trace` from an (n, 3) array-like of RAS mm points."""
    a = np.asarray(points, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"a trace is an (n, 3) array of points, got shape {a.shape}")
    return resection_pb2.Trace(points=[vec3(p) for p in a])


def _points(m: Any) -> F64:
    return np.array([(p.x, p.y, p.z) for p in m.points], dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True)
class Deformation:
    """A local deformation of a CP resection: the grid vertex nearest `point` (projected onto
    the plane) moves by `offset_mm` along the plane normal, the vertices within `radius_mm` by
    ``offset·½(1 + cos(π·d/radius))``."""

    point: tuple[float, float, float]
    offset_mm: float
    radius_mm: float

    def to_pb(self) -> resection_pb2.Deformation:
        return resection_pb2.Deformation(
            point=vec3(self.point), offset_mm=float(self.offset_mm), radius_mm=float(self.radius_mm)
        )

    @classmethod
    def from_pb(cls, m: resection_pb2.Deformation) -> Deformation:
        return cls(_xyz(m.point), m.offset_mm, m.radius_mm)


@dataclass(frozen=True, eq=False)
class Resection:
    """A virtual resection of one `kind`. Bézier: `control_points` has shape (m, n, 3): entry
    [i, j] is P_ij (i along u); ``control_points.reshape(-1, 3)`` is the row-major order of the
    plan file and of the wire (index i·n + j). DS and CP: `control_points` is empty (shape
    (0, 0, 3)) and `traces` holds the drawn polylines, each an (n, 3) array; CP also has its
    `deformations`, applied in order."""

    name: str
    control_points: F64
    margin_mm: float
    band_mm: float
    target: Target
    resolution: tuple[int, int]
    kind: ResectionKind = ResectionKind.BEZIER
    traces: tuple[F64, ...] = ()
    deformations: tuple[Deformation, ...] = ()

    @property
    def grid(self) -> tuple[int, int]:
        """(m, n): control points along u and v ((0, 0) for DS and CP)."""
        return self.control_points.shape[0], self.control_points.shape[1]

    def to_pb(self) -> resection_pb2.Resection:
        m, n = self.grid
        return resection_pb2.Resection(
            name=self.name,
            grid_m=m,
            grid_n=n,
            control_points=[vec3(p) for p in self.control_points.reshape(-1, 3)],
            margin_mm=self.margin_mm,
            band_mm=self.band_mm,
            target=self.target.to_pb(),
            ru=self.resolution[0],
            rv=self.resolution[1],
            kind=self.kind.to_pb(),
            traces=[trace_pb(t) for t in self.traces],
            deformations=[d.to_pb() for d in self.deformations],
        )

    @classmethod
    def from_pb(cls, m: resection_pb2.Resection) -> Resection:
        cps = np.array([(p.x, p.y, p.z) for p in m.control_points], dtype=np.float64)
        return cls(
            name=m.name,
            control_points=cps.reshape(m.grid_m, m.grid_n, 3),
            margin_mm=m.margin_mm,
            band_mm=m.band_mm,
            target=Target.from_pb(m.target),
            resolution=(m.ru, m.rv),
            kind=ResectionKind.from_pb(m.kind),
            traces=tuple(_points(t) for t in m.traces),
            deformations=tuple(Deformation.from_pb(d) for d in m.deformations),
        )


@dataclass(frozen=True)
class Verdict:
    """The global margin verdict of one resection: the smallest distance of its surface inside
    the liver to a target tumour (None when no part is inside), where (`point`, surface
    parameters `uv`), whether it violates the margin, and the violating / warning / inside
    areas. `min_margin_mm` is the exact distance to the tumours' segmented voxels taken as cubes
    (never more than to any tumour voxel centre); `margin_uncertainty_mm` is how much farther the
    nearest tumour voxel centre may lie (half a voxel along the minimum's direction)."""

    min_margin_mm: float | None
    point: tuple[float, float, float] | None
    uv: tuple[float, float] | None
    violation: bool
    violating_area_mm2: float
    warning_area_mm2: float
    inside_area_mm2: float
    margin_uncertainty_mm: float | None = None

    @classmethod
    def from_pb(cls, m: resection_pb2.Verdict) -> Verdict:
        has = m.HasField("min_margin_mm")
        return cls(
            min_margin_mm=m.min_margin_mm if has else None,
            point=_xyz(m.point) if has and m.HasField("point") else None,
            uv=(m.u, m.v) if m.HasField("u") and m.HasField("v") else None,
            violation=m.violation,
            violating_area_mm2=m.violating_area_mm2,
            warning_area_mm2=m.warning_area_mm2,
            inside_area_mm2=m.inside_area_mm2,
            margin_uncertainty_mm=(
                m.margin_uncertainty_mm if m.HasField("margin_uncertainty_mm") else None
            ),
        )


@dataclass(frozen=True)
class ResectionStatus:
    """A resection with its verdict, after an edit."""

    resection: Resection
    verdict: Verdict


@dataclass(frozen=True)
class EditResult:
    """The outcome of an edit: the plan version now, the resections it added or changed (with
    their verdicts) and the names it removed."""

    plan_version: int
    resections: tuple[ResectionStatus, ...]
    removed: tuple[str, ...]

    @classmethod
    def from_pb(cls, m: planning_service_pb2.EditResponse) -> EditResult:
        res = tuple(
            ResectionStatus(Resection.from_pb(r.resection), Verdict.from_pb(r.verdict)) for r in m.resections
        )
        return cls(m.plan_version, res, tuple(m.removed))

    def __getitem__(self, name: str) -> ResectionStatus:
        """The status of the resection `name` (KeyError if the edit did not touch it)."""
        for r in self.resections:
            if r.resection.name == name:
                return r
        raise KeyError(name)


# --- volumes, slices ---------------------------------------------------------------------------


def _opt(m: Any, name: str) -> Any:
    return getattr(m, name) if m.HasField(name) else None


@dataclass(frozen=True)
class ResectionMetrics:
    """A resection's plan quality metrics (thesis Sec. 7.4, Table 7.2), each None when absent:
    the minimum tumour distance inside the liver minus the margin (mm; negative falls short),
    the volume deviation against a reference plan (%; a server session has none, so always
    None here) and the median |mean curvature| over the surface inside the liver (mm⁻¹)."""

    margin_deviation_mm: float | None = None
    volume_deviation_pct: float | None = None
    median_abs_mean_curvature_per_mm: float | None = None

    @classmethod
    def from_pb(cls, m: volumes_pb2.ResectionMetrics) -> ResectionMetrics:
        return cls(*(_opt(m, f) for f in cls.__dataclass_fields__))


@dataclass(frozen=True)
class ResectionVolume:
    """One resection's share of the liver; volumes are None unless the cut is complete.
    `metrics` are its Sec. 7.4 metrics (None from a server that sends none)."""

    name: str
    resected_ml: float | None
    resected_pct: float | None
    complete_cut: bool
    incomplete_reason: str
    incomplete_point: tuple[float, float, float] | None
    metrics: ResectionMetrics | None = None


@dataclass(frozen=True)
class CutVessel:
    """A vessel a resection cuts: `system` ``"portal"`` or ``"hepatic"``, its branch (edge id
    of the centreline tree) and generation, the radius and RAS point of the crossing, and its
    (u, v) on the resection's surface (the resectogram's axes)."""

    system: str
    resection: str
    branch: int
    generation: int
    radius_mm: float
    point: tuple[float, float, float]
    uv: tuple[float, float]
    downstream_of_another_cut: bool

    @classmethod
    def from_pb(cls, m: volumes_pb2.CutVessel) -> CutVessel:
        system = {volumes_pb2.VESSEL_SYSTEM_HEPATIC: "hepatic"}.get(m.system, "portal")
        return cls(
            system,
            m.resection,
            m.branch,
            m.generation,
            m.radius_mm,
            _xyz(m.point),
            (m.u, m.v),
            m.downstream_of_another_cut,
        )


@dataclass(frozen=True)
class Risk:
    """What the plan puts at risk: the remnant without portal supply (devascularised) or
    hepatic drainage (congested), the functional remnant that keeps both (ml and % of the
    functional liver) and the cut vessels, largest first."""

    devascularised_ml: float
    congested_ml: float
    at_risk_ml: float
    functional_remnant_ml: float
    functional_remnant_pct: float
    has_portal: bool
    has_hepatic: bool
    cut_vessels: tuple[CutVessel, ...]

    @classmethod
    def from_pb(cls, m: volumes_pb2.RiskReport) -> Risk:
        return cls(
            m.devascularised_ml,
            m.congested_ml,
            m.at_risk_ml,
            m.functional_remnant_ml,
            m.functional_remnant_pct,
            m.has_portal,
            m.has_hepatic,
            tuple(CutVessel.from_pb(c) for c in m.cut_vessels),
        )


@dataclass(frozen=True)
class Volumes:
    """Resected and remnant volumes of the functional liver (every role but tumour) for
    `plan_version`; remnant and resected values are None when some cut is incomplete. `risk`
    is the vascular risk analysis when the label map has portal or hepatic vessels and every
    cut is complete (then `flr_warning` is based on the functional remnant);
    `risk_unavailable` says why there is none although the roles name vessels."""

    plan_version: int
    total_ml: float
    remnant_ml: float | None
    remnant_pct: float | None
    resected_ml: float | None
    flr_threshold_pct: float
    flr_warning: bool | None
    complete: bool
    resections: tuple[ResectionVolume, ...] = field(default=())
    risk: Risk | None = None
    risk_unavailable: str = ""

    @classmethod
    def from_pb(cls, m: volumes_pb2.VolumeReport, plan_version: int) -> Volumes:
        res = tuple(
            ResectionVolume(
                name=r.name,
                resected_ml=_opt(r, "resected_ml"),
                resected_pct=_opt(r, "resected_pct"),
                complete_cut=r.complete_cut,
                incomplete_reason=r.incomplete_reason,
                incomplete_point=_xyz(r.incomplete_point) if r.HasField("incomplete_point") else None,
                metrics=ResectionMetrics.from_pb(r.metrics) if r.HasField("metrics") else None,
            )
            for r in m.resections
        )
        return cls(
            plan_version=plan_version,
            total_ml=m.total_ml,
            remnant_ml=_opt(m, "remnant_ml"),
            remnant_pct=_opt(m, "remnant_pct"),
            resected_ml=_opt(m, "resected_ml"),
            flr_threshold_pct=m.flr_threshold_pct,
            flr_warning=_opt(m, "flr_warning"),
            complete=m.complete,
            resections=res,
            risk=Risk.from_pb(m.risk) if m.HasField("risk") else None,
            risk_unavailable=m.risk_unavailable,
        )


@dataclass(frozen=True, eq=False)
class Polyline:
    """One connected piece of a contour: points (n, 3) float32 RAS mm, closed or open."""

    points: F32
    closed: bool

    @classmethod
    def from_pb(cls, m: surface_pb2.Polyline) -> Polyline:
        pts = np.frombuffer(m.points, dtype="<f4").astype(np.float32).reshape(-1, 3)
        return cls(pts, m.closed)


@dataclass(frozen=True)
class Slices:
    """Contours of a surface on the axial, coronal and sagittal planes asked for (empty when a
    plane was not asked for or does not cut the surface)."""

    axial: tuple[Polyline, ...]
    coronal: tuple[Polyline, ...]
    sagittal: tuple[Polyline, ...]

    @classmethod
    def from_pb(cls, m: planning_service_pb2.GetSlicesResponse) -> Slices:
        return cls(
            *(tuple(Polyline.from_pb(p) for p in getattr(m, k)) for k in ("axial", "coronal", "sagittal"))
        )


@dataclass(frozen=True, eq=False)
class Resectogram:
    """A resection unrolled to its (u, v) square: `classes` (height, width) uint8 margin
    classes (0 outside the liver, 1 safe, 2 warning, 3 violation; pixel (r, c) at
    u = (c + ½)/width, v = (r + ½)/height), `territories` (height, width) portal territory ids
    (0 none), the cut vessels and the worst point's (u, v)."""

    plan_version: int
    resection: str
    classes: npt.NDArray[np.uint8]
    territories: npt.NDArray[np.uint32]
    cut_vessels: tuple[CutVessel, ...]
    worst_uv: tuple[float, float] | None
    min_margin_mm: float | None
    margin_mm: float
    band_mm: float

    @classmethod
    def from_pb(cls, m: planning_service_pb2.GetResectogramResponse) -> Resectogram:
        shape = (m.height, m.width)
        classes = np.frombuffer(m.classes, dtype=np.uint8).reshape(shape)
        terr = np.asarray(m.territories, dtype=np.uint32)
        territories = terr.reshape(shape) if terr.size else np.zeros(shape, np.uint32)
        worst = (m.worst_u, m.worst_v) if m.HasField("worst_u") and m.HasField("worst_v") else None
        return cls(
            int(m.plan_version),
            m.resection,
            classes,
            territories,
            tuple(CutVessel.from_pb(c) for c in m.cut_vessels),
            worst,
            _opt(m, "min_margin_mm"),
            m.margin_mm,
            m.band_mm,
        )


class RiskClass(enum.IntEnum):
    """Per-voxel class of a `RiskMap`."""

    NONE = 0
    FUNCTIONAL = 1
    RESECTED = 2
    DEVASCULARISED = 3
    CONGESTED = 4
    BOTH = 5


@dataclass(frozen=True, eq=False)
class RiskMap:
    """The plan's risk per voxel on the functional liver's bounding box: `classes` and
    `territories` are (k, j, i) arrays (x fastest in memory) of `RiskClass` codes and portal
    territory ids (0 none); `ijk_to_ras` (4×4) places voxel centres in RAS mm."""

    plan_version: int
    classes: npt.NDArray[np.uint8]
    territories: npt.NDArray[np.uint16]
    ijk_to_ras: F64
    risk: Risk

    @classmethod
    def from_pb(cls, m: planning_service_pb2.GetRiskMapResponse) -> RiskMap:
        try:
            import zstandard
        except ImportError:  # the `zstd` extra
            raise RuntimeError("a risk map needs the 'zstandard' package (the zstd extra)") from None
        i, j, k = (int(d) for d in m.dims)
        n = i * j * k
        unpack = zstandard.ZstdDecompressor().decompress
        classes = np.frombuffer(unpack(m.classes_zstd, max_output_size=n), np.uint8)
        terr = np.frombuffer(unpack(m.territories_zstd, max_output_size=2 * n), "<u2")
        if classes.size != n or terr.size != n:
            raise ValueError(f"risk map of {i}×{j}×{k} voxels holds {classes.size} classes, {terr.size} territories")
        ijk = np.eye(4)
        ijk[:3, :3] = np.asarray(m.direction, dtype=np.float64).reshape(3, 3) * np.asarray(m.spacing)
        ijk[:3, 3] = m.origin
        return cls(
            int(m.plan_version),
            classes.reshape(k, j, i),
            terr.astype(np.uint16).reshape(k, j, i),
            ijk,
            Risk.from_pb(m.risk),
        )

    def volume_ml(self, *codes: RiskClass) -> float:
        """Volume of the voxels of these classes, ml."""
        voxel = abs(float(np.linalg.det(self.ijk_to_ras[:3, :3]))) / 1000.0
        return float(np.isin(self.classes, [int(c) for c in codes]).sum()) * voxel


@dataclass(frozen=True, eq=False)
class LabelSlice:
    """One plane of the label map resampled by nearest neighbour: `labels` (height, width)
    uint16, the centre of pixel (r, c) at ``origin + c·pixel_mm·column_axis +
    r·pixel_mm·row_axis`` (RAS mm); `min_position_mm`..`max_position_mm` is the label map's
    extent along the axis."""

    labels: npt.NDArray[np.uint16]
    pixel_mm: float
    origin: tuple[float, float, float]
    column_axis: tuple[float, float, float]
    row_axis: tuple[float, float, float]
    min_position_mm: float
    max_position_mm: float

    @classmethod
    def from_pb(cls, m: planning_service_pb2.GetLabelSliceResponse) -> LabelSlice:
        labels = np.frombuffer(m.labels, dtype="<u2").astype(np.uint16).reshape(m.height, m.width)
        return cls(
            labels,
            m.pixel_mm,
            _xyz(m.origin),
            _xyz(m.column_axis),
            _xyz(m.row_axis),
            m.min_position_mm,
            m.max_position_mm,
        )

    def point(self, row: float, column: float) -> F64:
        """RAS of the centre of pixel (row, column), mm."""
        o, c, r = (np.asarray(v) for v in (self.origin, self.column_axis, self.row_axis))
        return o + (column * c + row * r) * self.pixel_mm
