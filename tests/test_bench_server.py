"""`resecta bench server --quick`: the load benchmark starts a server, runs every scenario and
reports one JSON object (figures of a debug build and a quick run mean nothing; the shape does)."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import resecta_bin


def test_bench_server_quick_smoke(resecta, tmp_path):
    rep = resecta("bench", "server", "--quick", "--json", "--sessions", "3", "--idle-sessions", "1",
                  "--plot-dir", tmp_path).json()
    assert rep["compute"] == {"backend": "cpu", "adapter": "", "f64": True}  # --gpu off by default
    rows = {(r["scenario"], r["resolution"][0], r["sessions"]): r for r in rep["latencies"]}
    assert set(rows) == {("single session", 40, 1), ("single session", 200, 1),
                         ("single session, paced", 40, 1), ("concurrent sessions", 40, 3)}
    for r in rows.values():
        assert r["edits"] > 0 and 0 < r["p50_ms"] <= r["p90_ms"] <= r["p99_ms"] <= r["max_ms"]
        assert r["server_cpu_ms_per_edit"] > 0
        assert 0 < r["ack_p50_ms"] <= r["ack_p99_ms"]
    multi = rows[("concurrent sessions", 40, 3)]
    single = rows[("single session", 40, 1)]
    paced = rows[("single session, paced", 40, 1)]
    assert math.isclose(rep["concurrent_p99_ratio"], multi["p99_ms"] / single["p99_ms"])
    assert math.isclose(rep["concurrent_p99_ratio_paced"], multi["p99_ms"] / paced["p99_ms"])
    assert rep["idle_session_bytes"] > 0
    assert rep["upload"]["bytes"] == 512 * 512 * 300 and rep["upload"]["median_s"] > 0
    assert (tmp_path / "edit_latency_cdf.png").stat().st_size > 0
    assert (tmp_path / "edit_latency_cdf.svg").stat().st_size > 0
    ready, restart = rep["ready"], rep["restart"]
    assert ready["dims"] == [512, 512, 300]
    for f in ("ack", "first_resection_from_ack", "first_resection_from_start", "volumes_from_start"):
        assert len(ready[f]["runs_s"]) == 1 and ready[f]["median_s"] > 0
    assert ready["first_resection_from_start"]["median_s"] > ready["first_resection_from_ack"]["median_s"]
    assert ready["volumes_from_start"]["median_s"] >= ready["first_resection_from_start"]["median_s"]
    assert restart["older_sessions"] == 1
    for f in ("bound", "first_edit", "volumes_after_edit", "first_volumes"):
        assert restart[f]["runs_s"] and restart[f]["min_s"] <= restart[f]["median_s"] <= restart[f]["max_s"]
    assert restart["volumes_after_edit"]["median_s"] >= restart["first_edit"]["median_s"]


def test_bench_server_python_client_quick_smoke(resecta):
    """`--client python`: the drag watched in turn by the benchmark's client and by the Python
    client (clients/python/scripts/bench_watch.py, run with this interpreter)."""
    root = Path(__file__).resolve().parents[1]
    rep = resecta("bench", "server", "--client", "python", "--quick", "--json",
                  "--python", sys.executable,
                  "--python-driver", root / "clients/python/scripts/bench_watch.py").json()
    assert rep["patient"]["name"] == "demo phantom"
    assert rep["patient"]["tumour_voxels"] > 0 and rep["patient"]["margin_triangles"] > 0
    assert rep["patient"]["resection_vertices"] == 40 * 40
    rows = {r["scenario"]: r for r in rep["latencies"]}
    assert set(rows) == {"rust client, round 1", "python client, round 1"}
    for r in rows.values():
        assert r["edits"] == 20 and 0 < r["p50_ms"] <= r["p90_ms"] <= r["p99_ms"] <= r["max_ms"]
        assert 0 < r["ack_p50_ms"] <= r["ack_p99_ms"]
        # CPU times come from /proc in clock ticks (10 ms): 20 quick 40×40 edits may read 0.
        assert r["client_cores"] >= 0 and r["server_cpu_ms_per_edit"] >= 0
    (run,) = rep["python_runs"]
    assert run["client"] == "python" and run["edits"] == 20 and "samples_ms" not in run
    assert run["p50_ms"] == rows["python client, round 1"]["p50_ms"]
    b = run["breakdown"]
    assert b["apply_p50_ms"] > 0 and 0 < b["to_apply_p50_ms"] <= run["max_ms"]


def test_bench_server_python_client_refuses_a_missing_driver(resecta, tmp_path):
    r = resecta("bench", "server", "--client", "python", "--quick",
                "--python-driver", tmp_path / "absent.py", check=False)
    assert r.code == 2 and "driver" in r.stderr

def test_bench_server_runs_only_the_scenarios_asked_for(resecta):
    rep = resecta("bench", "server", "--quick", "--json", "--scenarios", "upload").json()
    assert rep["latencies"] == [] and rep["idle_session_bytes"] is None
    assert rep["concurrent_p99_ratio"] is None
    assert rep["upload"]["bytes"] == 512 * 512 * 300
    assert rep["ready"] is None and rep["restart"] is None


def test_bench_server_compare_gpu_runs_the_latency_on_both_backends():
    """`--compare-gpu` under `WGPU_BACKEND=vulkan` (lavapipe in CI): one session editing back to
    back at 40×40, 200×200 and 500×500 on a `--gpu off` server, then on a `--gpu required` one,
    each with the compute backend its server reported; a machine without a Vulkan adapter skips,
    unless it asked for one."""
    env = {**os.environ, "WGPU_BACKEND": "vulkan"}
    proc = subprocess.run([resecta_bin(), "bench", "server", "--compare-gpu", "--quick", "--json",
                           "--edits", "4"], capture_output=True, text=True, timeout=600, env=env)
    if proc.returncode != 0 and "--gpu required" in proc.stderr and not os.environ.get("WGPU_BACKEND"):
        pytest.skip(f"SKIP: no Vulkan adapter ({proc.stderr.strip()[-300:]}); "
                    "install lavapipe (mesa-vulkan-drivers)")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["edits"] == 4 and rep["budget_s"] == 1.0 and rep["quick"] is True
    off, gpu = rep["backends"]
    assert off["gpu"] == "off" and off["compute"] == {"backend": "cpu", "adapter": "", "f64": True}
    assert gpu["gpu"] == "required" and gpu["compute"]["backend"] == "wgpu", gpu["compute"]
    assert gpu["compute"]["adapter"]
    if "llvmpipe" in gpu["compute"]["adapter"]:
        assert gpu["compute"]["f64"] is True  # lavapipe grants SHADER_F64
    for b in (off, gpu):
        assert [(r["scenario"], r["resolution"], r["sessions"]) for r in b["latencies"]] == [
            ("single session", [n, n], 1) for n in (40, 200, 500)]
        for r in b["latencies"]:
            assert 3 <= r["edits"] <= 4 and 0 < r["p50_ms"] <= r["p99_ms"] <= r["max_ms"]
            # The server's CPU time comes in clock ticks (10 ms): 4 quick 40×40 edits may read 0.
            assert r["server_cpu_ms_per_edit"] >= 0 and r["ack_p50_ms"] > 0
        assert b["latencies"][-1]["server_cpu_ms_per_edit"] > 0  # 500×500: tens of ms an edit
        # The capacity ramp: 1, then 2 sessions (quick) at 30 edits/s while p99 ≤ 5 ms.
        cap = b["capacity"]
        assert cap["rate_per_s"] == 30 and cap["p99_bound_ms"] == 5
        steps = cap["steps"]
        assert 1 <= len(steps) <= 2 and [s["sessions"] for s in steps] == [1, 2][:len(steps)]
        within = [s["sessions"] for s in steps if s["p99_ms"] <= 5]
        assert cap["sessions"] == (within[-1] if within and within == [1, 2][:len(within)] else 0)
        assert all(s["edits"] >= 25 * s["sessions"] for s in steps)
    assert [r["resolution"] for r in rep["cpu_over_gpu"]] == [[n, n] for n in (40, 200, 500)]
    for r, c, g in zip(rep["cpu_over_gpu"], off["latencies"], gpu["latencies"]):
        assert math.isclose(r["delta_p50"], c["p50_ms"] / g["p50_ms"])
        assert math.isclose(r["server_cpu_ms_per_edit"],
                            c["server_cpu_ms_per_edit"] / g["server_cpu_ms_per_edit"])


def test_bench_server_compare_gpu_starts_its_own_servers(resecta):
    r = resecta("bench", "server", "--compare-gpu", "--addr", "http://127.0.0.1:1", check=False)
    assert r.code == 2 and "--addr" in r.stderr
