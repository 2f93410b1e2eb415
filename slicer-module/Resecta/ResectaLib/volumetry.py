"""The volumetry table as plain rows (the Widget draws them; tests compare them).

Rows: total functional liver, then each resection's resected volume, then all resected together
and the future liver remnant (FLR), each with ml and % of the total; with the vascular risk
analysis, the functional remnant (the remnant that keeps portal supply and hepatic drainage) and
the devascularised and congested volumes. An FLR warning when the remnant (the functional one when
there is risk) falls below the threshold, the reason when a cut does not divide the liver (then
the remnant is unknown, shown as "—") or when there is no risk analysis, and the cut vessels.
"""

from __future__ import annotations

import dataclasses

DASH = "—"


@dataclasses.dataclass(frozen=True)
class Row:
    label: str
    ml: float | None
    pct: float | None
    warning: bool = False

    def cells(self) -> tuple[str, str, str]:
        ml = DASH if self.ml is None else f"{self.ml:.1f}"
        pct = DASH if self.pct is None else f"{self.pct:.1f}"
        return self.label, ml, pct


@dataclasses.dataclass(frozen=True)
class CutVesselRow:
    system: str
    radius_mm: float
    resection: str

    def cells(self) -> tuple[str, str, str]:
        return self.system, f"{self.radius_mm:.1f} mm", self.resection


@dataclasses.dataclass(frozen=True)
class VolumeTable:
    rows: tuple[Row, ...]
    plan_version: int
    flr_warning: bool
    messages: tuple[str, ...]
    cut_vessels: tuple[CutVesselRow, ...] = ()

    def row(self, label: str) -> Row:
        for r in self.rows:
            if r.label == label:
                return r
        raise KeyError(label)


EMPTY = VolumeTable((), 0, False, ("No volumes yet",))


def table(volumes) -> VolumeTable:
    """From the client's `Volumes` (or anything with the same attributes)."""
    total = float(volumes.total_ml)

    def pct(ml):
        return None if ml is None or total <= 0 else 100.0 * ml / total

    rows = [Row("Total liver", total, 100.0 if total > 0 else None)]
    messages = []
    for r in volumes.resections:
        rows.append(Row(f"Resected by {r.name}", r.resected_ml,
                        r.resected_pct if r.resected_pct is not None else pct(r.resected_ml)))
        if not r.complete_cut:
            messages.append(f"{r.name}: incomplete cut"
                            + (f" ({r.incomplete_reason})" if r.incomplete_reason else ""))
    if len(volumes.resections) != 1:
        rows.append(Row("Resected (all)", volumes.resected_ml, pct(volumes.resected_ml)))
    flr = bool(volumes.flr_warning)
    risk = getattr(volumes, "risk", None)
    remnant_pct = volumes.remnant_pct if volumes.remnant_pct is not None else pct(volumes.remnant_ml)
    rows.append(Row("Remnant (FLR)", volumes.remnant_ml, remnant_pct, warning=flr and risk is None))
    vessels = ()
    if risk is not None:
        rows += [Row("Functional remnant", risk.functional_remnant_ml,
                     risk.functional_remnant_pct, warning=flr),
                 Row("Devascularised", risk.devascularised_ml, pct(risk.devascularised_ml)),
                 Row("Congested", risk.congested_ml, pct(risk.congested_ml))]
        vessels = tuple(CutVesselRow(v.system, v.radius_mm, v.resection)
                        for v in risk.cut_vessels)
    if flr and risk is not None:
        messages.append(f"FLR warning: functional remnant {risk.functional_remnant_pct:.1f} % < "
                        f"{volumes.flr_threshold_pct:g} % of the liver")
    elif flr:
        messages.append(f"FLR warning: remnant {remnant_pct:.1f} % < "
                        f"{volumes.flr_threshold_pct:g} % of the liver")
    if getattr(volumes, "risk_unavailable", ""):
        messages.append(f"No risk analysis: {volumes.risk_unavailable}")
    return VolumeTable(tuple(rows), int(getattr(volumes, "plan_version", 0)), flr,
                       tuple(messages), vessels)


# --- plan metrics (thesis Sec. 7.4) ----------------------------------------------------------

KIND_LABELS = {"bezier": "Bézier", "ds": "DS", "cp": "CP"}


@dataclasses.dataclass(frozen=True)
class MetricRow:
    """One resection's kind and metrics: margin deviation (mm; negative falls short of the
    margin) and median |mean curvature| (mm⁻¹); None when the server has none."""

    name: str
    kind: str
    margin_deviation_mm: float | None
    median_abs_curvature_per_mm: float | None

    def cells(self) -> tuple[str, str, str, str]:
        dev = DASH if self.margin_deviation_mm is None else f"{self.margin_deviation_mm:+.1f} mm"
        h = self.median_abs_curvature_per_mm
        return self.name, KIND_LABELS.get(self.kind, self.kind), dev, \
            DASH if h is None else f"{h:.4f} mm⁻¹"


def metric_rows(volumes, kinds: dict[str, str]) -> tuple[MetricRow, ...]:
    """From the client's `Volumes` (each `ResectionVolume.metrics`) and resection name → kind
    ("bezier", "ds", "cp")."""
    rows = []
    for r in volumes.resections if volumes is not None else ():
        m = getattr(r, "metrics", None)
        rows.append(MetricRow(
            r.name, str(kinds.get(r.name, "bezier")),
            None if m is None else m.margin_deviation_mm,
            None if m is None else m.median_abs_mean_curvature_per_mm))
    return tuple(rows)
