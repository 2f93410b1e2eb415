"""Compare resecta-meshfilter's windowed_sinc with VTK's vtkWindowedSincPolyDataFilter.

Throwaway check, not part of the test suite. Needs `pip install vtk numpy` (any venv).
    cargo run --release -p resecta-meshfilter --example sinc_dump -- /tmp/sinc
    python docs/bench/meshfilter/compare_vtk.py /tmp/sinc > docs/bench/meshfilter/compare_vtk.txt
Prints, per mesh and parameter set, the largest vertex difference |ours - VTK| in mm and
relative to the mesh's bounding-box diagonal, and how far VTK moved the vertices.
"""

import sys
from pathlib import Path

import numpy as np
import vtk
from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy


def read_mesh(path):
    v, f = [], []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            f.append([int(x) for x in parts[1:4]])
    return np.array(v, dtype=np.float64), np.array(f, dtype=np.int64)


def to_polydata(v, f):
    pts = vtk.vtkPoints()
    pts.SetDataTypeToDouble()
    pts.SetData(numpy_to_vtk(v, deep=True))
    offsets = np.arange(0, 3 * len(f) + 1, 3, dtype=np.int64)
    polys = vtk.vtkCellArray()
    polys.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(f.ravel().copy(), deep=True))
    pd = vtk.vtkPolyData()
    pd.SetPoints(pts)
    pd.SetPolys(polys)
    return pd


def main(root):
    root = Path(root)
    print(f"VTK {vtk.vtkVersion.GetVTKVersion()}, double-precision points")
    print(f"{'mesh':8} {'case':26} {'iters':>5} {'passband':>9} {'max |ours-VTK| mm':>18} "
          f"{'/ diagonal':>11} {'max VTK move mm':>16}")
    worst = 0.0
    for line in (root / "manifest.txt").read_text().splitlines():
        name, case, file, iters, pb, norm, bnd, nm, wnm, edge, window = line.split()
        v, f = read_mesh(root / f"mesh_{name}.txt")
        ours, _ = read_mesh(root / file)
        flt = vtk.vtkWindowedSincPolyDataFilter()
        flt.SetInputData(to_polydata(v, f))
        flt.SetNumberOfIterations(int(iters))
        flt.SetPassBand(float(pb))
        flt.SetNormalizeCoordinates(int(norm))
        flt.SetBoundarySmoothing(int(bnd))
        flt.SetFeatureEdgeSmoothing(0)
        flt.SetNonManifoldSmoothing(int(nm))
        flt.SetWeightNonManifoldEdges(int(wnm))
        flt.SetEdgeAngle(float(edge))
        flt.SetWindowFunction(int(window))
        flt.Update()
        theirs = vtk_to_numpy(flt.GetOutput().GetPoints().GetData()).astype(np.float64)
        diff = np.abs(ours - theirs).max()
        diag = np.linalg.norm(v.max(axis=0) - v.min(axis=0))
        moved = np.linalg.norm(theirs - v, axis=1).max()
        worst = max(worst, diff / diag)
        print(f"{name:8} {case:26} {iters:>5} {float(pb):9.4g} {diff:18.3e} {diff / diag:11.3e} "
              f"{moved:16.4f}")
    print(f"worst relative difference: {worst:.3e}")


if __name__ == "__main__":
    main(sys.argv[1])
