"""`vtkPolyData` of a watched surface, when the `vtk` package is importable (the `vtk` extra; in
3D Slicer it always is). Point data: normals (``Normals``, set as the normals), and for
resections ``margin_mm`` (float32, the active scalars) and ``margin_class`` (uint8 `MarginClass`
codes), the names of the server's VTP export."""

from __future__ import annotations

from typing import Any

import numpy as np

from .scene import SurfaceState


def vtk_available() -> bool:
    """Whether `vtk` can be imported."""
    try:
        import vtkmodules.vtkCommonDataModel  # noqa: F401
    except ImportError:
        return False
    return True


def to_vtk_polydata(surface: SurfaceState, polydata: Any = None) -> Any:
    """A `vtkPolyData` holding copies of `surface`'s arrays, or `polydata` updated to them (for
    a live view: after a delta the points and scalars are replaced and `Modified()` is called,
    so that pipelines downstream re-render). Raises ImportError without `vtk`."""
    from vtkmodules.util import numpy_support as ns
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    pd = polydata if polydata is not None else vtkPolyData()
    points = vtkPoints()
    points.SetData(ns.numpy_to_vtk(np.ascontiguousarray(surface.positions, np.float32), deep=True))
    pd.SetPoints(points)
    tri = np.ascontiguousarray(surface.triangles, np.int64)
    cells = vtkCellArray()
    offsets = np.arange(0, 3 * len(tri) + 1, 3, dtype=np.int64)
    cells.SetData(
        ns.numpy_to_vtkIdTypeArray(offsets, deep=True), ns.numpy_to_vtkIdTypeArray(tri.reshape(-1), deep=True)
    )
    pd.SetPolys(cells)
    data = pd.GetPointData()
    for name in ("Normals", "margin_mm", "margin_class"):
        data.RemoveArray(name)
    if surface.normals is not None:
        normals = ns.numpy_to_vtk(np.ascontiguousarray(surface.normals, np.float32), deep=True)
        normals.SetName("Normals")
        data.SetNormals(normals)
    if surface.classes is not None:
        classes = ns.numpy_to_vtk(np.ascontiguousarray(surface.classes, np.uint8), deep=True)
        classes.SetName("margin_class")
        data.AddArray(classes)
    if surface.margins is not None:
        margins = ns.numpy_to_vtk(np.ascontiguousarray(surface.margins, np.float32), deep=True)
        margins.SetName("margin_mm")
        data.SetScalars(margins)
    pd.Modified()
    return pd
