"""`resecta bench server --quick`: the load benchmark starts a server, runs every scenario and
reports one JSON object (figures of a debug build and a quick run mean nothing; the shape does)."""
import math


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
