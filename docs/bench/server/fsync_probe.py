"""The disk's fdatasync latency, back to back and with the gaps of paced edits (1.6 ms: 20 sessions
at 30 edits/s; 33 ms: one session), on a preallocated file in the current folder: what an edit's
acknowledgement waits for. Usage: python3 docs/bench/server/fsync_probe.py [N]"""
import os
import sys
import time

n = int(sys.argv[1]) if len(sys.argv) > 1 else 400
path = "fsync_probe.bin"
fd = os.open(path, os.O_RDWR | os.O_CREAT)
try:
    os.ftruncate(fd, 1 << 20)
    os.fsync(fd)
    for gap in (0.0, 0.0016, 0.033):
        ts = []
        for i in range(n):
            os.pwrite(fd, b"x" * 400, (i * 512) % (1 << 20))
            t = time.perf_counter()
            os.fdatasync(fd)
            ts.append((time.perf_counter() - t) * 1e3)
            if gap:
                time.sleep(gap)
        ts.sort()
        q = lambda p: ts[min(len(ts) - 1, round(p * (len(ts) - 1)))]
        print(f"gap {gap * 1e3:5.1f} ms: p50 {q(0.5):.3f}  p90 {q(0.9):.3f}  p99 {q(0.99):.3f}  max {ts[-1]:.3f} ms")
finally:
    os.close(fd)
    os.remove(path)
