"""The global margin indicator: one line and one colour for the whole plan.

From each resection's verdict (minimum distance inside the liver to its target tumours, where,
and whether it is below the margin) the indicator shows the worst resection: a violation first,
then the smallest slack (minimum − margin). The minimum is the distance to the segmented tumour
voxels taken as cubes; the nearest voxel centre may lie up to the verdict's
`margin_uncertainty_mm` farther, shown as "(+u)". Green: every resection keeps its margin; red: some
resection violates it; grey: nothing to judge yet (no resection, or no surface inside the liver).
"""

from __future__ import annotations

import dataclasses

import numpy as np

GREEN = "#2e9e44"
RED = "#d7261e"
GREY = "#8a8a8a"


@dataclasses.dataclass(frozen=True)
class MarginIndicator:
    state: str  # "none", "ok" or "violation"
    text: str
    color: str
    resection: str | None = None
    min_margin_mm: float | None = None
    margin_mm: float | None = None
    point: tuple[float, float, float] | None = None
    uncertainty_mm: float | None = None

    @property
    def can_jump(self) -> bool:
        return self.point is not None


NONE = MarginIndicator("none", "No resection", GREY)


def indicator(resections: dict[str, tuple[float, object]]) -> MarginIndicator:
    """The indicator for `resections`: name → (margin_mm, verdict), the verdict with
    `min_margin_mm` (None when no surface is inside the liver), `point` and `violation`."""
    worst = None
    for name, (margin_mm, verdict) in sorted(resections.items()):
        d = getattr(verdict, "min_margin_mm", None)
        if d is None:
            continue
        violation = bool(getattr(verdict, "violation", d < margin_mm))
        key = (0 if violation else 1, d - margin_mm)
        if worst is None or key < worst[0]:
            worst = (key, name, margin_mm, d, violation, getattr(verdict, "point", None),
                     getattr(verdict, "margin_uncertainty_mm", None))
    if worst is None:
        if resections:
            return MarginIndicator("none", "No resection surface inside the liver", GREY)
        return NONE
    _, name, margin_mm, d, violation, point, u = worst
    p = None if point is None else tuple(float(x) for x in np.asarray(point).reshape(3))
    plus = "" if u is None else f" (+{u:.1f})"
    if violation:
        text = f"{name}: margin violated, {d:.1f}{plus} mm < {margin_mm:g} mm"
        return MarginIndicator("violation", text, RED, name, d, margin_mm, p, u)
    text = f"{name}: min. margin {d:.1f}{plus} mm ≥ {margin_mm:g} mm"
    return MarginIndicator("ok", text, GREEN, name, d, margin_mm, p, u)
