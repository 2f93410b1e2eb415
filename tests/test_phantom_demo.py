"""`resecta phantom` and `resecta demo`, cross-checked with nibabel's reading of our files."""
import json

import nibabel as nib
import numpy as np
import pytest


def test_phantom_labels_sit_at_the_right_world_positions(resecta, tmp_path):
    out = resecta("phantom", "--out", tmp_path, "--preset", "small", "--json").json()
    truth = json.loads((tmp_path / "truth.json").read_text())
    img = nib.load(out["labels_file"])
    data = np.asarray(img.dataobj)
    assert list(data.shape) == out["dims"]
    np.testing.assert_allclose(np.linalg.norm(img.affine[:3, :3], axis=0), out["spacing"], rtol=1e-6)
    # Voxel counts per label as nibabel sees them equal the truth.
    values, counts = np.unique(data, return_counts=True)
    assert {int(v): int(c) for v, c in zip(values, counts) if v} == {
        int(k): v["voxels"] for k, v in truth["labels"].items()}
    # Every tumour voxel centre (through nibabel's affine) is inside a tumour sphere, and every
    # voxel centre well inside a sphere is labelled tumour: the oblique affine is written right.
    tumor = truth["spec"]["roles"]["tumor"][0]
    ijk = np.argwhere(np.ones(data.shape, bool))
    world = nib.affines.apply_affine(img.affine, ijk)
    spheres = [s for s in truth["shapes"] if s["kind"] == "sphere"]
    assert spheres
    dist = np.min([np.linalg.norm(world - s["center"], axis=1) - s["radius"] for s in spheres], axis=0)
    labels = data.reshape(-1, order="F")[np.ravel_multi_index(ijk.T, data.shape, order="F")]
    assert np.all(dist[labels == tumor] <= 1e-6)
    assert np.all(labels[dist < -1e-6] == tumor)


def test_phantom_spec_round_trips_and_formats_agree(resecta, tmp_path):
    resecta("phantom", "--out", tmp_path / "a", "--preset", "small", "--json")
    resecta("phantom", "--out", tmp_path / "b", "--spec", tmp_path / "a" / "truth.json",
            "--name", "p.nrrd", "--json")
    a = resecta("info", tmp_path / "a" / "phantom.nii.gz", "--json").json()
    b = resecta("info", tmp_path / "b" / "p.nrrd", "--json").json()
    assert [(l["value"], l["voxels"]) for l in a["labels"]] == [(l["value"], l["voxels"]) for l in b["labels"]]
    # NIfTI holds its affine in f32; NRRD in full precision.
    for la, lb in zip(a["labels"], b["labels"]):
        assert la["ml"] == pytest.approx(lb["ml"], rel=1e-6)
    np.testing.assert_allclose(a["affine"], b["affine"], atol=1e-4)


def test_bad_spec_exits_2(resecta, tmp_path):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"grid": {"dims": [10, 10, 10], "spacing": [1, 1, 1], "origin": [0, 0, 0]},
                                "liver": [{"center": [5, 5, 5], "radii": [3, 3, -1]}]}))
    r = resecta("phantom", "--out", tmp_path / "o", "--spec", spec, "--json", check=False)
    assert r.code == 2 and r.stdout == ""
    assert "radii" in r.stderr or "positive" in r.stderr, r.stderr


def test_demo_checks_itself_against_the_truth(resecta, tmp_path):
    rep = resecta("demo", "--out", tmp_path, "--json").json()
    assert rep["all_round_trips_exact"]
    assert len(rep["round_trips"]) == 4
    for v in rep["volumes"]:
        # Voxel-centre sampling at 0.8×0.8×2.5 mm: within 1 % for bulk, 3 % for thin tubes.
        assert abs(v["relative_error"]) < (0.01 if v["role"] in ("parenchyma", "tumor") else 0.03), v
    for c in rep["clearances"]:
        # Model vertices lie on the sphere; tube models are capsule chains inscribed to < 0.1 mm.
        assert c["model_mm"] == pytest.approx(c["analytic_mm"], abs=0.1), c
        # Voxel centres of the two labels lie inside the shapes: never closer than the true gap,
        # and at most one voxel diagonal (2.74 mm) farther.
        assert c["analytic_mm"] - 1e-6 <= c["voxel_edt_mm"] <= c["analytic_mm"] + 2.74, c
    for m in rep["models"]:
        assert m["watertight"]
        if m["analytic_ml"] is not None:
            assert m["volume_ml"] == pytest.approx(m["analytic_ml"], rel=2e-3)
        info = resecta("info", m["file"], "--json").json()
        assert info["triangles"] == m["triangles"] and info["watertight"]
