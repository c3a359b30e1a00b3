"""Helpers of the recording tests: messages of every type, wire equality, climbd processes."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from climbd.daemon.contract import messages as m

ROOT = Path(__file__).resolve().parents[2]


def one_of_each(n: int) -> list[m.Message]:
    """One message of every type with content that differs by ``n`` (NaN and bytes included);
    types added to the contract later get their defaults with ``stamp = n``."""
    grid = np.array([0.1 * n, np.nan, 0.2, 0.3], dtype="<f4").tobytes()
    joist = m.Joist(distance=1.0 + n, yaw=0.26, height=0.1, endpoints=[[1, 0, 0], [1, 1, 0]])
    chosen = [
        m.JointState(stamp=n, names=["a", "b"], position=[0.1 * n, -0.2], velocity=[0, 0]),
        m.JointCommand(stamp=n, position=[0.3, n], kp=[60.0, 60.0]),
        m.Health(
            stamp=n,
            mode=m.Mode.HOLD,
            joints=[m.JointHealth(name="a"), m.JointHealth(name="b", temperature=40.0 + n)],
            loop=m.LoopStats(rate_hz=100.0, ticks=100 * n),
            session="op",
        ),
        m.BodyState(stamp=n, position=[n, 0.0, 0.1], stance=[True, False]),
        m.FootTargets(stamp=n, positions=[[0.1, 0.2, -0.1]], stance=[True], grip=[False]),
        m.MotionCommand(stamp=n, session="s", vx=0.05 * n, body_height=None),
        m.ModeState(stamp=n, mode=m.Mode.ACTIVE, reason=f"step {n}"),
        m.ModeRequest(stamp=n, session="s", mode=m.Mode.STAND),
        m.EStop(stamp=n, source="test", reason=f"r{n}"),
        m.SessionClaim(stamp=n, session="s", client="c"),
        m.Heartbeat(stamp=n, session="s", seq=n),
        m.ElevationGrid(stamp=n, rows=2, cols=2, heights=grid),
        m.Joists(stamp=n, frame_stamp=n, joists=[joist]),
        m.GraspablePoints(stamp=n, points=[[0.1, 0.2, n]]),
        m.TrussMembers(
            stamp=n,
            members=[m.TrussMember(p0=[0, 0, 0], p1=[n, 0, 1], radius=0.02, axis=[0, 0, 1])],
        ),
        m.Stairs(stamp=n, steps=[m.Stair(height=0.15, rise=0.15, depth=0.3, edge=[[0, 0, 0]])]),
    ]
    covered = {type(x) for x in chosen}
    return chosen + [t(stamp=n) for t in m.ALL_MESSAGES if t not in covered]


def same(a: m.Message, b: m.Message) -> bool:
    """Equal as received on the wire (ints in float fields become floats), NaN equal to NaN."""

    def wire(x: m.Message) -> bytes:
        return m.encode(m.decode(m.encode(x), type(x)))

    return wire(a) == wire(b)


def climbd(*args: str, **kw) -> subprocess.Popen:
    """A ``climbd`` command in a process of its own, stdout and stderr piped as text."""
    return subprocess.Popen(
        [sys.executable, "-m", "climbd.daemon.cli", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def wait_line(proc: subprocess.Popen, text: str, timeout: float = 30.0) -> None:
    """Read the process's stdout until a line contains ``text``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"{text!r} not printed; stderr: {proc.stderr.read()}")
