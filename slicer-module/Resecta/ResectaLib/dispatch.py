"""How work leaves the main thread and how its results come back to it.

Scene (MRML) and GUI objects may only be touched on the main thread, and network calls must never
run there (the GUI would freeze). `ThreadDispatcher` runs calls on worker threads and queues their
results; whoever owns the main thread calls `poll()` to deliver them: in Slicer a `qt.QTimer`
(every 20 ms), in tests a wait loop (`wait_until`). `SyncDispatcher` runs everything inline, for
scripts and simple tests. Both offer the same three methods.
"""

from __future__ import annotations

import concurrent.futures
import queue
import threading
import time
from typing import Any, Callable

Callback = Callable[[Any], None]


class SyncDispatcher:
    """Runs the call at once on the calling thread and delivers the result at once."""

    def submit(self, fn: Callable[[], Any], on_done: Callback | None = None,
               on_error: Callback | None = None) -> None:
        try:
            result = fn()
        except Exception as exc:  # noqa: BLE001 - handed to the caller's error callback
            if on_error is None:
                raise
            on_error(exc)
            return
        if on_done is not None:
            on_done(result)

    def call_soon(self, fn: Callable[[], None]) -> None:
        fn()

    def start_thread(self, target: Callable[[], None], name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread

    def poll(self, max_items: int = 1000) -> int:
        return 0

    def shutdown(self) -> None:
        pass


class ThreadDispatcher:
    """Worker threads for calls; a queue of callbacks for the main thread.

    `workers` calls run at once (calls of one session are ordered by the server anyway; the
    Logic uses separate dispatchers or the coalescer where order matters). `call_soon` may be
    used from any thread (e.g. the watch thread) to run something on the main thread."""

    def __init__(self, workers: int = 1):
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=workers,
                                                           thread_name_prefix="resecta")
        self._queue: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._main = threading.get_ident()
        self.errors: list[BaseException] = []

    def submit(self, fn: Callable[[], Any], on_done: Callback | None = None,
               on_error: Callback | None = None) -> concurrent.futures.Future:
        def run():
            try:
                result = fn()
            except BaseException as exc:  # noqa: BLE001 - delivered on the main thread
                self._queue.put(lambda exc=exc: self._deliver_error(exc, on_error))
                return None
            if on_done is not None:
                self._queue.put(lambda: on_done(result))
            return result
        return self._pool.submit(run)

    def _deliver_error(self, exc: BaseException, on_error: Callback | None) -> None:
        if on_error is None:
            self.errors.append(exc)
        else:
            on_error(exc)

    def call_soon(self, fn: Callable[[], None]) -> None:
        self._queue.put(fn)

    def start_thread(self, target: Callable[[], None], name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread

    def poll(self, max_items: int = 1000) -> int:
        """Runs queued main-thread callbacks (at most `max_items`); returns how many ran."""
        ran = 0
        while ran < max_items:
            try:
                fn = self._queue.get_nowait()
            except queue.Empty:
                break
            fn()
            ran += 1
        return ran

    def wait_until(self, predicate: Callable[[], Any], timeout: float = 60.0,
                   every: float = 0.005) -> Any:
        """Polls until `predicate()` is truthy (tests and the self-test); raises TimeoutError."""
        end = time.monotonic() + timeout
        while True:
            self.poll()
            value = predicate()
            if value:
                return value
            if time.monotonic() > end:
                raise TimeoutError("condition not met in time")
            time.sleep(every)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
