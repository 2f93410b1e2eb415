"""Resident memory of `resecta serve --demo` under the heavy plan of #19 (N resections at R×R,
imported at once) and W watchers asking for snapshots over HTTP, for one memory budget.

Usage: RESECTA_BIN=target/debug/resecta python scripts/memory_budget.py BUDGET_MIB N R W
Prints one JSON object: the import's answer, how many watchers were refused, RSS before the
import, after, and at its peak (VmHWM)."""
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

MIB = 1 << 20


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    budget_mib, n, res, watchers = (int(a) for a in sys.argv[1:5])
    cfg = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
    cfg.write(f"[limits]\nmax_memory_bytes = {budget_mib * MIB}\n")
    cfg.close()
    http = free_port()
    proc = subprocess.Popen([os.environ["RESECTA_BIN"], "serve", "--demo", "--config", cfg.name,
                             "--http", f"127.0.0.1:{http}", "--grpc", f"127.0.0.1:{free_port()}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{http}"

    def call(method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(base + path, method=method, data=data,
                                     headers={"content-type": "application/json"})
        try:
            with urllib.request.urlopen(req, timeout=600) as r:
                return r.status, json.loads(r.read() or b"{}")
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read() or b"{}")

    def status(key):
        with open(f"/proc/{proc.pid}/status") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith(key + ":"))

    try:
        sid = None
        for _ in range(600):
            try:
                _, b = call("GET", "/v1/sessions")
                if b.get("sessions") and b["sessions"][0].get("labelMap"):
                    sid = b["sessions"][0]["id"]
                    break
            except OSError:
                pass
            time.sleep(0.2)
        init = {"initFromEndPoint": {"name": "r0", "endPoint": {"x": -60, "y": 0, "z": 0}}}
        s, e = call("POST", f"/v1/sessions/{sid}/edits", init)
        assert s == 200, e
        plan = json.loads(call("GET", f"/v1/sessions/{sid}/plan")[1]["planJson"])
        one = plan["resections"][0]
        plan["resections"] = [dict(one, name=f"h{k}", resolution=[res, res]) for k in range(n)]
        before = status("VmRSS")
        t = time.monotonic()
        s, b = call("PUT", f"/v1/sessions/{sid}/plan", {"planJson": json.dumps(plan)})
        imported = {"status": s, "s": round(time.monotonic() - t, 2), "code": b.get("code")}
        answers = []

        def watch():
            req = urllib.request.Request(base + f"/v1/sessions/{sid}/watch")
            try:
                with urllib.request.urlopen(req, timeout=600) as r:
                    r.read(1 << 16)
                    answers.append(r.status)
                    time.sleep(5)
            except urllib.error.HTTPError as e:
                answers.append(e.code)

        threads = [threading.Thread(target=watch) for _ in range(watchers)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        print(json.dumps({"budget_mib": budget_mib, "resections": n, "resolution": res,
                          "watchers": watchers, "import": imported,
                          "watchers_refused": sum(a != 200 for a in answers),
                          "rss_before_mib": before // MIB, "rss_mib": status("VmRSS") // MIB,
                          "peak_rss_mib": status("VmHWM") // MIB}))
    finally:
        proc.terminate()
        proc.wait()
        os.unlink(cfg.name)


if __name__ == "__main__":
    main()
