"""Helpers of the multi-process tests: climbd processes and an observer on real Zenoh sessions."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from climbd.daemon.contract.messages import Health, Heartbeat, Message, ModeState
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

ROOT = Path(__file__).resolve().parents[2]


class Proc:
    """A ``climbd`` subprocess with its stdout and stderr collected line by line."""

    def __init__(
        self, *args: str, prefix: tuple[str, ...] = (), env: dict[str, str] | None = None
    ) -> None:
        self.proc = subprocess.Popen(
            [*prefix, sys.executable, "-m", "climbd.daemon.cli", *args],
            cwd=ROOT,
            env={**os.environ, **env} if env else None,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.log: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.log.append(line)

    @property
    def text(self) -> str:
        return "".join(self.log)

    def wait_for(self, pattern: str, timeout: float = 60.0, count: int = 1) -> list[re.Match]:
        """The first ``count`` matches of regex ``pattern`` in the log, waiting for them."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            found = [m for line in list(self.log) if (m := re.search(pattern, line))]
            if len(found) >= count:
                return found
            if self.proc.poll() is not None:
                time.sleep(0.2)
                found = [m for line in list(self.log) if (m := re.search(pattern, line))]
                if len(found) >= count:
                    return found
                break
            time.sleep(0.05)
        raise AssertionError(f"{pattern!r} ×{count} not logged; log:\n{self.text}")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(5)
        return self.proc.returncode

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class Observer:
    """A test-side Zenoh session that records a robot's messages with their arrival times."""

    def __init__(self, robot: str, connect: list[str]) -> None:
        from conftest import free_port

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        """Where clients dial the observer too: peers do not route between other peers."""
        self.bus = Network(robot, zenoh_config(None, "test", Endpoints([self.endpoint], connect)))
        self.robot = robot
        self.seen: dict[type, list[tuple[float, Message]]] = {}
        self._lock = threading.Lock()
        for t in (ModeState, Health, Heartbeat):
            self.watch(t)

    def watch(self, message: type[Message]) -> None:
        self.seen.setdefault(message, [])

        def record(m: Message) -> None:
            with self._lock:
                self.seen[message].append((time.monotonic(), m))

        self.bus.subscribe(message, record)

    def messages(self, message: type[Message]) -> list[Message]:
        with self._lock:
            return [m for _, m in self.seen[message]]

    def wait(
        self, message: type[Message], pred: Callable[[Message], bool], timeout: float = 30.0
    ) -> Message:
        """The first recorded ``message`` satisfying ``pred``, waiting up to ``timeout`` s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for m in self.messages(message):
                if pred(m):
                    return m
            time.sleep(0.02)
        last = self.messages(message)[-3:]
        raise AssertionError(f"no {message.__name__} matching within {timeout} s; last: {last}")

    def health(self, role: str = "control") -> Health:
        return self.wait(Health, lambda h: h.role == role)

    def latest_health(self, role: str = "control", after: float = 0.0) -> Health:
        """The newest Health of ``role`` whose stamp is later than ``after``, waiting for one."""
        end = time.monotonic() + 10.0
        while time.monotonic() < end:
            found = [h for h in self.messages(Health) if h.role == role and h.stamp > after]
            if found:
                return found[-1]
            time.sleep(0.05)
        raise AssertionError(f"no {role} health after {after}")

    def close(self) -> None:
        self.bus.close()
