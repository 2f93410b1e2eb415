"""`resecta bezier eval` against an independent numpy Bernstein evaluation, and the benchmark
command as a smoke test (its figures are not asserted)."""
import json
import os
from math import comb

import numpy as np
import pytest


def bernstein(deg, t):
    t = np.asarray(t)[:, None]
    k = np.arange(deg + 1)[None, :]
    return np.array([comb(deg, i) for i in range(deg + 1)])[None, :] * t**k * (1 - t) ** (deg - k)


def reference(P, ru, rv):
    m, n = P.shape[:2]
    Bu = bernstein(m - 1, np.linspace(0, 1, ru))
    Bv = bernstein(n - 1, np.linspace(0, 1, rv))
    return np.einsum("ai,ijc,bj->abc", Bu, P, Bv).reshape(-1, 3)


@pytest.mark.parametrize("m,n,ru,rv,precision,tol", [
    (4, 4, 17, 9, "f64", 1e-9),
    (12, 5, 33, 40, "f64", 1e-9),
    (7, 12, 21, 8, "f32", 2e-3),
])
def test_eval_matches_numpy(resecta, tmp_path, m, n, ru, rv, precision, tol):
    rng = np.random.default_rng(m * 100 + n)
    P = rng.uniform(-100, 100, size=(m, n, 3))
    cp = tmp_path / "cp.json"
    cp.write_text(json.dumps(P.reshape(-1, 3).tolist()))
    out = tmp_path / "s.json"
    summary = resecta("bezier", "eval", "--grid", f"{m},{n}", "--control-points", cp,
                      "--resolution", f"{ru},{rv}", "--precision", precision, "--out", out,
                      "--json").json()
    got = json.loads(out.read_text())
    assert got["resolution"] == [ru, rv] and summary["points"] == ru * rv
    pts = np.array(got["points"])
    np.testing.assert_allclose(pts, reference(P, ru, rv), atol=tol * 100)
    # Corners interpolate the corner control points.
    np.testing.assert_allclose(pts[0], P[0, 0], atol=tol * 100)
    np.testing.assert_allclose(pts[-1], P[-1, -1], atol=tol * 100)


def test_eval_writes_a_mesh(resecta, tmp_path):
    cp = tmp_path / "cp.json"
    cp.write_text(json.dumps([[i, j, 0.0] for i in range(4) for j in range(4)]))
    resecta("bezier", "eval", "--grid", "4,4", "--control-points", cp, "--resolution", "20,30",
            "--out", tmp_path / "s.vtp")
    info = resecta("info", tmp_path / "s.vtp", "--json").json()
    assert info["vertices"] == 600 and info["triangles"] == 2 * 19 * 29
    assert info["area_mm2"] == pytest.approx(9.0, rel=1e-9)


@pytest.mark.parametrize("points,grid", [
    ([[0, 0, 0]] * 15, "4,4"),                # wrong count
    ([[0, 0, "x"]] * 16, "4,4"),              # not numbers
    ([[0, 0, 0]] * 4, "1,4"),                 # M < 2
])
def test_eval_bad_input_exits_2(resecta, tmp_path, points, grid):
    cp = tmp_path / "cp.json"
    cp.write_text(json.dumps(points))
    r = resecta("bezier", "eval", "--grid", grid, "--control-points", cp, "--resolution", "5,5",
                "--out", tmp_path / "s.json", check=False)
    assert r.code == 2 and "panicked" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_bench_quick_smoke(resecta):
    rep = resecta("bench", "bezier", "--quick", "--json").json()
    rows = rep["results"]
    assert {r["method"] for r in rows} == {"brf", "mat", "mle"}
    assert {r["precision"] for r in rows} == {"f32", "f64"}
    for r in rows:
        for key in ("method", "precision", "grid", "resolution", "threads", "backend", "evals_per_s",
                    "write_ceiling_evals_per_s"):
            assert key in r
        assert r["evals_per_s"] > 0
    assert rep["speedups"] and rep["write_ceilings"]
    if os.environ.get("WGPU_BACKEND") == "vulkan":
        # CI installs lavapipe: the wgpu rows must be there, on Vulkan, with f64.
        assert rep["wgpu"] and rep["wgpu"]["backend"] == "vulkan" and rep["wgpu"]["f64"], rep["wgpu"]
        gpu = [r for r in rows if r["backend"] == "wgpu"]
        assert {r["precision"] for r in gpu} == {"f32", "f64"}
        assert all(r["threads"] is None and r["method"] == "mle" for r in gpu)
