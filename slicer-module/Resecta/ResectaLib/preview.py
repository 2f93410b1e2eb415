"""The preview shown while the end point is placed: the liver's contour on the initial plane.

The server initialises a resection (thesis Algorithm 1) on the plane through the midpoint of the
target tumour's centroid c and the end point p_e, with normal p_e − c, and spans the control grid
over the parenchyma's contour on that plane. While the surgeon moves the end point we draw the
same contour locally (cutting the parenchyma model already in the scene), so the preview follows
the mouse without a server round trip; the grid itself comes from the server.
"""

from __future__ import annotations

import numpy as np
import vtk
from vtk.util import numpy_support


def mesh_centroid(poly: vtk.vtkPolyData) -> np.ndarray:
    """Volume centroid of a closed triangle mesh (signed tetrahedra from the origin)."""
    pts = numpy_support.vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64)
    tri = numpy_support.vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    total = vol.sum()
    if abs(total) < 1e-12:
        return pts.mean(axis=0)
    return ((a + b + c) / 4.0 * vol[:, None]).sum(axis=0) / total


def initial_plane(tumor_centroid, end_point) -> tuple[np.ndarray, np.ndarray]:
    """(point, unit normal) of Algorithm 1's plane; ValueError within 1 mm of the centroid."""
    c = np.asarray(tumor_centroid, dtype=float)
    e = np.asarray(end_point, dtype=float)
    d = e - c
    length = float(np.linalg.norm(d))
    if length < 1.0:
        raise ValueError("the end point must be at least 1 mm from the tumour's centroid")
    return (c + e) / 2.0, d / length


def contour(surface: vtk.vtkPolyData, point, normal, out: vtk.vtkPolyData | None = None):
    """The intersection polylines of `surface` with the plane (into `out` when given)."""
    plane = vtk.vtkPlane()
    plane.SetOrigin(*map(float, point))
    plane.SetNormal(*map(float, normal))
    cutter = vtk.vtkCutter()
    cutter.SetCutFunction(plane)
    cutter.SetInputData(surface)
    stripper = vtk.vtkStripper()
    stripper.SetInputConnection(cutter.GetOutputPort())
    stripper.Update()
    result = out if out is not None else vtk.vtkPolyData()
    result.DeepCopy(stripper.GetOutput())
    return result
