"""The control grids of a session's resections ↔ markups nodes, kept in step both ways.

Server → scene: `sync(name, resection)` makes or updates the markups node of a resection from
its control points, unless the user is dragging one of its points or drag edits of it are on
their way (`busy(name)`; an echo would pull the point back under the mouse). Scene → server: a
point the user moves calls `on_drag(name, i, j, position)` (the Logic sends it); moves made by
`sync` itself are not reported. When the user lets go of a point and no edit of its grid is on
its way, `on_released()` lets the Logic bring the grids in line with the server.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import vtk

from . import controlgrid


class GridSync:
    def __init__(self, scene, session_id: str, on_drag: Callable[[str, int, int, np.ndarray], None],
                 busy: Callable[[str], bool], on_released: Callable[[], None]):
        self.scene = scene
        self.session_id = session_id
        self._on_drag = on_drag
        self._busy = busy
        self._on_released = on_released
        self.nodes: dict[str, object] = {}  # resection name → markups node
        self._observers: dict[str, list[tuple[object, int]]] = {}
        self._syncing = False
        self._interacting: set[str] = set()

    def __contains__(self, name: str) -> bool:
        return name in self.nodes

    def __getitem__(self, name: str):
        return self.nodes[name]

    def get(self, name: str, default=None):
        return self.nodes.get(name, default)

    def is_grid(self, node) -> bool:
        """Whether `node` is a control grid of this module (never an end point)."""
        return node is not None and node.GetAttribute(controlgrid.RESECTION_ATTRIBUTE) is not None

    def busy(self, name: str) -> bool:
        return name in self._interacting or self._busy(name)

    def sync(self, name: str, resection) -> None:
        """The markups of `name` hold the resection's control points (made when missing)."""
        cp = np.asarray(resection.control_points, dtype=float)
        m, n = cp.shape[0], cp.shape[1]
        points = cp.reshape(-1, 3)
        node = self.nodes.get(name)
        if node is None or self.scene.GetNodeByID(node.GetID()) is None:
            self._forget(name)
            node = controlgrid.find_grid_node(self.scene, name, self.session_id)
            if node is None:
                node = controlgrid.make_grid_node(self.scene, name, points, m, n,
                                                  session_id=self.session_id)
            self.nodes[name] = node
            self._observe(name, node)
        if self.busy(name):
            return
        if node.GetNumberOfControlPoints() == m * n and controlgrid.grid_shape(node) == (m, n) \
                and np.allclose(controlgrid.grid_points(node), points, atol=1e-6):
            return
        self._syncing = True
        try:
            controlgrid.set_grid(node, points, m, n)
        finally:
            self._syncing = False

    def remove(self, name: str) -> None:
        """Stops following `name` and removes its markups node from the scene."""
        node = self.nodes.get(name)
        self._forget(name)
        if node is not None and self.scene.GetNodeByID(node.GetID()) is not None:
            self.scene.RemoveNode(node)

    def close(self) -> None:
        """Stops following every grid (the nodes stay in the scene)."""
        for name in list(self.nodes):
            self._forget(name)

    @property
    def observer_count(self) -> int:
        return sum(len(tags) for tags in self._observers.values())

    def _forget(self, name: str) -> None:
        for obj, tag in self._observers.pop(name, []):
            obj.RemoveObserver(tag)
        self.nodes.pop(name, None)
        self._interacting.discard(name)

    def _observe(self, name: str, node) -> None:
        import slicer

        Markups = slicer.vtkMRMLMarkupsNode

        @vtk.calldata_type(vtk.VTK_INT)
        def moved(caller, event, index=None):
            if self._syncing or index is None or index < 0:
                return
            m, n = controlgrid.grid_shape(node)
            if index < m * n:
                i, j = controlgrid.ij(int(index), n)
                self._on_drag(name, i, j, controlgrid.control_point(node, int(index)))

        def started(caller, event):
            self._interacting.add(name)

        def ended(caller, event):
            self._interacting.discard(name)
            if not self._busy(name):
                self._on_released()

        self._observers[name] = [
            (node, node.AddObserver(Markups.PointModifiedEvent, moved)),
            (node, node.AddObserver(Markups.PointStartInteractionEvent, started)),
            (node, node.AddObserver(Markups.PointEndInteractionEvent, ended)),
        ]
