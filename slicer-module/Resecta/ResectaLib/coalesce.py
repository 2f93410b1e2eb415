"""Coalescing of control-point edits while a point is dragged.

A drag fires many position changes per second; the server answers each edit in about a
millisecond plus the round trip, but a remote server or a big grid may take longer. The coalescer
keeps at most one edit in flight: while one is on its way, further positions are parked, one per
key (a control point), replacing each other; when the edit in flight returns, the parked positions
are sent, oldest key first, one at a time. So the server sees every point's latest position and
never a backlog. `push` and `done` are called on the main thread; `send` must start the edit and
arrange for `done` to be called when it returns (successfully or not).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable, Hashable


class EditCoalescer:
    def __init__(self, send: Callable[[Hashable, object], None]):
        self._send = send
        self._pending: OrderedDict[Hashable, object] = OrderedDict()
        self._in_flight: Hashable | None = None
        self._busy = False
        #: counters, for tests and the status line
        self.pushed = 0
        self.sent = 0
        self.dropped = 0

    @property
    def busy(self) -> bool:
        return self._busy

    @property
    def in_flight(self) -> Hashable | None:
        """The key of the value on its way, or None."""
        return self._in_flight

    @property
    def pending(self) -> dict:
        return dict(self._pending)

    def push(self, key: Hashable, value: object) -> None:
        """A new value for `key`: sent now when idle, else parked (replacing a parked one)."""
        self.pushed += 1
        if not self._busy:
            self._start(key, value)
            return
        if key in self._pending:
            self.dropped += 1
            self._pending[key] = value  # keeps its place in the queue, newest value
        else:
            self._pending[key] = value

    def done(self) -> None:
        """The edit in flight returned: send the next parked value, if any."""
        self._busy = False
        self._in_flight = None
        if self._pending:
            key, value = self._pending.popitem(last=False)
            self._start(key, value)

    def clear(self) -> None:
        """Forget parked values (e.g. the resection was deleted, undo was pressed)."""
        self.dropped += len(self._pending)
        self._pending.clear()

    def _start(self, key: Hashable, value: object) -> None:
        self._busy = True
        self._in_flight = key
        self.sent += 1
        self._send(key, value)
