"""`resecta reconstruct --backend gpu` and `resecta bench recon` against the real binary, under
`WGPU_BACKEND=vulkan` (lavapipe in CI); skipped with a visible reason when no adapter exists and
WGPU_BACKEND is unset."""
import json
import os
import subprocess

import pytest

from conftest import resecta_bin


def run(*args, env=None):
    env = {**os.environ, **(env or {})}
    return subprocess.run([resecta_bin(), *map(str, args)], capture_output=True, text=True,
                          timeout=600, env=env)


def gpu_or_skip(proc):
    if proc.returncode != 0 and "--backend gpu" in proc.stderr and not os.environ.get("WGPU_BACKEND"):
        print(f"SKIP: no GPU adapter: {proc.stderr.strip()}")
        pytest.skip("no GPU adapter (set WGPU_BACKEND=vulkan with lavapipe)")
    assert proc.returncode == 0, proc.stderr


@pytest.fixture
def phantom(resecta, tmp_path):
    out = resecta("phantom", "--out", tmp_path / "ph", "--preset", "small", "--json").json()
    return out["labels_file"]


def test_reconstruct_gpu_matches_cpu(resecta, phantom, tmp_path):
    common = (phantom, "--labels", "1,2,3", "--depth", "6", "--json")
    cpu = resecta("reconstruct", *common, "--out", tmp_path / "c.vtp").json()
    assert cpu["backend"] == "cpu" and "adapter" not in cpu
    proc = run("reconstruct", *common, "--out", tmp_path / "g.vtp", "--backend", "gpu",
               env={"WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")})
    gpu_or_skip(proc)
    gpu = json.loads(proc.stdout)
    assert gpu["backend"] == "gpu" and gpu["adapter"]["name"]
    assert gpu["watertight"] is True and gpu["samples"] == cpu["samples"]
    assert abs(gpu["volume_ml"] - cpu["volume_ml"]) / cpu["volume_ml"] < 5e-4
    assert gpu["mean_mm"] == pytest.approx(cpu["mean_mm"], abs=0.05)


def test_reconstruct_gpu_without_adapter_names_the_problem(resecta, phantom, tmp_path):
    # No backend of this name has an adapter: a clear error, exit 1.
    proc = run("reconstruct", phantom, "--labels", "1", "--out", tmp_path / "x.vtp",
               "--backend", "gpu", env={"WGPU_BACKEND": "metal"})
    assert proc.returncode == 1
    assert "--backend gpu" in proc.stderr and "adapter" in proc.stderr


def test_bench_recon_reports_both_backends(tmp_path):
    proc = run("bench", "recon", "--backend", "both", "--depths", "5,6", "--dims", "64,60,48",
               "--json", env={"WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")})
    gpu_or_skip(proc)
    rep = json.loads(proc.stdout)
    rows = {(r["backend"], r["depth"]): r for r in rep["rows"]}
    assert sorted(rows) == [("cpu", 5), ("cpu", 6), ("gpu", 5), ("gpu", 6)]
    for r in rows.values():
        assert r["watertight"] is True and r["residual"] <= rep["tolerance"]
        assert r["solve_s"] > 0 and r["total_s"] >= r["solve_s"]
    assert [d["depth"] for d in rep["cpu_vs_gpu"]] == [5, 6]
    for d in rep["cpu_vs_gpu"]:
        assert d["max_mm"] <= 0.05 and d["volume_pct"] <= 0.05
    assert rep["adapter"]["name"]
