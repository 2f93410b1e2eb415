"""`vtkPolyData` of a watched surface, when the `vtk` package is importable (the `vtk` extra; in
3D Slicer it always is). Point data: normals (``Normals``, set as the normals), and for
resections ``margin_mm`` (float32, the active scalars) and ``margin_class`` (uint8 `MarginClass`
codes), the names of the server's VTP export. This is the one numpy → VTK builder: the Slicer
module's model nodes are made and updated with it."""

from __future__ import annotations

from typing import Any

import numpy as np

from .scene import SurfaceState

#: Point-data array names (as the server's VTP export writes them).
NORMALS = "Normals"
MARGIN_ARRAY = "margin_mm"
CLASS_ARRAY = "margin_class"


def vtk_available() -> bool:
    """Whether `vtk` can be imported."""
    try:
        import vtkmodules.vtkCommonDataModel  # noqa: F401
    except ImportError:
        return False
    return True


def _point_arrays(surface: SurfaceState) -> list[tuple[str, np.ndarray | None]]:
    return [
        (NORMALS, None if surface.normals is None else np.asarray(surface.normals, np.float32)),
        (MARGIN_ARRAY, None if surface.margins is None else np.asarray(surface.margins, np.float32)),
        (CLASS_ARRAY, None if surface.classes is None else np.asarray(surface.classes, np.uint8)),
    ]


def _update_in_place(surface: SurfaceState, pd: Any) -> bool:
    """Writes `surface`'s rows into `pd`'s existing arrays; False when a shape differs (the
    polydata must be rebuilt)."""
    from vtkmodules.util import numpy_support as ns

    points = pd.GetPoints()
    if points is None or points.GetNumberOfPoints() != len(surface.positions):
        return False
    if pd.GetNumberOfPolys() != len(surface.triangles):
        return False
    data = pd.GetPointData()
    arrays = [(points.GetData(), np.asarray(surface.positions, np.float32))]
    for name, values in _point_arrays(surface):
        arr = data.GetArray(name)
        if (arr is None) != (values is None):
            return False
        if arr is not None:
            arrays.append((arr, values))
    views = [(arr, ns.vtk_to_numpy(arr)) for arr, _ in arrays]
    if any(view.dtype != values.dtype or view.size != values.size
           for (_, view), (_, values) in zip(views, arrays)):
        return False
    for (arr, view), (_, values) in zip(views, arrays):
        view[...] = values.reshape(view.shape)
        arr.Modified()
    points.Modified()
    pd.Modified()
    return True


def to_vtk_polydata(surface: SurfaceState, polydata: Any = None, rebuild: bool = True) -> Any:
    """A `vtkPolyData` holding copies of `surface`'s arrays, or `polydata` updated to them (for
    a live view, so that pipelines downstream re-render). With ``rebuild=False`` (the surface
    only had rows updated: a Watch delta that is not in `SceneUpdate.rebuilt`) the existing
    point and scalar arrays of `polydata` are overwritten in place, the same VTK objects kept;
    when their shapes do not fit, it is rebuilt anyway. Raises ImportError without `vtk`."""
    from vtkmodules.util import numpy_support as ns
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    if polydata is not None and not rebuild and _update_in_place(surface, polydata):
        return polydata
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
    for name, values in _point_arrays(surface):
        data.RemoveArray(name)
        if values is None:
            continue
        arr = ns.numpy_to_vtk(np.ascontiguousarray(values), deep=True)
        arr.SetName(name)
        if name == NORMALS:
            data.SetNormals(arr)
        elif name == MARGIN_ARRAY:
            data.SetScalars(arr)
        else:
            data.AddArray(arr)
    pd.Modified()
    return pd
