"""The Bézier control grid of a resection ↔ a markups node.

The server's order (proto `Resection.control_points`, `resecta-plan/1` files, `bezier eval`):
an m×n grid is stored row-major, entry `i·n + j` is P_ij, `i` along u (the grid's first index,
0..m) and `j` along v. The markups node holds the same m·n control points in the same order,
labelled `P<i>,<j>`; the grid size is kept in node attributes. A control-net model (the lines
between neighbouring control points) can be drawn beside it.
"""

from __future__ import annotations

import numpy as np
import vtk
from vtk.util import numpy_support

GRID_M_ATTRIBUTE = "Resecta.GridM"
GRID_N_ATTRIBUTE = "Resecta.GridN"
RESECTION_ATTRIBUTE = "Resecta.Resection"
SESSION_ATTRIBUTE = "Resecta.SessionId"


def index(i: int, j: int, n: int) -> int:
    """Markups / wire index of P_ij in an m×n grid."""
    return i * n + j


def ij(k: int, n: int) -> tuple[int, int]:
    """(i, j) of markups / wire index k in an m×n grid."""
    return divmod(k, n)


def label(i: int, j: int) -> str:
    return f"P{i},{j}"


def find_grid_node(scene, resection: str, session_id: str | None = None):
    """The control-grid markups node of `resection` (of `session_id` when given), or None."""
    cls = "vtkMRMLMarkupsFiducialNode"
    for i in range(scene.GetNumberOfNodesByClass(cls)):
        node = scene.GetNthNodeByClass(i, cls)
        if node.GetAttribute(RESECTION_ATTRIBUTE) != resection:
            continue
        if session_id is not None and node.GetAttribute(SESSION_ATTRIBUTE) not in (None, session_id):
            continue
        return node
    return None


def make_grid_node(scene, resection: str, points: np.ndarray, m: int, n: int, name: str = "",
                   session_id: str | None = None):
    """A markups fiducial node with the m·n control points of `resection` (row-major)."""
    node = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode",
                                   name or f"Resecta {resection} control points")
    node.SetAttribute(RESECTION_ATTRIBUTE, resection)
    if session_id:
        node.SetAttribute(SESSION_ATTRIBUTE, session_id)
    node.CreateDefaultDisplayNodes()
    display = node.GetDisplayNode()
    display.SetSelectedColor(0.1, 0.45, 0.95)
    display.SetColor(0.1, 0.45, 0.95)
    display.SetGlyphScale(2.0)
    display.SetPointLabelsVisibility(False)
    set_grid(node, points, m, n)
    return node


def set_grid(node, points: np.ndarray, m: int, n: int) -> None:
    """Makes the node hold exactly these m·n points (positions and labels), in place."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) != m * n:
        raise ValueError(f"{len(points)} control points for a {m}×{n} grid")
    node.SetAttribute(GRID_M_ATTRIBUTE, str(m))
    node.SetAttribute(GRID_N_ATTRIBUTE, str(n))
    wasModifying = node.StartModify()
    try:
        while node.GetNumberOfControlPoints() > m * n:
            node.RemoveNthControlPoint(node.GetNumberOfControlPoints() - 1)
        for k, p in enumerate(points):
            i, j = ij(k, n)
            if k < node.GetNumberOfControlPoints():
                node.SetNthControlPointPosition(k, float(p[0]), float(p[1]), float(p[2]))
            else:
                node.AddControlPoint(vtk.vtkVector3d(float(p[0]), float(p[1]), float(p[2])),
                                     label(i, j))
            node.SetNthControlPointLabel(k, label(i, j))
    finally:
        node.EndModify(wasModifying)


def grid_shape(node) -> tuple[int, int]:
    m, n = node.GetAttribute(GRID_M_ATTRIBUTE), node.GetAttribute(GRID_N_ATTRIBUTE)
    if m is None or n is None:
        raise ValueError(f"markups node {node.GetName()!r} is not a Resecta control grid")
    return int(m), int(n)


def grid_points(node) -> np.ndarray:
    """The node's control points as an (m·n, 3) array in wire order."""
    m, n = grid_shape(node)
    count = node.GetNumberOfControlPoints()
    if count != m * n:
        raise ValueError(f"control grid {node.GetName()!r} has {count} points, expected {m}×{n}")
    out = np.empty((count, 3))
    p = [0.0, 0.0, 0.0]
    for k in range(count):
        node.GetNthControlPointPosition(k, p)
        out[k] = p
    return out


def control_point(node, k: int) -> np.ndarray:
    p = [0.0, 0.0, 0.0]
    node.GetNthControlPointPosition(k, p)
    return np.array(p)


def net_polydata(points: np.ndarray, m: int, n: int, poly: vtk.vtkPolyData | None = None):
    """The control net: lines between P_ij and P_(i+1)j, P_i(j+1) (updated in place if given)."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if poly is not None and poly.GetNumberOfPoints() == len(points):
        view = numpy_support.vtk_to_numpy(poly.GetPoints().GetData())
        view[...] = points
        poly.GetPoints().GetData().Modified()
        poly.GetPoints().Modified()
        poly.Modified()
        return poly
    poly = vtk.vtkPolyData()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_support.numpy_to_vtk(points, deep=True, array_type=vtk.VTK_FLOAT))
    poly.SetPoints(pts)
    lines = vtk.vtkCellArray()
    for i in range(m):
        for j in range(n):
            if i + 1 < m:
                lines.InsertNextCell(2, [index(i, j, n), index(i + 1, j, n)])
            if j + 1 < n:
                lines.InsertNextCell(2, [index(i, j, n), index(i, j + 1, n)])
    poly.SetLines(lines)
    return poly


def ring_of(k: int, m: int, n: int) -> int:
    """Ring of point k: its distance in grid steps from the border (0 = border)."""
    i, j = ij(k, n)
    return min(i, j, m - 1 - i, n - 1 - j)
