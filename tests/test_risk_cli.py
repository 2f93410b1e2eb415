"""`resecta plan --json` with the risk analysis and `resecta resectogram` against the real binary,
on a phantom whose portal trunk a plane cuts: everything downstream loses its supply."""
import json

import numpy as np
import pytest

from test_territories import Y_SPEC

ROLES = Y_SPEC["roles"]


@pytest.fixture
def cut_trunk(resecta, tmp_path):
    """The Y phantom (trunk along x from −44 to 0) and the plane x = −15 resecting the tumour at
    x = −25: the plane crosses the trunk inside the liver."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(Y_SPEC))
    resecta("phantom", "--out", tmp_path / "ph", "--spec", spec, "--json")
    labels = tmp_path / "ph" / "phantom.nii.gz"
    plan = resecta("plan", "init", labels, "--tumor-label", "2", "--plane-point", "-15,0,0",
                   "--plane-normal", "1,0,0", "--roles", json.dumps(ROLES), "--json").json()
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(plan))
    return labels, path


def test_cutting_the_trunk_devascularises_the_whole_remnant(resecta, cut_trunk, tmp_path):
    labels, plan = cut_trunk
    r = resecta("plan", labels, plan, "--out-dir", tmp_path / "out", "--json").json()
    assert r["complete"] and r["has_portal"] and not r["has_hepatic"]
    (c,) = r["cut_vessels"]
    assert c["system"] == "portal" and c["generation"] == 1 and abs(c["point"][0] + 15) < 1.5
    # Downstream of the trunk's cut is every centreline point the remnant is nearest to.
    assert r["devascularised_ml"] == pytest.approx(r["remnant_ml"], rel=0.02)
    assert r["functional_remnant_ml"] == pytest.approx(r["remnant_ml"] - r["at_risk_ml"])
    assert r["flr_warning"] is True and r["remnant_pct"] > r["flr_threshold_pct"]
    # The risk map written beside: its devascularised voxels are the remnant's, in RAS.
    import nibabel as nib  # noqa: PLC0415

    img = nib.load(str(tmp_path / "out" / "risk.nii.gz"))
    cls = np.asarray(img.dataobj)
    ml = float(np.prod(img.header.get_zooms()[:3])) / 1000
    assert set(np.unique(cls)) <= {0, 1, 2, 3}
    assert (cls == 3).sum() * ml == pytest.approx(r["devascularised_ml"], rel=0.05)
    assert (cls == 1).sum() * ml < 0.05 * r["remnant_ml"]
    ras = nib.affines.apply_affine(img.affine, np.argwhere(cls == 3))
    assert np.median(ras[:, 0]) > -15, "the remnant lies beyond the plane x = −15"
    terr = np.asarray(nib.load(str(tmp_path / "out" / "risk-territories.nii.gz")).dataobj)
    assert terr.shape == cls.shape and np.all((terr > 0) == (cls > 0))


def test_resectogram_png(resecta, cut_trunk, tmp_path):
    labels, plan = cut_trunk
    out = tmp_path / "r.png"
    r = resecta("resectogram", labels, plan, "--out", out, "--size", "160x120", "--scale", "3",
                "--json").json()
    assert (r["width"], r["height"], r["png_width"], r["png_height"]) == (160, 120, 480, 360)
    assert sum(r["class_counts"]) == 160 * 120 and 0.05 < r["inside_fraction"] < 0.95
    assert [c["system"] for c in r["cut_vessels"]] == ["portal"]
    assert r["territories"] >= 1 and r["worst_uv"] is not None
    png = out.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image  # noqa: PLC0415

    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (360, 480, 3)
    # The portal disc (blue) and the liver boundary (black) are drawn.
    assert np.any(np.all(img == [40, 90, 220], axis=-1)) and np.any(np.all(img == 0, axis=-1))
    for bad, msg in [(["--size", "0x10"], "1..=512"), (["--scale", "9"], "--scale"),
                     (["--resection", "nope"], "nope")]:
        e = resecta("resectogram", labels, plan, "--out", out, *bad, check=False)
        assert e.code == 2 and msg in e.stderr, e.stderr
