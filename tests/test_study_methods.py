"""`resecta study methods` (Paper II's comparison, in silico) against the real binary."""
import json

import pytest

METHODS = ["bezier", "ds", "cp"]
MSD = ("liver", "msd-task08-hepaticvessel")


def test_quick_phantom_study_contract(resecta, tmp_path):
    out_dir = tmp_path / "study"
    r = resecta("study", "methods", "--quick", "--margins", "5,10", "--out-dir", out_dir, "--json")
    out = r.json()
    assert r.stderr == ""
    assert out["study"] == "methods" and out["in_silico"] is True
    assert out["margins_mm"] == [5.0, 10.0] and out["inputs_per_method"] == 16
    # The quick set: one phantom with two tumours, each at both margins.
    assert out["sources"] == ["phantom-ellipsoid-a"]
    assert out["skipped"] == []
    assert out["cases"] == len(out["records"]) == 2 * 2
    for f in ("methods.md", "methods.json", "methods.svg", "methods.png"):
        assert (out_dir / f).stat().st_size > 0
    assert json.loads((out_dir / "methods.json").read_text())["cases"] == out["cases"]
    assert (out_dir / "methods.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out_dir / "methods.md").read_text()
    assert "not the surgeons' study" in md and "Table 7.2" in md
    for case in out["records"]:
        assert [m["method"] for m in case["methods"]] == METHODS
        for m in case["methods"]:
            assert m["inputs"] == 16
            assert m["complete_cut"] is True, (case["tumour"], case["margin_mm"], m)
            assert m["resected_ml"] > 0
            assert m["violation"] == (m["margin_deviation_mm"] < -0.01)
        bez = case["methods"][0]
        # The Bézier plan is the reference: exactly no volume deviation against itself.
        assert bez["volume_deviation_pct"] == 0.0
        # The scripted user moved the inner inputs onto the margin shell.
        assert bez["pushed_inputs"] >= 1
        # The interpolating DS surface passes through inputs placed exactly at the margin, so
        # it falls short of the margin at least as much as the Bézier surface, which only
        # approaches its control points.
        ds = case["methods"][1]
        assert ds["margin_deviation_mm"] <= bez["margin_deviation_mm"] + 1e-6
    summary = {s["method"]: s for s in out["summary"]}
    assert list(summary) == METHODS
    for s in summary.values():
        assert s["n"] == out["cases"] and s["complete_cuts"] == out["cases"]
        assert 0 <= s["violations"] <= s["n"]
        q = s["margin_deviation_mm"]
        assert q["min"] <= q["q25"] <= q["median"] <= q["q75"] <= q["max"]
    assert summary["bezier"]["volume_deviation_pct"]["max"] == 0.0
    thesis = {t["method"]: t for t in out["thesis_table_7_2"]}
    assert thesis["bezier"]["margin_deviation_mm"][2] == 0.42
    assert thesis["cp"]["violations"] == 31 and thesis["ds"]["violations"] == 28


def test_equally_spaced_layout_misses_the_tumours(resecta, tmp_path):
    """The equally spaced layout never reaches the margin shell on the quick phantom: every
    method plans P0 itself, which touches the shell (deviation ≈ 0)."""
    r = resecta("study", "methods", "--quick", "--layout", "regular", "--margins", "10",
                "--out-dir", tmp_path / "s", "--json")
    out = r.json()
    assert out["cases"] == 2
    for case in out["records"]:
        for m in case["methods"]:
            assert m["pushed_inputs"] == 0
            assert m["complete_cut"] is True
            assert abs(m["margin_deviation_mm"]) < 0.1
            assert abs(m["volume_deviation_pct"]) < 1e-6


def test_bad_arguments_exit_2(resecta, tmp_path):
    r = resecta("study", "methods", "--margins", "0", "--out-dir", tmp_path, check=False)
    assert r.code == 2 and "--margins" in r.stderr
    r = resecta("study", "methods", tmp_path / "missing.nii.gz", "--out-dir", tmp_path,
                check=False)
    assert r.code == 2
    r = resecta("study", "methods", tmp_path / "a.nii.gz", "--liver-mask", tmp_path / "m1.nii.gz",
                "--liver-mask", tmp_path / "m2.nii.gz", "--out-dir", tmp_path, check=False)
    assert r.code == 2 and "--liver-mask" in r.stderr


def test_real_msd_label_map_with_liver_mask(resecta, test_data, tmp_path):
    folder = test_data.joinpath(*MSD)
    labels = folder / "hepaticvessel_010_label.nii.gz"
    if not labels.is_file():
        print(f"SKIP: {labels} not found")
        pytest.skip(f"{labels} not found")
    r = resecta("study", "methods", labels, "--liver-mask",
                folder / "hepaticvessel_010_liver_pred.nii.gz", "--margins", "5",
                "--out-dir", tmp_path / "s", "--json")
    out = r.json()
    assert out["sources"] == [labels.name]
    assert out["cases"] == len(out["records"]) >= 1
    for case in out["records"]:
        assert case["liver_ml"] > 500
        assert [m["method"] for m in case["methods"]] == METHODS
        bez = case["methods"][0]
        if bez["complete_cut"]:
            assert bez["volume_deviation_pct"] == 0.0
    # Label 2 of these maps is one component spanning the liver: flagged as not tumour-like.
    assert max(c["target_extent_mm"] for c in out["records"]) > 100
    assert "not tumour-like" in (tmp_path / "s" / "methods.md").read_text()
