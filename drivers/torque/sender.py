"""The thread that puts the torque-leg driver's frames on its CAN channels.

A 1 kHz tick writes 18 frames, one syscall each (SocketCAN, or ``udp_can`` in the twin); on
the tick's own thread those take a third of its budget. The tick hands its frames to this
thread and goes on; the sends then overlap the loop's sleep, and each syscall leaves the GIL
to the tick. A command batch (every joint's whole MIT command) not yet begun when the next
arrives is replaced by it: the motors need only the newest.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import can

from drivers.base import DriverError
from drivers.torque.links import FrameLink


class Batch(NamedTuple):
    """Frames for one channel: the motor ids and their payloads, in order."""

    link: FrameLink
    ids: Sequence[int]
    payloads: Sequence[bytes]


class FrameSender:
    """Sends batches of frames in order from one thread; a send's failure is raised, once, by
    the driver's next call, so the error path (torque off) can still send."""

    def __init__(self, name: str = "climbd-can-send") -> None:
        self._wake = threading.Condition()
        self._queue: deque[tuple[list[Batch], bool]] = deque()
        self._busy = False
        self._failure: DriverError | None = None
        self._stopping = False
        self.replaced = 0
        """Command batches replaced by a newer one before any of their frames went out."""
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, batches: list[Batch], command: bool) -> int:
        """Queue ``batches``; a ``command`` replaces a queued command not yet begun. Returns
        the number of frames that replacement dropped (0 if none)."""
        with self._wake:
            self.raise_failure()
            dropped = 0
            if command and self._queue and self._queue[-1][1]:
                dropped = sum(len(b.ids) for b in self._queue.pop()[0])
                self.replaced += 1
            self._queue.append((batches, command))
            self._wake.notify_all()
        return dropped

    def flush(self, timeout: float) -> None:
        """Wait until every queued frame went out; raise its failure, or a timeout naming the
        frames still queued."""
        with self._wake:
            idle = self._wake.wait_for(
                lambda: self._failure is not None or not (self._queue or self._busy), timeout
            )
            self.raise_failure()
            if not idle:
                raise DriverError(f"CAN send: frames still queued after {timeout * 1e3:.0f} ms")

    def raise_failure(self) -> None:
        """Raise (and clear) the failure of an earlier send, if any."""
        with self._wake:
            failure, self._failure = self._failure, None
        if failure is not None:
            raise failure

    def close(self, timeout: float = 1.0) -> None:
        """Send what is queued, then stop the thread."""
        with self._wake:
            self._stopping = True
            self._wake.notify_all()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._wake:
                self._busy = False
                self._wake.notify_all()
                self._wake.wait_for(lambda: self._queue or self._stopping)
                if not self._queue:
                    return
                batches, _ = self._queue.popleft()
                self._busy = True
            for batch in batches:
                try:
                    batch.link.send(batch.ids, batch.payloads)
                except can.CanError as e:
                    with self._wake:
                        self._failure = self._failure or DriverError(
                            f"CAN send on {batch.link.channel}: {e}"
                        )
