"""Edit commands of a resection plan: each is one server call, run on the Logic's worker in the
order made (the server applies a session's edits in that order), its result handed back on the
main thread.

Dragging a control point sends `set_control_point` edits through an `EditCoalescer` (one edit
in flight; while it is, only the latest position per point waits), with `base_version = 0` (a
dragged point's position is absolute: the last one wins). `busy(name)` tells the grid sync
whether edits of a resection are on their way, so that watch echoes do not pull a dragged point
back.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from .coalesce import EditCoalescer

AXES = {"R": (1.0, 0.0, 0.0), "A": (0.0, 1.0, 0.0), "S": (0.0, 0.0, 1.0)}
GROUPS = ("inner", "outer", "all")


def grid_normal(resection) -> np.ndarray:
    """Unit normal of a resection's control grid (u × v of its mean edges)."""
    cp = np.asarray(resection.control_points, dtype=float)
    du = cp[-1, :, :].mean(axis=0) - cp[0, :, :].mean(axis=0)
    dv = cp[:, -1, :].mean(axis=0) - cp[:, 0, :].mean(axis=0)
    n = np.cross(du, dv)
    length = float(np.linalg.norm(n))
    if length == 0.0:
        raise ValueError(f"the control grid of {resection.name!r} is degenerate")
    return n / length


class EditCommands:
    """`call(fn, on_done, user_done, on_error)` runs `fn()` on the worker; `session()` is the
    client session (ValueError without one); `resection(name)` the parameters last seen;
    `on_result(EditResult)` folds an acknowledged edit into the Logic's state; `on_idle()` runs
    when the drag edits are all answered."""

    def __init__(self, call: Callable, session: Callable[[], Any],
                 resection: Callable[[str], Any], on_result: Callable[[Any], None],
                 on_idle: Callable[[], None]):
        self._call = call
        self._session = session
        self._resection = resection
        self._on_result = on_result
        self._on_idle = on_idle
        self.coalescer = EditCoalescer(self._send_control_point)
        #: edits the server acknowledged, and the last answer (tests, status line)
        self.acknowledged = 0
        self.last = None
        #: called on the worker with each answer in the order the server gave them (the trace
        #: sync's view of the traces), with None after a plan import
        self.on_answer: Callable[[Any], None] | None = None

    def _edit(self, work: Callable[[Any], Any], on_done: Callable | None = None,
              on_error: Callable | None = None) -> None:
        sess = self._session()

        def run():
            result = work(sess)
            if self.on_answer is not None and result is not None:
                self.on_answer(result)
            return result

        self._call(run, self._done, on_done, on_error)

    def _done(self, result) -> None:
        if result is None:
            return
        self.acknowledged += 1
        self.last = result
        self._on_result(result)

    def busy(self, name: str) -> bool:
        """Whether drag edits of resection `name` are in flight or waiting."""
        c = self.coalescer
        in_flight = c.in_flight
        return (in_flight is not None and in_flight[0] == name) or any(
            key[0] == name for key in c.pending)

    # --- drags ------------------------------------------------------------------------------

    def drag(self, name: str, i: int, j: int, point) -> None:
        """Control point P_ij of `name` was dragged to `point`: sent, coalesced."""
        self.coalescer.push((name, i, j), tuple(float(x) for x in point))

    def _send_control_point(self, key, point) -> None:
        name, i, j = key
        try:
            sess = self._session()
        except ValueError:
            self._drag_answered()
            return
        self._call(lambda: sess.set_control_point(name, i, j, point, base_version=0),
                   self._done, lambda _r: self._drag_answered(),
                   lambda _exc: self._drag_answered())

    def _drag_answered(self) -> None:
        self.coalescer.done()
        if not self.coalescer.busy:
            self._on_idle()

    # --- commands ---------------------------------------------------------------------------

    def new_resection(self, name: str, end_point, target, margin_mm: float | None = None,
                      band_mm: float | None = None, grid=(4, 4),
                      on_done: Callable | None = None) -> None:
        """Adds resection `name` for `target` (a `resecta_client.Target`) from the end point
        (Algorithms 1–2), then sets its margin and band when given."""
        if not name:
            raise ValueError("the resection needs a name")
        end = tuple(float(x) for x in end_point)

        def work(sess):
            result = sess.init_from_end_point(name, end, target=target, grid=tuple(grid))
            if margin_mm is not None and abs(result[name].resection.margin_mm - margin_mm) > 1e-9:
                result = sess.set_margin(name, margin_mm)
            if band_mm is not None and abs(result[name].resection.band_mm - band_mm) > 1e-9:
                result = sess.set_band(name, band_mm)
            return result

        self._edit(work, on_done)

    def set_margin_and_band(self, name: str, margin_mm: float, band_mm: float,
                            on_done: Callable | None = None) -> None:
        """Sends only what differs from the values last seen (nothing when both are equal)."""
        current = self._resection(name)

        def work(sess):
            result = None
            if current is None or abs(current.margin_mm - margin_mm) > 1e-9:
                result = sess.set_margin(name, margin_mm)
            if current is None or abs(current.band_mm - band_mm) > 1e-9:
                result = sess.set_band(name, band_mm)
            return result

        self._edit(work, on_done)

    def move_group(self, name: str, group, delta, on_done: Callable | None = None) -> None:
        """Moves `group` ("inner", "outer", "all" or a ring number) of `name`'s grid by delta."""
        delta = tuple(float(x) for x in delta)
        if isinstance(group, int):
            self._edit(lambda s: s.move_group(name, delta, ring=group), on_done)
        elif group in GROUPS:
            self._edit(lambda s: s.move_group(name, delta, group=group), on_done)
        else:
            raise ValueError(f"unknown group {group!r} (one of {', '.join(GROUPS)} or a ring)")

    def translate(self, name: str, delta, on_done: Callable | None = None) -> None:
        delta = tuple(float(x) for x in delta)
        self._edit(lambda s: s.translate(name, delta), on_done)

    def rotate(self, name: str, axis, angle_deg: float, centre=None,
               on_done: Callable | None = None) -> None:
        """Rotates `name` about `axis` ("R", "A", "S", "normal" or a vector) through `centre`
        (default: the control points' centroid)."""
        if isinstance(axis, str):
            if axis == "normal":
                resection = self._resection(name)
                if resection is None:
                    raise ValueError(f"no resection {name!r}")
                axis = grid_normal(resection)
            elif axis in AXES:
                axis = AXES[axis]
            else:
                raise ValueError(f"unknown axis {axis!r} (R, A, S, normal or a vector)")
        axis = tuple(float(x) for x in axis)
        self._edit(lambda s: s.rotate(name, axis, float(angle_deg), centre=centre), on_done)

    def send(self, work: Callable[[Any], Any], on_done: Callable | None = None,
             on_error: Callable | None = None) -> None:
        """Runs `work(session)` (an edit returning an `EditResult`) in order with the others."""
        self._edit(work, on_done, on_error)

    def add_deformation(self, name: str, point, offset_mm: float, radius_mm: float,
                        on_done: Callable | None = None) -> None:
        """Deforms CP resection `name`: the grid vertex nearest `point` by `offset_mm` along
        the plane normal, cosine falloff to `radius_mm`."""
        point = tuple(float(x) for x in point)
        self._edit(lambda s: s.add_deformation(name, point, float(offset_mm), float(radius_mm)),
                   on_done)

    def undo_deformation(self, name: str, on_done: Callable | None = None) -> None:
        self._edit(lambda s: s.undo_deformation(name), on_done)

    def delete(self, name: str, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.delete_resection(name), on_done)

    def undo(self, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.undo(), on_done)

    def redo(self, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.redo(), on_done)

    def import_plan(self, plan_json: str, on_done: Callable | None = None) -> None:
        """Replaces the plan (one undoable step); `on_done(plan_version)`."""
        self.coalescer.clear()
        sess = self._session()

        def run():
            version = sess.import_plan(plan_json)
            if self.on_answer is not None:
                self.on_answer(None)
            return version

        self._call(run, None, on_done)
