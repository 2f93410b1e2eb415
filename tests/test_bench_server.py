"""`resecta bench server --quick`: the load benchmark starts a server, runs every scenario and
reports one JSON object (figures of a debug build and a quick run mean nothing; the shape does)."""
import math
import sys
from pathlib import Path


def test_bench_server_quick_smoke(resecta, tmp_path):
    rep = resecta("bench", "server", "--quick", "--json", "--sessions", "3", "--idle-sessions", "1",
                  "--plot-dir", tmp_path).json()
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
        assert r["client_cores"] > 0 and r["server_cpu_ms_per_edit"] > 0
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
