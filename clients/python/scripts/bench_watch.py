"""Edit → delta latency at a watching Python client, on the Slicer module's path.

`resecta bench server --client python` runs this against a session it prepared (a resection
planned on its patient); it can also be run by hand against any server and session:

    python clients/python/scripts/bench_watch.py --addr 127.0.0.1:50051 --session ID \
        --resection r1 --rate 30 --edits 300

What it does is what the Slicer module (slicer-module/Resecta/ResectaLib) does during a drag:
a worker thread sends `Session.set_control_point(..., base_version=0)` edits, one in flight
(the module's dispatcher worker and coalescer), while a watch thread iterates
`Session.watch()`, which decodes every delta and writes its rows into the `LiveScene`'s arrays
(`resecta_client.scene`). The main thread paces the drag: control point (i, j) moves along the
grid's normal, `amplitude` mm, one period per second. Per edit it records the time from the
edit sent to its delta applied to the arrays (the watch iterator yielding the update of that plan
version, or a later one), and, apart, the acknowledgement and how long `LiveScene.apply` took.

It prints one JSON object on stdout: percentiles (ms), the per-edit samples, client CPU (cores
and ms per edit, from `time.process_time`), and the breakdown. The client imported is the one
in this checkout (``../src``), not an installed one.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import numpy as np  # noqa: E402

import resecta_client as rc  # noqa: E402
from resecta_client import scene as scene_mod  # noqa: E402


def percentiles(values: list[float]) -> dict[str, float]:
    """p50/p90/p99/max with the Rust bench's rank rule (round(q·(n − 1)))."""
    if not values:
        return {"p50_ms": math.nan, "p90_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}
    s = sorted(values)

    def q(p: float) -> float:
        return s[min(len(s) - 1, round(p * (len(s) - 1)))]

    return {"p50_ms": q(0.50), "p90_ms": q(0.90), "p99_ms": q(0.99), "max_ms": s[-1]}


def grid_normal(cp: np.ndarray) -> np.ndarray:
    """Unit normal of an (m, n, 3) control grid (u × v of its mean edges), as the module's."""
    du = cp[-1, :, :].mean(axis=0) - cp[0, :, :].mean(axis=0)
    dv = cp[:, -1, :].mean(axis=0) - cp[:, 0, :].mean(axis=0)
    n = np.cross(du, dv)
    return n / np.linalg.norm(n)


class ApplyTimer:
    """Times `LiveScene.apply` (decode + write into the arrays) per event, by plan version."""

    def __init__(self) -> None:
        self.by_version: dict[int, tuple[float, float]] = {}
        self._orig = scene_mod.LiveScene.apply

    def install(self) -> None:
        orig, by_version = self._orig, self.by_version

        def timed(live, msg):  # type: ignore[no-untyped-def]
            t0 = time.perf_counter()
            out = orig(live, msg)
            t1 = time.perf_counter()
            if msg.WhichOneof("event") == "delta":
                by_version.setdefault(msg.plan_version, (t0, t1))
            return out

        scene_mod.LiveScene.apply = timed  # type: ignore[method-assign]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--addr", required=True, help="gRPC address, HOST:PORT")
    ap.add_argument("--token", default=os.environ.get("RESECTA_TOKEN"))
    ap.add_argument("--session", required=True)
    ap.add_argument("--resection", required=True)
    ap.add_argument("--i", type=int, default=1)
    ap.add_argument("--j", type=int, default=1)
    ap.add_argument("--rate", type=float, default=30.0, help="edits per second")
    ap.add_argument("--edits", type=int, default=300)
    ap.add_argument("--warmup", type=int, default=15)
    ap.add_argument("--amplitude", type=float, default=5.0, help="mm along the grid normal")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for one delta")
    ap.add_argument(
        "--no-breakdown", action="store_true", help="do not time LiveScene.apply (no wrapper)"
    )
    args = ap.parse_args()

    timer = ApplyTimer()
    if not args.no_breakdown:
        timer.install()

    client = rc.Client(args.addr, args.token, timeout=60)
    sess = client.session(args.session)
    watch = sess.watch()
    applied: dict[int, float] = {}  # plan version → delta applied (perf_counter)
    cond = threading.Condition()
    failure: list[BaseException] = []

    first = next(watch)  # the snapshot
    if first.kind != "snapshot":
        raise SystemExit("the watch stream did not start with a snapshot")
    with watch.scene.lock:
        surface = watch.scene.surfaces.get(args.resection)
        if surface is None or surface.resection is None:
            raise SystemExit(f"no resection {args.resection!r} in the session")
        cp = np.asarray(surface.resection.control_points, float)
        vertices = len(surface.positions)
    normal = grid_normal(cp)
    p0 = cp[args.i, args.j].copy()

    def watch_loop() -> None:
        try:
            for update in watch:
                t = time.perf_counter()
                if update.kind == "delta":
                    with cond:
                        applied.setdefault(update.plan_version, t)
                        cond.notify_all()
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            failure.append(exc)
            with cond:
                cond.notify_all()

    watcher = threading.Thread(target=watch_loop, name="resecta-watch", daemon=True)
    watcher.start()

    # The module's worker: one edit call at a time (dispatcher with one worker).
    worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="resecta")

    def send(k: int) -> tuple[float, float, int]:
        p = p0 + normal * (args.amplitude * math.sin(2 * math.pi * k / max(args.rate, 1.0)))
        t0 = time.perf_counter()
        r = sess.set_control_point(args.resection, args.i, args.j, tuple(p), base_version=0)
        return t0, time.perf_counter(), r.plan_version

    def wait_applied(version: int) -> float:
        """The first time a delta of `version` or later was applied."""
        end = time.monotonic() + args.timeout
        with cond:
            while True:
                hits = [t for v, t in applied.items() if v >= version]
                if hits:
                    return min(hits)
                if failure:
                    raise failure[0]
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no delta of plan version {version} in {args.timeout} s")
                cond.wait(left)

    period = 1.0 / max(args.rate, 0.1)
    total = args.warmup + args.edits
    rows = []
    cpu0 = wall0 = 0.0
    start = time.perf_counter()
    for k in range(total):
        if k == args.warmup:
            cpu0, wall0 = time.process_time(), time.perf_counter()
        # Paced like the Rust bench (tokio interval, missed ticks delayed).
        target = start + k * period
        now = time.perf_counter()
        if target > now:
            time.sleep(target - now)
        else:
            start += now - target
        t0, t_ack, version = worker.submit(send, k).result()
        t_applied = wait_applied(version)
        if k >= args.warmup:
            rows.append((t0, t_ack, version, t_applied))
    cpu = time.process_time() - cpu0
    wall = time.perf_counter() - wall0
    watch.stop()
    worker.shutdown()
    client.close()

    delta_ms = [(ta - t0) * 1e3 for t0, _, _, ta in rows]
    ack_ms = [(tk - t0) * 1e3 for t0, tk, _, _ in rows]
    out = {
        "client": "python",
        "python": sys.version.split()[0],
        "grpcio": __import__("grpc").__version__,
        "numpy": np.__version__,
        "rate": args.rate,
        "edits": len(rows),
        "resection_vertices": vertices,
        **percentiles(delta_ms),
        "ack_p50_ms": percentiles(ack_ms)["p50_ms"],
        "ack_p99_ms": percentiles(ack_ms)["p99_ms"],
        "client_cores": cpu / wall if wall > 0 else math.nan,
        "client_cpu_ms_per_edit": cpu * 1e3 / max(len(rows), 1),
        "samples_ms": delta_ms,
        "ack_samples_ms": ack_ms,
    }
    if not args.no_breakdown:
        # Edit sent → the delta's message handed to `LiveScene.apply` (server, transport, gRPC's
        # threads), and the apply itself (decode + write into the arrays).
        recv, apply = [], []
        for t0, _, version, _ in rows:
            hit = timer.by_version.get(version)
            if hit is not None:
                recv.append((hit[0] - t0) * 1e3)
                apply.append((hit[1] - hit[0]) * 1e3)
        out["breakdown"] = {
            "to_apply_" + k: v for k, v in percentiles(recv).items()
        } | {"apply_" + k: v for k, v in percentiles(apply).items()}
    json.dump(out, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
