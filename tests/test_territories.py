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


def test_a_liver_mask_stands_in_for_missing_liver_labels(resecta, y_phantom, tmp_path):
    """Label maps without a liver label (the MSD cases) take the liver from a mask: the same
    functional liver as the labels give; a mask on another grid is refused."""
    img = nib.load(str(y_phantom))
    lab = np.asarray(img.dataobj)
    mask = tmp_path / "liver.nii.gz"
    nib.save(nib.Nifti1Image((lab != 0).astype(np.uint8), img.affine), str(mask))
    want = resecta("territories", y_phantom, "--out-dir", tmp_path / "a", "--json").json()
    got = resecta("territories", y_phantom, "--out-dir", tmp_path / "b", "--json",
                  "--roles", '{"tumor":[2],"portal":[3]}', "--liver-mask", mask).json()
    assert got["liver_ml"] == pytest.approx(want["liver_ml"], rel=1e-12)
    assert [t["ml"] for t in got["territories"]] == pytest.approx(
        [t["ml"] for t in want["territories"]], rel=1e-12)
    shifted = tmp_path / "shifted.nii.gz"
    moved = img.affine.copy()
    moved[0, 3] += 1.0
    nib.save(nib.Nifti1Image((lab != 0).astype(np.uint8), moved), str(shifted))
    r = resecta("territories", y_phantom, "--out-dir", tmp_path / "c", "--json",
                "--liver-mask", shifted, check=False)
    assert r.code == 2 and "grid differs" in r.stderr, r.stderr


@pytest.mark.parametrize("case", ["002", "008", "010"])
def test_real_msd_vessel_territories_partition_the_liver(resecta, test_data, tmp_path, case):
    """The MSD hepatic-vessel label maps (label 1 vessels, 2 tumour) with their predicted liver
    masks: the territories partition the functional liver (sum within 0.1 %)."""
    d = test_data / "liver" / "msd-task08-hepaticvessel"
    r = resecta("territories", d / f"hepaticvessel_{case}_label.nii.gz", "--out-dir", tmp_path,
                "--roles", '{"tumor":[2],"vessel":[1]}',
                "--liver-mask", d / f"hepaticvessel_{case}_liver_pred.nii.gz", "--json").json()
    (system,) = r["systems"]
    assert system["vessel"] == "vessel" and system["edges"] >= 3
    t = r["territories"]
    assert len(t) >= 2
    assert abs(sum(x["ml"] for x in t) - r["liver_ml"]) <= 1e-3 * r["liver_ml"]
    print(f"MSD {case}: liver {r['liver_ml']:.1f} ml, {system['edges']} edges, "
          f"{system['branch_points']} branch points, {len(t)} territories, "
          f"{system['specks']} specks, {system['detached_components']} detached pieces, "
          f"{r['elapsed_ms']:.0f} ms")


def test_couinaud_style_grouping(resecta, y_phantom, tmp_path, test_data):
    """`--couinaud`: the largest portal subtrees (at most 8), named as an approximation. On the Y
    they are the two arms, as `--order 2`; on a real MSD tree (taken as portal) eight."""
    y = resecta("territories", y_phantom, "--out-dir", tmp_path / "y", "--couinaud", "--json").json()
    o2 = resecta("territories", y_phantom, "--out-dir", tmp_path / "o2", "--json").json()
    assert [t["ml"] for t in y["territories"]] == [t["ml"] for t in o2["territories"]]
    assert "approximation" in y["systems"][0]["grouping"]
    d = test_data / "liver" / "msd-task08-hepaticvessel"
    r = resecta("territories", d / "hepaticvessel_002_label.nii.gz", "--out-dir", tmp_path / "msd",
                "--roles", '{"tumor":[2],"portal":[1]}', "--couinaud",
                "--liver-mask", d / "hepaticvessel_002_liver_pred.nii.gz", "--json").json()
    t = r["territories"]
    assert len(t) == 1 + 8 and t[0]["branch"] is None
    assert abs(sum(x["ml"] for x in t) - r["liver_ml"]) <= 1e-3 * r["liver_ml"]
    assert min(x["ml"] for x in t[1:]) > 0
    r = resecta("territories", y_phantom, "--out-dir", tmp_path / "bad", "--couinaud",
                "--order", "3", check=False)
    assert r.code == 2


def test_real_totalsegmentator_portal_territories_partition_the_liver(resecta, test_data, tmp_path):
    """TotalSegmentator's v1 labels on its example CT (3 mm): liver 5, portal and splenic vein 9.
    The territories of the portal tree partition the functional liver (sum within 0.1 %)."""
    f = test_data / "liver" / "totalsegmentator-example" / "example_seg_v1_on_ct.nii.gz"
    r = resecta("territories", f, "--out-dir", tmp_path, "--roles", '{"parenchyma":[5],"portal":[9]}',
                "--json").json()
    (portal,) = r["systems"]
    assert portal["edges"] >= 3 and portal["branch_points"] >= 1
    t = r["territories"]
    assert len(t) >= 3
    assert abs(sum(x["ml"] for x in t) - r["liver_ml"]) <= 1e-3 * r["liver_ml"]
    # The liver label's own volume (41 733 voxels of 27 mm³) is inside the functional liver.
    assert r["liver_ml"] >= 41733 * 27 / 1000 - 1e-6
    print(f"TotalSegmentator: liver {r['liver_ml']:.1f} ml, {portal['edges']} edges, "
          + ", ".join(f"{x['ml']:.1f}" for x in t) + " ml")


def test_a_root_given_by_a_point(resecta, test_data, tmp_path):
    """TotalSegmentator's portal label holds the splenic vein, whose end at the spleen is the
    widest: `--root portal=x,y,z` roots the tree at the node nearest a point instead."""
    f = test_data / "liver" / "totalsegmentator-example" / "example_seg_v1_on_ct.nii.gz"
    roles = '{"parenchyma":[5],"portal":[9]}'
    auto = resecta("territories", f, "--out-dir", tmp_path / "a", "--roles", roles, "--json").json()
    img = nib.load(str(f))
    lab = np.asarray(img.dataobj)
    hilum = nib.affines.apply_affine(img.affine, np.argwhere(lab == 5).mean(axis=0))
    point = ",".join(f"{c:.2f}" for c in hilum)
    given = resecta("territories", f, "--out-dir", tmp_path / "g", "--roles", roles,
                    "--root", f"portal={point}", "--json").json()
    a, g = auto["systems"][0]["root"], given["systems"][0]["root"]
    assert np.linalg.norm(np.subtract(a, g)) > 20, (a, g)
    assert np.linalg.norm(np.subtract(g, hilum)) < np.linalg.norm(np.subtract(a, hilum))
    t = given["territories"]
    assert abs(sum(x["ml"] for x in t) - given["liver_ml"]) <= 1e-3 * given["liver_ml"]
    for bad in ["liver=0,0,0", "portal=1,2", "portal"]:
        r = resecta("territories", f, "--out-dir", tmp_path / "b", "--roles", roles, "--root", bad,
                    check=False)
        assert r.code == 2, bad
