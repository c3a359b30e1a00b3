"""systemd readiness and watchdog over the ``NOTIFY_SOCKET`` datagram protocol (no libsystemd).

``READY=1`` once the control loop ticks, ``WATCHDOG=1`` only while it keeps ticking, so a
hung loop is restarted by systemd (WatchdogSec) rather than kept alive by a healthy thread.
"""

from __future__ import annotations

import os
import socket


def _address() -> str | None:
    path = os.environ.get("NOTIFY_SOCKET")
    if not path:
        return None
    return "\0" + path[1:] if path.startswith("@") else path


def notify(state: str) -> bool:
    """Send ``state`` (e.g. ``READY=1``) to systemd; False when not run under systemd."""
    address = _address()
    if address is None:
        return False
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
        sock.connect(address)
        sock.sendall(state.encode())
    return True


def watchdog_period() -> float | None:
    """Half of systemd's WatchdogSec for this process (s), or None when no watchdog is set."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if not usec or (pid and int(pid) != os.getpid()):
        return None
    return int(usec) / 2e6
