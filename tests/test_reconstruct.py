"""`resecta reconstruct`, `measure`, `models` and `evaluate` against the real binary."""
import json
import struct

import pytest


@pytest.fixture
def phantom(resecta, tmp_path):
    out = resecta("phantom", "--out", tmp_path / "ph", "--preset", "small", "--json").json()
    return out["labels_file"]


def test_psr_json_contract_and_volume(resecta, phantom, tmp_path):
    mesh = tmp_path / "liver.vtp"
    pts = tmp_path / "points.ply"
    # d = 6: cells of ~1.5 mm on this 2×2×3 mm phantom (d = 7 over-resolves it: the surface then
    # follows the voxel staircase and ends ~1.5 % above the mask volume).
    r = resecta("reconstruct", phantom, "--labels", "1,2,3", "--method", "psr", "--depth", "6",
                "--out", mesh, "--points-out", pts, "--json")
    out = r.json()
    for key in ("polys", "points", "mean_mm", "p95_mm", "watertight", "time_ms", "volume_ml"):
        assert key in out
    assert out["watertight"] is True
    assert out["depth"] == 6
    assert out["mean_mm"] < 1.0 and out["p95_mm"] < 2.5
    # Half-voxel corrected: the model holds the mask's volume.
    assert abs(out["volume_ml"] - out["mask_ml"]) / out["mask_ml"] < 0.01
    assert mesh.stat().st_size > 0
    # Piped: no progress output.
    assert r.stderr == ""
    # The oriented points: binary PLY with x y z nx ny nz, one per sample.
    head = pts.read_bytes()[:400].split(b"end_header")[0].decode()
    assert f"element vertex {out['samples']}" in head
    assert all(f"property float {p}" in head or f"property double {p}" in head
               for p in ("x", "y", "z", "nx", "ny", "nz"))
    # Measuring the written mesh gives the same accuracy.
    m = resecta("measure", mesh, "--reference", phantom, "--labels", "1,2,3", "--json").json()
    assert m["polys"] == out["polys"]
    assert m["mean_mm"] == pytest.approx(out["mean_mm"], abs=1e-3)
    info = resecta("info", mesh, "--json").json()
    assert info["watertight"] is True


def test_mcsd_and_auto_depth(resecta, phantom, tmp_path):
    c = resecta("reconstruct", phantom, "--labels", "2", "--method", "mcsd", "--smoothing", "0.5",
                "--decimation", "0.3", "--out", tmp_path / "t.stl", "--json").json()
    assert c["watertight"] is True and c["method"] == "mcsd" and c["decimation"] == 0.3
    a = resecta("reconstruct", phantom, "--labels", "1,2,3", "--depth", "auto",
                "--out", tmp_path / "a.ply", "--json").json()
    assert 5 <= a["depth"] <= 8
    cands = {x["depth"]: x for x in a["depth_candidates"]}
    assert sorted(cands) == [5, 6, 7, 8]
    assert cands[a["depth"]]["sigma"] == min(x["sigma"] for x in cands.values())


def test_models_one_mesh_per_role_and_component(resecta, phantom, tmp_path):
    roles = '{"parenchyma":[1],"tumor":[2],"portal":[3]}'
    out = resecta("models", phantom, "--roles", roles, "--out-dir", tmp_path / "m", "--json").json()
    names = [m["name"] for m in out["models"]]
    assert names == ["parenchyma", "tumor_1", "portal_1"]
    for m in out["models"]:
        assert m["watertight"] is True
        assert (tmp_path / "m" / f"{m['name']}.vtp").is_file()
    assert out["models"][0]["method"] == "psr" and out["models"][1]["method"] == "mcsd"


def test_evaluate_writes_tables_and_plot(resecta, phantom, tmp_path):
    out = resecta("evaluate", phantom, "--labels", "1,2,3", "--out-dir", tmp_path / "e", "--quick",
                  "--json").json()
    assert out["models"] == 3 + 3 * 2
    assert out["p_best"].startswith("PSR") and out["c_best"].startswith("MCSD")
    study = json.loads((tmp_path / "e" / "study.json").read_text())
    assert len(study["study"]["models"]) == out["models"]
    md = (tmp_path / "e" / "study.md").read_text()
    assert "PSR d=5" in md and "MCSD" in md
    assert (tmp_path / "e" / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<svg" in (tmp_path / "e" / "pareto.svg").read_text()


@pytest.mark.parametrize("args, needle", [
    (["--labels", "9"], "9"),
    (["--labels", "1", "--depth", "11"], "depth"),
    (["--labels", "1", "--method", "mcsd", "--smoothing", "2"], "smoothing"),
    (["--labels", "0"], "label"),
])
def test_bad_input_exits_2_naming_the_problem(resecta, phantom, tmp_path, args, needle):
    r = resecta("reconstruct", phantom, *args, "--out", tmp_path / "x.vtp", check=False)
    assert r.code == 2, r.stderr
    assert needle in r.stderr
    assert not (tmp_path / "x.vtp").exists()


def test_real_totalsegmentator_liver(resecta, test_data, tmp_path):
    liver = test_data / "liver" / "totalsegmentator-example" / "v1_liver.nii.gz"
    out = resecta("reconstruct", liver, "--labels", "1", "--out", tmp_path / "l.vtp", "--json").json()
    assert out["watertight"] is True
    # 3 mm voxels; the mask touches the volume's top slice.
    assert out["mean_mm"] < 1.5
    assert abs(out["volume_ml"] - out["mask_ml"]) / out["mask_ml"] < 0.01
    c = resecta("reconstruct", liver, "--labels", "1", "--method", "mcsd", "--out", tmp_path / "c.vtp",
                "--json").json()
    assert c["watertight"] is True and c["mean_mm"] < 2.0


def test_real_msd_tumours_and_vessels(resecta, test_data, tmp_path):
    label = test_data / "liver" / "msd-task08-hepaticvessel" / "hepaticvessel_002_label.nii.gz"
    out = resecta("models", label, "--roles", '{"vessel":[1],"tumor":[2]}', "--out-dir", tmp_path,
                  "--json").json()
    roles = {m["role"] for m in out["models"]}
    assert roles == {"vessel", "tumor"}
    assert all(m["watertight"] for m in out["models"])
