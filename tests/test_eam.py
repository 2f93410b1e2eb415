"""`resecta reconstruct-points` and `resecta eam-study` against the real binary: a sphere's
points with and without normals, the phantom study's outputs, the LASC'13 atria."""
import json
import math

import numpy as np
import pytest


def fibonacci_sphere(n, radius, centre):
    i = np.arange(n)
    z = 1 - (2 * i + 1) / n
    r = np.sqrt(1 - z * z)
    t = math.pi * (3 - math.sqrt(5)) * i
    unit = np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)
    return np.asarray(centre) + radius * unit, unit


@pytest.mark.parametrize("with_normals", [False, True])
def test_reconstruct_points_gives_the_sphere(resecta, tmp_path, with_normals):
    pts, normals = fibonacci_sphere(2000, 20.0, [5.0, -3.0, 8.0])
    rows = np.hstack([pts, normals]) if with_normals else pts
    header = "x,y,z,nx,ny,nz" if with_normals else "x,y,z"
    csv = tmp_path / "points.csv"
    np.savetxt(csv, rows, delimiter=",", header=header, comments="")
    out = tmp_path / "sphere.vtp"
    r = resecta("reconstruct-points", csv, "--depth", "6", "--out", out, "--json").json()
    assert r["normals"] == ("given" if with_normals else "estimated")
    assert r["points"] == 2000 and r["depth"] == 6 and r["watertight"]
    assert r["components"] == (None if with_normals else 1)
    assert r["volume_ml"] == pytest.approx(4 / 3 * math.pi * 20**3 / 1000, rel=0.02)
    assert r["sampled_area_mm2"] == pytest.approx(4 * math.pi * 400, rel=0.1)
    assert out.stat().st_size > 0
    # Every vertex near the sphere (cells of 0.69 mm).
    info = resecta("info", out, "--json").json()
    lo, hi = np.array(info["bounds"][0]), np.array(info["bounds"][1])
    assert np.allclose((lo + hi) / 2, [5, -3, 8], atol=0.3)
    assert np.allclose(hi - lo, 40, atol=0.6)


def test_reconstruct_points_refuses_bad_files(resecta, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n1,2,3\n4,5\n")
    r = resecta("reconstruct-points", bad, "--out", tmp_path / "o.vtp", "--json", check=False)
    assert r.code == 2 and "line 3" in r.stderr and r.stdout == ""
    few = tmp_path / "few.csv"
    few.write_text("0,0,0\n1,0,0\n0,1,0\n")
    r = resecta("reconstruct-points", few, "--out", tmp_path / "o.vtp", check=False)
    assert r.code == 2 and "at least 4" in r.stderr


def test_eam_study_on_the_phantom_writes_its_tables_and_pictures(resecta, tmp_path):
    out = tmp_path / "study"
    r = resecta("eam-study", "phantom", "--out-dir", out, "--n", "100,300", "--u", "0.5,0.9",
                "--repeats", "2", "--noise", "--json").json()
    rows = r["results"]
    assert len(rows) == 8
    assert {tuple(sorted(x)) for x in rows} == {tuple(sorted(
        ["n", "u", "noise", "median_error_mm", "median_time_s", "thesis_median_error_mm"]))}
    err = {(x["n"], x["u"], x["noise"]): x["median_error_mm"] for x in rows}
    for u in (0.5, 0.9):
        for noise in (False, True):
            assert err[(300, u, noise)] < err[(100, u, noise)]
    assert rows[0]["thesis_median_error_mm"] in (4.30, 4.17)
    assert r["split"]["source"]["kind"] == "ostia" and r["split"]["source"]["veins"] == 4
    assert len(r["runs"]) == 2 * 2 * 2 * 2
    for name in ["eam.md", "eam.json", "eam-error.svg", "eam-error.png",
                 "eam-reconstructions.png"]:
        assert (out / name).stat().st_size > 0
    assert json.loads((out / "eam.json").read_text())["results"] == rows
    md = (out / "eam.md").read_text()
    assert "| 100 |" in md and "/ 4.30" in md


def test_eam_study_refuses_what_it_cannot_split(resecta, tmp_path):
    pts, _ = fibonacci_sphere(500, 10.0, [0, 0, 0])
    csv = tmp_path / "p.csv"
    np.savetxt(csv, pts, delimiter=",")
    closed = tmp_path / "closed.vtp"
    resecta("reconstruct-points", csv, "--out", closed)
    r = resecta("eam-study", closed, "--out-dir", tmp_path / "s", check=False)
    assert r.code == 2 and "give a plane" in r.stderr
    r = resecta("eam-study", closed, "--out-dir", tmp_path / "s", "--plane", "0,0,0,0,0,1",
                "--n", "100", "--u", "0.5", "--repeats", "1", "--json").json()
    assert r["split"]["source"]["kind"] == "given" and r["results"][0]["median_error_mm"] < 0.5


def test_eam_study_on_lasc_b002_beats_the_thesis(resecta, tmp_path, test_data):
    labels = test_data / "heart" / "lasc2013-b002" / "gt_std.mhd"
    r = resecta("eam-study", labels, "--out-dir", tmp_path / "s", "--n", "600", "--u", "0.9",
                "--repeats", "3", "--json").json()
    (row,) = r["results"]
    assert row["median_error_mm"] <= row["thesis_median_error_mm"] == 2.28
    assert r["split"]["source"]["veins"] == 4
