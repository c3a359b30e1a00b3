"""The thread that puts the torque-leg driver's frames on its CAN channels.

A 1 kHz tick writes 18 frames, one syscall each (SocketCAN, or ``udp_can`` in the twin); on
the tick's own thread those take a third of its budget. The tick hands its frames to this
thread and goes on; the sends then overlap the loop's sleep, and each syscall leaves the GIL
to the tick. One batch is on its way at a time: a tick whose last frames have not all gone
out waits for them, so an overrunning loop (which never sleeps) still gets every command out.
"""

from __future__ import annotations

import threading
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
        self._pending: list[Batch] | None = None
        self._busy = False
        self._failure: DriverError | None = None
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, batches: list[Batch], timeout: float) -> None:
        """Queue ``batches`` once the frames before them went out (waiting up to ``timeout``)."""
        with self._wake:
            self._wait_idle(timeout)
            self._pending = batches
            self._wake.notify_all()

    def flush(self, timeout: float) -> None:
        """Wait until every queued frame went out."""
        with self._wake:
            self._wait_idle(timeout)

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

    def _wait_idle(self, timeout: float) -> None:
        """Wait for the sends before to end; raise their failure, or a timeout."""
        idle = self._wake.wait_for(
            lambda: self._failure is not None or not (self._pending or self._busy), timeout
        )
        self.raise_failure()
        if not idle:
            raise DriverError(f"CAN send: frames still queued after {timeout * 1e3:.0f} ms")

    def _run(self) -> None:
        while True:
            with self._wake:
                self._busy = False
                self._wake.notify_all()
                self._wake.wait_for(lambda: self._pending or self._stopping)
                if not self._pending:
                    return
                batches, self._pending = self._pending, None
                self._busy = True
            for batch in batches:
                try:
                    batch.link.send(batch.ids, batch.payloads)
                except can.CanError as e:
                    with self._wake:
                        self._failure = self._failure or DriverError(
                            f"CAN send on {batch.link.channel}: {e}"
                        )
