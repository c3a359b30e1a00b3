"""Counting what happens: decode errors and refused commands by topic in the control role's
Health, and the commands and foot targets it sends published on state/command and state/feet.

One control role (fake driver, tripod gait) serves the multi-process tests; each compares
Health before and after its burst, so they do not depend on one another's counts.
"""

from __future__ import annotations

import os
import threading
import time
import uuid
from collections.abc import Iterator

import msgspec
import numpy as np
import pytest
import zenoh
from conftest import free_port, lossless
from support.fuzzing import DECODE_ERRORS
from support.zenoh_roles import Observer, Proc

from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.runtime.counting import OTHER, Tally
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.network import Endpoints, zenoh_config
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.fake import FakeJointBus

ROBOT = "widowx"
GARBAGE_TOPICS: tuple[type[m.Message], ...] = (
    m.MotionCommand,
    m.ModeRequest,
    m.SessionClaim,
    m.Heartbeat,
    m.ElevationGrid,
)
"""Subscribed topics the garbage goes to (not cmd/estop: nothing there may look like one)."""


def garbage(message: type[m.Message], count: int) -> list[bytes]:
    """``count`` payloads ``message``'s decoder refuses: random bytes, wrong types, unknown
    fields, truncated msgpack and another schema version, in turn."""
    valid = m.encode(message(stamp=1.0))
    kinds = (
        lambda k: b"\xc1" + os.urandom(1 + k % 31),  # 0xc1 is never valid msgpack
        lambda k: msgspec.msgpack.encode({"schema": "one", "stamp": k}),
        lambda k: msgspec.msgpack.encode({"stamp": float(k), "bogus": k}),
        lambda k: valid[: max(1, len(valid) - 1 - k % 3)],
        lambda k: m.encode(message(schema=m.SCHEMA_VERSION + 1 + k)),
    )
    payloads = [kinds[k % len(kinds)](k) for k in range(count)]
    for payload in payloads:
        with pytest.raises(DECODE_ERRORS):
            m.decode(payload, message)
    return payloads


class Driver:
    """A teleop session from the test: claim, heartbeats with rising seq and stamp, motion."""

    def __init__(self, obs: Observer) -> None:
        self.session = uuid.uuid4().hex
        self.bus = obs.bus
        self._beat = self.bus.publisher(m.Heartbeat)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._heartbeats, daemon=True)

    def claim(self) -> None:
        self.bus.publisher(m.SessionClaim).put(m.SessionClaim(session=self.session, client="t"))
        time.sleep(0.05)
        self._thread.start()

    def _heartbeats(self) -> None:
        seq = 0
        while not self._stop.wait(0.05):
            seq += 1
            self._beat.put(m.Heartbeat(session=self.session, seq=seq, stamp=time.monotonic()))

    def mode(self, mode: m.Mode) -> None:
        self.bus.publisher(m.ModeRequest).put(m.ModeRequest(session=self.session, mode=mode))

    def drive(self, seconds: float, vx: float) -> None:
        """Send a forward command at 20 Hz for ``seconds``."""
        motion = self.bus.publisher(m.MotionCommand)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            motion.put(m.MotionCommand(session=self.session, vx=vx))
            time.sleep(0.05)

    def release(self) -> None:
        self.bus.publisher(m.SessionClaim).put(m.SessionClaim(session=self.session, release=True))
        self._stop.set()
        self._thread.join(1.0)


@pytest.fixture(scope="module")
def robot() -> Iterator[tuple[str, Observer]]:
    """A standing control role (fake driver, tripod gait) and an observer of its state."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                "--gait", "tripod", "--listen", endpoint)  # fmt: skip
    obs = Observer(ROBOT, [endpoint])
    for kind in (m.JointState, m.JointCommand, m.FootTargets):
        obs.watch(kind)
    try:
        obs.wait(m.ModeState, lambda s: s.mode == m.Mode.HOLD, 60)
        yield endpoint, obs
        assert proc.stop() == 0
    finally:
        obs.close()
        proc.kill()


def health_after(obs: Observer, stamp: float, pred, timeout: float = 10.0) -> m.Health:
    """The first control Health stamped after ``stamp`` satisfying ``pred``."""
    return obs.wait(
        m.Health, lambda h: h.role == "control" and h.stamp > stamp and pred(h), timeout
    )


def plain_session(endpoint: str) -> zenoh.Session:
    """A plain Zenoh peer connected to the robot, once the control role is reachable."""
    session = zenoh.open(zenoh_config(None, "test", Endpoints([], [endpoint])))
    end = time.monotonic() + 10.0
    while time.monotonic() < end:
        if any(r.ok is not None for r in session.liveliness().get(m.key(ROBOT, "alive/*"))):
            return session
        time.sleep(0.1)
    session.close()
    raise AssertionError(f"no control role at {endpoint}")


def test_garbage_is_counted_by_topic(robot) -> None:
    endpoint, obs = robot
    before = obs.latest_health()
    per_topic = 40
    sent = per_topic * len(GARBAGE_TOPICS)
    session = plain_session(endpoint)
    try:
        for message in GARBAGE_TOPICS:
            for payload in garbage(message, per_topic):
                session.put(
                    m.key(ROBOT, message),
                    payload,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
        after = health_after(
            obs, before.stamp, lambda h: h.decode_errors >= before.decode_errors + sent
        )
    finally:
        session.close()
    assert after.decode_errors == before.decode_errors + sent
    for message in GARBAGE_TOPICS:
        added = after.decode_errors_by.get(message.TOPIC, 0)
        added -= before.decode_errors_by.get(message.TOPIC, 0)
        assert added == per_topic, (message.TOPIC, after.decode_errors_by)
    assert sum(after.decode_errors_by.values()) == after.decode_errors
    assert after.mode == m.Mode.HOLD, "garbage changed nothing"


def test_refused_commands_are_counted_by_topic(robot) -> None:
    _, obs = robot
    before = obs.latest_health()
    intruder = "not-the-holder"
    modes, motions = 30, 20
    mode = lossless(obs.bus, m.ModeRequest)
    for _ in range(modes):
        mode.put(m.ModeRequest(session=intruder, mode=m.Mode.ACTIVE))
    motion = lossless(obs.bus, m.MotionCommand)
    for _ in range(motions):  # paced: the role keeps only the newest motion command
        motion.put(m.MotionCommand(session=intruder, vx=0.1))
        time.sleep(0.03)
    total = modes + motions
    after = health_after(
        obs, before.stamp, lambda h: h.refused_commands >= before.refused_commands + total
    )
    assert after.refused_commands == before.refused_commands + total
    for topic, sent in (("cmd/mode", modes), ("cmd/motion", motions)):
        added = after.refused_by.get(topic, 0) - before.refused_by.get(topic, 0)
        assert added == sent, (topic, after.refused_by)
    assert sum(after.refused_by.values()) == after.refused_commands
    assert after.mode == m.Mode.HOLD, "a refused command changed the mode"


def in_window(obs: Observer, kind: type[m.Message], start: float, end: float) -> list:
    return [s for s in obs.messages(kind) if start <= s.stamp <= end]


def test_commands_and_feet_are_published_at_the_state_rate(robot, robots) -> None:
    _, obs = robot
    profile = profiles.load(robots / "widowx.toml")
    lower = np.array([j.limits.lower for j in profile.joints])
    upper = np.array([j.limits.upper for j in profile.joints])
    standing = obs.latest_health().stamp
    time.sleep(1.0)
    driver = Driver(obs)
    driver.claim()
    driver.mode(m.Mode.ACTIVE)
    active = obs.wait(m.ModeState, lambda s: s.mode == m.Mode.ACTIVE and s.stamp > standing)
    driver.drive(2.0, vx=0.05)
    driver.release()
    held = obs.wait(m.ModeState, lambda s: s.mode == m.Mode.HOLD and s.stamp > active.stamp)

    stand = in_window(obs, m.JointCommand, standing, standing + 0.9)
    assert len(stand) >= 0.9 * 0.9 * profile.rate_hz, f"{len(stand)} commands in 0.9 s standing"
    assert not in_window(obs, m.FootTargets, standing, active.stamp - 0.01), "feet with no gait"

    start, end = active.stamp + 0.1, held.stamp - 0.1
    commands = in_window(obs, m.JointCommand, start, end)
    feet = in_window(obs, m.FootTargets, start, end)
    expected = (end - start) * profile.rate_hz  # the state rate: 100 Hz, every tick
    assert len(commands) >= 0.9 * expected and len(feet) >= 0.9 * expected, (
        len(commands),
        len(feet),
        expected,
    )
    # telemetry goes congestion DROP (docs/topics.md): a loaded machine loses a few samples of
    # either topic, as the counts above allow; a tick publishing feet without its command
    # would show as many feet unmatched
    unmatched = {f.stamp for f in feet} - {c.stamp for c in commands}
    assert len(unmatched) <= 0.1 * expected, f"{len(unmatched)} feet of ticks with no command"
    q = np.array([c.position for c in stand + commands])
    assert q.shape[1] == len(profile.joints)
    assert np.all((q >= lower - 1e-9) & (q <= upper + 1e-9)), "a command beyond a joint limit"
    positions = np.array([f.positions for f in feet])
    assert positions.shape[1:] == (len(profile.legs), 3)
    assert np.ptp(positions[:, :, 0], axis=0).max() > 0.01, "the feet never moved as it walked"
    assert np.ptp(np.array([c.position for c in commands]), axis=0).max() > 0.05


class Sway(GaitPlugin):
    """Sways every foot along x; keeps each FootTargets it returns."""

    def start(self, body, feet) -> None:
        self.home = np.array(feet)
        self.returned: list[m.FootTargets] = []

    def step(self, t, dt, body, world, command) -> m.FootTargets:
        feet = self.home + [0.01 * np.sin(4.0 * t), 0.0, 0.0]
        out = m.FootTargets(stamp=t, positions=feet.tolist(), stance=[True] * len(feet))
        self.returned.append(out)
        return out


class NumpySway(Sway):
    """Sway's targets as numpy arrays: the motion pipeline takes them, the wire does not."""

    def step(self, t, dt, body, world, command) -> m.FootTargets:
        out = super().step(t, dt, body, world, command)
        out.positions = np.array(out.positions)
        return out


def encoded(published: list[m.Message]):
    """A publish callable that encodes as the network does, keeping what it published."""

    def publish(message: m.Message) -> None:
        m.encode(message)
        published.append(message)

    return publish


def walk(profile, gait: Sway, published: list[m.Message], written: list[m.JointCommand]):
    """Stand, then walk ``gait`` for one second, in process on a stepped clock."""
    clock = SteppedClock()
    bus = FakeJointBus(profile, tau=0.01, clock=clock.now)
    bus.open()
    write = bus.write

    def record(command: m.JointCommand) -> None:
        written.append(command)
        write(command)

    bus.write = record
    isolated = Isolated("sway", gait, lambda n, e: None)
    stack = control_stack(profile, bus, clock, isolated, publish=encoded(published))
    assert stack.stand()
    stack.safety.request(m.Mode.ACTIVE, clock.now())
    stack.run(1.0)
    return stack


def test_published_command_is_the_one_written_and_feet_the_gaits(robots) -> None:
    """In process, by identity: every state tick publishes the JointCommand the bus was given
    and, while the gait steps, the FootTargets it returned that tick."""
    profile = profiles.load(robots / "widowx.toml")
    published: list[m.Message] = []
    written: list[m.JointCommand] = []
    gait = Sway(profile=profile)
    walk(profile, gait, published, written)
    commands = [p for p in published if isinstance(p, m.JointCommand)]
    feet = [p for p in published if isinstance(p, m.FootTargets)]
    assert len(commands) == len(written) and all(
        a is b for a, b in zip(commands, written, strict=True)
    )
    assert len(feet) == len(gait.returned) == profile.rate_hz
    assert all(a is b for a, b in zip(feet, gait.returned, strict=True))
    assert [c.stamp for c in commands[-len(feet) :]] == [f.stamp for f in feet]


def test_unencodable_foot_targets_are_skipped_not_a_fault(robots) -> None:
    profile = profiles.load(robots / "widowx.toml")
    published: list[m.Message] = []
    stack = walk(profile, NumpySway(profile=profile), published, [])
    assert stack.safety.mode == m.Mode.ACTIVE, stack.safety.reason
    assert not any(isinstance(p, m.FootTargets) for p in published)
    assert any(isinstance(p, m.JointCommand) for p in published[-5:])
    assert [s for s in stack.controller.messages if s.startswith("state/feet not published")]


def test_tally_is_bounded_and_its_total_exact() -> None:
    tally = Tally(limit=4)
    for k in range(10):
        tally.add(f"topic{k}", k + 1)
    counts = tally.counts()
    assert len(counts) == 4 and counts[OTHER] == sum(range(4, 11))
    assert tally.total == sum(counts.values()) == sum(range(1, 11))
