"""`resecta territories` against the real binary on a phantom with a Y-shaped portal tree."""
import json

import nibabel as nib
import numpy as np
import pytest

Y_SPEC = {
    "grid": {"dims": [80, 70, 56], "spacing": [1.5, 1.5, 1.6], "origin": [-59.25, -51.75, -44.0],
             "direction": {"euler_deg": [4.0, -3.0, 5.0]}},
    "liver": [{"center": [0.0, 0.0, 0.0], "radii": [45.0, 36.0, 30.0],
               "rotation": {"euler_deg": [0.0, 0.0, 0.0]}}],
    "tumors": [{"center": [-25.0, 0.0, 12.0], "radius": 5.0}],
    # A trunk along x to the junction at the origin, two symmetric children (y = ±).
    "vessels": [{"role": "portal", "radius": 4.0, "points": [[-44.0, 0.0, 0.0], [0.0, 0.0, 0.0]]},
                {"role": "portal", "radius": 2.5, "points": [[0.0, 0.0, 0.0], [32.0, 20.0, 0.0]]},
                {"role": "portal", "radius": 2.5, "points": [[0.0, 0.0, 0.0], [32.0, -20.0, 0.0]]}],
    "roles": {"parenchyma": [1], "tumor": [2], "portal": [3], "hepatic": [4]},
    "max_voxels": None, "truth_tolerance_mm": 0.05,
}


@pytest.fixture
def y_phantom(resecta, tmp_path):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(Y_SPEC))
    resecta("phantom", "--out", tmp_path / "ph", "--spec", spec, "--json")
    return tmp_path / "ph" / "phantom.nii.gz"


def test_a_y_tree_splits_the_liver_into_symmetric_territories(resecta, y_phantom, tmp_path):
    out = tmp_path / "out"
    r = resecta("territories", y_phantom, "--out-dir", out, "--json").json()
    (portal,) = r["systems"]
    assert portal["vessel"] == "portal" and portal["branch_points"] == 1 and portal["edges"] == 3
    assert portal["root"][0] < -35, "the root is the trunk's end"
    t = [x for x in r["territories"] if x["vessel"] == "portal"]
    assert [x["id"] for x in t] == [1, 2, 3] and t[0]["branch"] is None
    # They partition the functional liver exactly.
    assert sum(x["ml"] for x in t) == pytest.approx(r["liver_ml"], rel=1e-12)
    # The two children mirror each other about the bisector y = 0: each within one voxel layer
    # of their mean (the layer: the half-ellipse x > 0 of the liver's y = 0 section times the
    # largest spacing; the grid is oblique, so the split is not exact).
    a, b = t[1]["ml"], t[2]["ml"]
    layer_ml = np.pi * 45.0 * 30.0 / 2 * 1.6 / 1000
    assert abs(a - b) / 2 <= layer_ml, (a, b, layer_ml)
    # The label map holds them; the children lie on either side of y = 0.
    img = nib.load(str(out / "portal-territories.nii.gz"))
    lab = np.asarray(img.dataobj)
    assert set(np.unique(lab)) <= {0, 1, 2, 3}
    vox = nib.load(str(y_phantom)).header.get_zooms()
    ml = lambda k: (lab == k).sum() * float(np.prod(vox)) / 1000
    assert ml(2) == pytest.approx(a, rel=1e-6) and ml(3) == pytest.approx(b, rel=1e-6)
    ijk = np.argwhere(lab == 2)
    ras = nib.affines.apply_affine(img.affine, ijk)
    # NIfTI affines are RAS; the child's territory lies on one side of the bisector y = 0.
    side = np.sign(np.median(ras[:, 1]))
    assert side != 0 and np.mean(np.sign(ras[:, 1]) == side) > 0.97
    # Centrelines: one polyline per edge, radius per point, branch and generation per line.
    vtk = pytest.importorskip("vtk")
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(out / "portal-centrelines.vtp"))
    reader.Update()
    poly = reader.GetOutput()
    assert poly.GetNumberOfLines() == 3
    radius = poly.GetPointData().GetArray("radius")
    assert radius is not None and 1.5 < radius.GetRange()[1] < 5.0
    gen = poly.GetCellData().GetArray("generation")
    assert sorted(gen.GetValue(k) for k in range(3)) == [1, 2, 2]
    assert json.loads((out / "territories.json").read_text())["liver_ml"] == r["liver_ml"]


def test_explicit_branches_and_bad_input(resecta, y_phantom, tmp_path):
    out = tmp_path / "out"
    r = resecta("territories", y_phantom, "--out-dir", out, "--branches", '{"portal":[1]}',
                "--json").json()
    t = [x for x in r["territories"] if x["vessel"] == "portal"]
    assert [x["branch"] for x in t] == [None, 1]
    human = resecta("territories", y_phantom, "--out-dir", out).stdout
    assert "portal territory" in human
    for args, needle in [
        (["--branches", '{"arterial":[1]}'], "not a vessel system"),
        (["--branches", '{"portal":[99]}'], "portal vessels"),
        (["--roles", '{"parenchyma":[1],"tumor":[2]}'], "no vessel label"),
        (["--roles", "{"], "--roles"),
    ]:
        r = resecta("territories", y_phantom, "--out-dir", out, "--json", *args, check=False)
        assert r.code == 2 and needle in r.stderr and r.stdout == "", r.stderr
