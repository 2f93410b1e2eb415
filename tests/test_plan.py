"""`resecta plan init` and `resecta plan` against the real binary, on a phantom and real livers."""
import json

import nibabel as nib
import numpy as np
import pytest


@pytest.fixture
def phantom(resecta, tmp_path):
    out = resecta("phantom", "--out", tmp_path / "ph", "--preset", "small", "--json").json()
    return out


def tumour_centroid(path, label):
    img = nib.load(str(path))
    ijk = np.argwhere(np.asarray(img.dataobj) == label)
    return nib.affines.apply_affine(img.affine, ijk.mean(axis=0))


def test_init_then_plan_json_contract_and_volumes(resecta, phantom, tmp_path):
    labels = phantom["labels_file"]
    c = tumour_centroid(labels, 2)
    end = c + np.array([-25.0, 0.0, 0.0])
    r = resecta("plan", "init", labels, "--tumor-label", "2", "--end-point",
                ",".join(f"{v:.3f}" for v in end), "--roles",
                '{"parenchyma":[1],"tumor":[2],"portal":[3]}', "--json")
    plan = r.json()
    assert plan["format"] == "resecta-plan/1"
    (res,) = plan["resections"]
    assert res["grid"] == [4, 4] and len(res["control_points"]) == 16
    # The initial grid lies on the plane halfway between the tumour centroid and the end point.
    mid, n = (c + end) / 2, (end - c) / np.linalg.norm(end - c)
    # (NIfTI stores the affine in float32: the two centroids agree to ~1e-3 mm.)
    assert np.abs((np.array(res["control_points"]) - mid) @ n).max() < 0.01
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(plan))
    out_dir = tmp_path / "out"
    r = resecta("plan", labels, plan_file, "--out-dir", out_dir, "--json")
    out = r.json()
    assert r.stderr == ""
    for key in ("total_ml", "remnant_ml", "remnant_pct", "resections"):
        assert key in out
    (s,) = out["resections"]
    for key in ("name", "resected_ml", "min_margin_mm", "min_margin_point", "violation",
                "violating_area_mm2", "complete_cut"):
        assert key in s
    assert s["complete_cut"] is True and out["complete"] is True
    assert out["remnant_ml"] + s["resected_ml"] == pytest.approx(out["total_ml"], rel=1e-9)
    assert out["remnant_pct"] == pytest.approx(100 * out["remnant_ml"] / out["total_ml"])
    # The tumour centroid is 12.5 mm from the plane; its radius is 8 mm, so ~4.5 mm margin.
    assert 3.0 < s["min_margin_mm"] < 6.0
    assert s["violation"] is True and s["violating_area_mm2"] > 0
    p = np.array(s["min_margin_point"])
    assert abs((p - mid) @ n) < 1e-3
    # Functional liver: parenchyma + portal inside the liver; the tumour does not count.
    img = nib.load(str(labels))
    data = np.asarray(img.dataobj)
    vox = abs(np.linalg.det(img.affine[:3, :3]))
    assert out["total_ml"] <= np.isin(data, [1, 3]).sum() * vox / 1000 + 1e-6
    assert out["total_ml"] >= (data == 1).sum() * vox / 1000
    # The resected label map agrees with the fractional volume to within the cut's voxel layer.
    cut = nib.load(str(out_dir / "resected.nii.gz"))
    assert np.allclose(cut.affine, img.affine, atol=1e-4)
    lab = np.asarray(cut.dataobj)
    assert set(np.unique(lab)) <= {0, 1, 2}
    assert (lab == 2).sum() * vox / 1000 == pytest.approx(s["resected_ml"], rel=0.05)
    assert (lab[data == 2] == 0).all()
    info = resecta("info", out_dir / "resection-0.vtp", "--json").json()
    assert "margin_mm" in json.dumps(info)
    again = json.loads((out_dir / "plan.json").read_text())
    assert again["resections"][0]["control_points"] == res["control_points"]


def test_metrics_against_a_reference_plan(resecta, phantom, tmp_path):
    """Sec. 7.4's metrics per resection: margin deviation = minimum − margin, volume deviation
    against the reference plan's resection of the same name, the median |H| of a plane is 0;
    a reference on another role map, or unreadable, is refused naming its file."""
    labels = phantom["labels_file"]
    roles = '{"parenchyma":[1],"tumor":[2],"portal":[3]}'
    plan = write_plan(tmp_path, planar())
    shifted = dict(planar(), control_points=[[p[0] + 5, p[1], p[2]] for p in planar()["control_points"]])
    ref = tmp_path / "ref.json"
    ref.write_text(json.dumps({"format": "resecta-plan/1", "roles": json.loads(roles),
                               "resections": [shifted]}))
    alone = resecta("plan", labels, plan, "--json").json()["resections"][0]
    out = resecta("plan", labels, plan, "--reference", ref, "--json").json()["resections"][0]
    refd = resecta("plan", labels, ref, "--json").json()["resections"][0]
    m = out["metrics"]
    assert m["margin_deviation_mm"] == pytest.approx(out["min_margin_mm"] - out["margin_mm"])
    assert m["median_abs_mean_curvature_per_mm"] < 1e-9
    assert alone["metrics"]["volume_deviation_pct"] is None
    want = 100 * (out["resected_ml"] - refd["resected_ml"]) / refd["resected_ml"]
    assert m["volume_deviation_pct"] == pytest.approx(want, rel=1e-9) and want != 0
    # Against itself: no deviation.
    same = resecta("plan", labels, plan, "--reference", plan, "--json").json()["resections"][0]
    assert same["metrics"]["volume_deviation_pct"] == 0
    human = resecta("plan", labels, plan, "--reference", ref).stdout
    assert "margin deviation" in human and "median |H|" in human
    bad = tmp_path / "nope.json"
    r = resecta("plan", labels, plan, "--reference", bad, "--json", check=False)
    assert r.code == 2 and "nope.json" in r.stderr and r.stdout == ""
    other = tmp_path / "other-roles.json"
    other.write_text(json.dumps({"format": "resecta-plan/1",
                                 "roles": {"parenchyma": [1], "tumor": [3]},
                                 "resections": [planar()]}))
    r = resecta("plan", labels, plan, "--reference", other, "--json", check=False)
    assert r.code == 2 and other.name in r.stderr, r.stderr


def write_plan(tmp_path, resection, roles='{"parenchyma":[1],"tumor":[2],"portal":[3]}'):
    plan = {"format": "resecta-plan/1", "roles": json.loads(roles), "resections": [resection]}
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(plan))
    return f


def planar(n=16, margin=10):
    pts = [[-20.0 + 0 * k, -80 + 160 * (k // 4) / 3, -80 + 160 * (k % 4) / 3] for k in range(n)]
    return {"name": "r1", "kind": "bezier", "grid": [4, 4], "control_points": pts,
            "margin_mm": margin}


def ds_plane(zs=(-80, -25, 30, 80)):
    """Straight traces on the plane x = −20, on axial slices."""
    return {"name": "r1", "kind": "ds", "margin_mm": 10,
            "traces": [[[-20.0, y, z] for y in (-80, -30, 20, 80)] for z in zs]}


def cp_ring(radius=80, n=24):
    """A ring on the plane x = −20."""
    ring = [[-20.0, radius * np.cos(2 * np.pi * k / n), radius * np.sin(2 * np.pi * k / n)]
            for k in range(n + 1)]
    return {"name": "r1", "kind": "cp", "margin_mm": 10, "traces": [ring]}


def test_ds_and_cp_plans_cut_the_bezier_plane_s_volume(resecta, phantom, tmp_path):
    """The same plane as Bézier, DS traces and a CP ring: volumes equal within 0.1 %, flat
    (median |H| < 1e-6 mm⁻¹), the same margin deviation; a CP deformation bends it and the
    plan file round-trips through --out-dir."""
    labels = phantom["labels_file"]
    runs = {}
    for kind, r in [("bezier", planar()), ("ds", ds_plane()), ("cp", cp_ring())]:
        f = tmp_path / f"{kind}.json"
        f.write_text(json.dumps({"format": "resecta-plan/1",
                                 "roles": {"parenchyma": [1], "tumor": [2], "portal": [3]},
                                 "resections": [r]}))
        runs[kind] = resecta("plan", labels, f, "--json", "--out-dir", tmp_path / kind).json()
    want = runs["bezier"]["resections"][0]
    for kind in ("ds", "cp"):
        got = runs[kind]["resections"][0]
        assert got["complete_cut"], got
        assert got["resected_ml"] == pytest.approx(want["resected_ml"], rel=1e-3), kind
        assert got["metrics"]["median_abs_mean_curvature_per_mm"] < 1e-6
        assert got["metrics"]["margin_deviation_mm"] == pytest.approx(
            want["metrics"]["margin_deviation_mm"], abs=0.05), kind
        saved = json.loads((tmp_path / kind / "plan.json").read_text())["resections"][0]
        assert saved["kind"] == kind and "control_points" not in saved
    bent = dict(cp_ring(), deformations=[{"point": [-20, 0, 0], "offset_mm": 6, "radius_mm": 30}])
    f = tmp_path / "bent.json"
    f.write_text(json.dumps({"format": "resecta-plan/1",
                             "roles": {"parenchyma": [1], "tumor": [2], "portal": [3]},
                             "resections": [bent]}))
    got = resecta("plan", labels, f, "--json").json()["resections"][0]
    assert got["metrics"]["median_abs_mean_curvature_per_mm"] > 1e-4
    assert got["resected_ml"] != pytest.approx(want["resected_ml"], rel=1e-3)


@pytest.mark.parametrize("resection, needle", [
    (ds_plane(zs=(-80, 80)), "2 traces"),
    (dict(ds_plane(), traces=ds_plane()["traces"][:3] + [[[-20, 0, 0], [-10, 0, 9], [-15, 0, 2]]]),
     "one orientation"),
    (dict(ds_plane(), traces=ds_plane()["traces"][:3]
          + [[[0, 0, 50], [10, 10, 50], [10, 0, 50], [0, 10, 50]]]), "intersects itself"),
    (dict(ds_plane(), traces=ds_plane()["traces"] + [[[-20, y, 30] for y in (-80, 0, 80)]]),
     "same axial slice"),
    (dict(ds_plane(), grid=[4, 4]), "not a control grid"),
    (dict(cp_ring(), traces=[[[-20, 0, z] for z in range(0, 50, 10)]]), "collinear"),
    (dict(cp_ring(), deformations=[{"point": [-20, 500, 0], "offset_mm": 5, "radius_mm": 9}]),
     "beyond the cutting plane"),
    (dict(cp_ring(), deformations=[{"point": [-20, 0, 0], "offset_mm": 5, "radius_mm": 0}]),
     "radius_mm"),
    (dict(planar(), traces=ds_plane()["traces"]), "not traces"),
])
def test_bad_ds_and_cp_plans_exit_2_naming_the_problem(resecta, phantom, tmp_path, resection,
                                                        needle):
    f = write_plan(tmp_path, resection)
    r = resecta("plan", phantom["labels_file"], f, "--json", check=False)
    assert r.code == 2, r.stderr
    assert r.stdout == ""
    assert needle in r.stderr and '"r1"' in r.stderr, r.stderr


@pytest.mark.parametrize("resection, needle", [
    (planar(n=15), "needs 16 control points, got 15"),
    (planar(margin=0), "margin_mm"),
    (dict(planar(), grid=[4, 1]), "grid 4×1"),
    (dict(planar(), control_points=[[1e300 * 10, 0, 0]] * 16), "control_points"),
])
def test_bad_plans_exit_2_naming_the_problem(resecta, phantom, tmp_path, resection, needle):
    f = write_plan(tmp_path, resection)
    r = resecta("plan", phantom["labels_file"], f, "--json", check=False)
    assert r.code == 2, r.stderr
    assert r.stdout == ""
    assert needle in r.stderr or "finite" in r.stderr, r.stderr


def test_bad_init_input(resecta, phantom, tmp_path):
    labels = phantom["labels_file"]
    c = tumour_centroid(labels, 2)
    roles = ("--roles", '{"parenchyma":[1],"tumor":[2],"portal":[3]}')
    at = ",".join(f"{v:.6f}" for v in c + 0.3)
    r = resecta("plan", "init", labels, "--tumor-label", "2", "--end-point", at, *roles,
                "--json", check=False)
    assert r.code == 2 and "within 1 mm of the tumour centroid" in r.stderr, r.stderr
    far = ",".join(f"{v:.3f}" for v in c + np.array([0, 0, 300.0]))
    r = resecta("plan", "init", labels, "--tumor-label", "2", "--end-point", far, *roles,
                check=False)
    assert r.code == 2 and "misses the liver" in r.stderr
    r = resecta("plan", "init", labels, "--tumor-label", "7", "--end-point", far, check=False)
    assert r.code == 2 and "label 7" in r.stderr
    r = resecta("plan", "init", labels, "--tumor-label", "2", "--end-point", "1,2", check=False)
    assert r.code == 2 and "three finite numbers" in r.stderr
    f = write_plan(tmp_path, planar())
    f.write_text(f.read_text().replace("resecta-plan/1", "resecta-plan/9"))
    r = resecta("plan", labels, f, check=False)
    assert r.code == 2 and "resecta-plan/9" in r.stderr


def plan_real(resecta, tmp_path, labels, roles, tumour_label, end, target_point=None):
    args = ["plan", "init", labels, "--tumor-label", str(tumour_label), "--end-point",
            ",".join(f"{v:.3f}" for v in end), "--roles", roles, "--json"]
    if target_point is not None:
        args += ["--tumor-point", ",".join(f"{v:.3f}" for v in target_point)]
    plan = resecta(*args).json()
    f = tmp_path / "plan.json"
    f.write_text(json.dumps(plan))
    return resecta("plan", labels, f, "--json").json()


def test_real_totalsegmentator_liver_with_a_synthetic_tumour(resecta, test_data, tmp_path):
    """TotalSegmentator's real liver (3 mm) with a 12 mm tumour placed 25 mm inside it."""
    img = nib.load(str(test_data / "liver/totalsegmentator-example/v1_liver.nii.gz"))
    liver = np.asarray(img.dataobj) > 0
    ijk = np.argwhere(liver)
    centre = nib.affines.apply_affine(img.affine, ijk.mean(axis=0))
    world = nib.affines.apply_affine(img.affine, np.indices(liver.shape).reshape(3, -1).T)
    ball = (np.linalg.norm(world - centre, axis=1) <= 12.0).reshape(liver.shape) & liver
    labels = liver.astype(np.uint8)
    labels[ball] = 2
    path = tmp_path / "liver_tumour.nii.gz"
    nib.save(nib.Nifti1Image(labels, img.affine), str(path))
    out = plan_real(resecta, tmp_path, path, '{"parenchyma":[1],"tumor":[2]}', 2,
                    centre + np.array([0.0, 0.0, -60.0]))
    (s,) = out["resections"]
    assert s["complete_cut"] is True
    vox = abs(np.linalg.det(img.affine[:3, :3]))
    assert out["total_ml"] == pytest.approx((labels == 1).sum() * vox / 1000, rel=1e-6)
    assert 0 < s["resected_ml"] < out["total_ml"]
    assert out["remnant_ml"] + s["resected_ml"] == pytest.approx(out["total_ml"])
    # The plane is 30 mm from the tumour centre: margin ≈ 30 − 12 (voxelised at 3 mm).
    assert 15.0 < s["min_margin_mm"] < 21.0
    assert s["violation"] is False


def test_real_msd_tumour_with_vessels(resecta, test_data, tmp_path):
    """MSD case 002: predicted liver + manual vessels (1) and tumours (2)."""
    d = test_data / "liver/msd-task08-hepaticvessel"
    liver = nib.load(str(d / "hepaticvessel_002_liver_pred.nii.gz"))
    lab = nib.load(str(d / "hepaticvessel_002_label.nii.gz"))
    m = np.asarray(liver.dataobj) > 0
    v = np.asarray(lab.dataobj)
    labels = np.where(m, 1, 0).astype(np.uint8)
    labels[v == 1] = 3
    labels[v == 2] = 2
    path = tmp_path / "case.nii.gz"
    nib.save(nib.Nifti1Image(labels, lab.affine), str(path))
    # Resect the tumour holding the tumour voxel nearest the tumours' centroid; end point 40 mm
    # from it towards the liver's centre.
    tum = np.argwhere(labels == 2)
    tw = nib.affines.apply_affine(lab.affine, tum)
    pick = tw[np.argmin(np.linalg.norm(tw - tw.mean(axis=0), axis=1))]
    centre = nib.affines.apply_affine(lab.affine, np.argwhere(m).mean(axis=0))
    toward = (centre - pick) / np.linalg.norm(centre - pick)
    out = plan_real(resecta, tmp_path, path, '{"parenchyma":[1],"tumor":[2],"portal":[3]}', 2,
                    pick + 40.0 * toward, target_point=pick)
    (s,) = out["resections"]
    vox = abs(np.linalg.det(lab.affine[:3, :3]))
    # Functional liver: parenchyma and the vessels inside it, never the tumours.
    assert (labels == 1).sum() * vox / 1000 <= out["total_ml"] <= np.isin(labels, [1, 3]).sum() * vox / 1000
    assert s["complete_cut"] is True, s
    assert out["remnant_ml"] + s["resected_ml"] == pytest.approx(out["total_ml"])
    assert s["min_margin_mm"] is not None and s["min_margin_mm"] < 40.0
