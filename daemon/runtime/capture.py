"""Capture: runs a Camera in a background thread and keeps only its newest frame.

Perception takes ``latest()`` when it is ready; frames it had no time for are dropped (newest
wins) and counted, so a slow consumer never backs up the camera and the drop count reaches the
health topic.
"""

from __future__ import annotations

import logging
import threading

import msgspec

from climbd.daemon.contract.hardware import Camera, DepthFrame, ReportsCameraHealth
from climbd.daemon.contract.messages import Health

log = logging.getLogger("climbd.capture")


class Capture:
    """A camera's frames on a thread: ``latest()`` hands out each new frame once."""

    def __init__(self, camera: Camera, name: str = "depth") -> None:
        self.camera = camera
        self.name = name
        self._reports_health = isinstance(camera, ReportsCameraHealth)
        self.received = 0
        self.delivered = 0
        self.dropped = 0
        self.error = ""
        self._slot: DepthFrame | None = None
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._running = False

    def start(self) -> None:
        """Open the camera (errors surface here, in the caller) and start the capture thread."""
        self.camera.open()
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"capture-{self.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for frame in self.camera.frames():
                with self._cond:
                    if self._slot is not None:
                        self.dropped += 1
                    self._slot = frame
                    self.received += 1
                    self._cond.notify_all()
                if not self._running:
                    break
        except Exception as e:
            self.error = f"{type(e).__name__}: {e}"
            log.error("capture %s stopped: %s", self.name, self.error)
        finally:
            with self._cond:
                self._running = False
                self._cond.notify_all()

    def latest(self, timeout: float | None = None) -> DepthFrame | None:
        """The newest frame not yet handed out, waiting up to ``timeout`` s; None if none came."""
        with self._cond:
            self._cond.wait_for(lambda: self._slot is not None or not self._running, timeout)
            frame, self._slot = self._slot, None
            if frame is not None:
                self.delivered += 1
            return frame

    @property
    def running(self) -> bool:
        """True while the camera thread runs (False after stop, end of a recording or an error)."""
        return self._running

    def stop(self) -> None:
        """Stop the thread and close the camera."""
        self._running = False
        self.camera.close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def report(self, health: Health) -> Health:
        """``health`` with this capture's drops added and its camera problem named, if any."""
        messages = list(health.messages)
        status = self.camera.health() if self._reports_health else None
        if status is not None and not status.connected and status.last_error:
            messages.append(f"camera {self.name}: {status.last_error}")
        if self.error:
            messages.append(f"camera {self.name}: {self.error}")
        drops = self.dropped + (status.dropped if status is not None else 0)
        return msgspec.structs.replace(
            health, dropped_frames=health.dropped_frames + drops, messages=messages
        )
