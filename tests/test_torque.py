"""MIT-mode torque legs: the codec against the published bit layout, the driver against emulated
motors on python-can's virtual bus, faults, and the 1 kHz control loop through the driver."""

from __future__ import annotations

import itertools
import select
import socket
import subprocess
import sys
import threading
import time

import can
import numpy as np
import pytest

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import JointCommand, Mode
from climbd.daemon.runtime.loop import MonotonicClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.sim import mit_motors
from climbd.drivers.sim.mit_motors import MitMotorChain
from climbd.drivers.torque import links, mit
from climbd.drivers.torque.bus import MitJointBus, joint_channels
from climbd.drivers.torque.config import ActuatorRanges, TorqueConfig

RANGES = ActuatorRanges()
_channels = itertools.count()


def test_command_bytes_follow_the_published_layout() -> None:
    """p 16 bits, v 12, kp 12, kd 12, t 12, big-endian nibble packing (mini-cheetah firmware)."""
    # mid-scale: p = 0x7FFF, v = 0x7FF, kp = kd = 0, t = 0x7FF; then everything saturated high
    frames = mit.pack_commands(
        [0.0, 99.0], [0.0, 99.0], [0.0, 999.0], [0.0, 99.0], [0.0, 99.0], RANGES
    )
    assert frames == [bytes([0x7F, 0xFF, 0x7F, 0xF0, 0x00, 0x00, 0x07, 0xFF]), bytes([0xFF] * 8)]
    reply = mit.pack_reply(mit.Reply(7, -12.5, -45.0, -18.0), RANGES)
    assert reply == bytes([7, 0, 0, 0, 0, 0])


def test_round_trip_within_quantisation() -> None:
    """Commands packed together decode motor by motor; replies packed one by one decode
    together; both within one quantisation step of the actuator's ranges."""
    rng = np.random.default_rng(1)
    n = 200
    p, v, t = rng.uniform(-10, 10, n), rng.uniform(-40, 40, n), rng.uniform(-17, 17, n)
    kp, kd = rng.uniform(0, 500, n), rng.uniform(0, 5, n)
    for i, frame in enumerate(mit.pack_commands(p, v, kp, kd, t, RANGES)):
        back = mit.unpack_command(frame, RANGES)
        assert abs(back.position - p[i]) <= 25.0 / 65535
        assert abs(back.velocity - v[i]) <= 90.0 / 4095 and abs(back.torque - t[i]) <= 36.0 / 4095
        assert abs(back.kp - kp[i]) <= 500.0 / 4095 and abs(back.kd - kd[i]) <= 5.0 / 4095
    replies = b"".join(
        mit.pack_reply(mit.Reply(i % 256, p[i], v[i], t[i]), RANGES) for i in range(n)
    )
    motor, position, velocity, torque = mit.unpack_replies(replies, RANGES)
    assert motor == [i % 256 for i in range(n)]
    assert np.abs(position - p).max() <= 25.0 / 65535
    assert np.abs(velocity - v).max() <= 90.0 / 4095 and np.abs(torque - t).max() <= 36.0 / 4095
    with pytest.raises(mit.ProtocolError, match="5 bytes, expected 6"):
        mit.unpack_replies(b"\x01\x02\x03\x04\x05", RANGES)


def test_a_non_finite_command_is_refused_naming_the_joint() -> None:
    """A NaN would cast to a full-scale position: the codec refuses it before the wire."""
    with pytest.raises(mit.ProtocolError, match="command torque of LF_femur is not finite"):
        mit.pack_commands(
            [0, 0], [0, 0], [5, 5], [1, 1], [0, np.nan], RANGES, ["LF_coxa", "LF_femur"]
        )


@pytest.fixture()
def qingzhui(robots):
    return profiles.load(robots / "qingzhui.toml")


def patient(profile: profiles.Profile) -> profiles.Profile:
    """The profile with a driver waiting 50 ms for replies (not 0.5 ms), so a loaded test
    machine's late emulator is not taken for a fault."""
    return profiles.with_bus_options(profile, reply_timeout=0.05)


def follows_goal(bus: MitJointBus) -> float:
    """Largest joint error (rad) after commanding a spread of positions for 600 cycles."""
    bus.torque(True)
    goal = np.linspace(-0.4, 0.4, 18)
    for _ in range(600):
        bus.read()
        bus.write(JointCommand(position=goal.tolist()))
    return float(np.max(np.abs(np.array(bus.read().position) - goal)))


@pytest.fixture()
def rig(qingzhui):
    """Emulated motors serving in a thread and the driver, on python-can's virtual bus."""
    channel = f"qz-test-{next(_channels)}"
    chain = MitMotorChain(
        [j.id for j in qingzhui.joints], TorqueConfig.from_profile(qingzhui).actuator, channel
    ).start()
    bus = MitJointBus(patient(qingzhui), [channel], interface="virtual")
    yield chain, bus
    bus.close()
    chain.stop()


def test_motors_follow_impedance_commands(rig) -> None:
    chain, bus = rig
    bus.open()
    assert follows_goal(bus) < 0.01
    assert all(m.motor_mode for m in chain.motors.values())
    chain.motors[3].load = 2.0  # a steady load on one joint shows up as measured torque
    follows_goal(bus)
    assert bus.read().effort[2] == pytest.approx(2.0, abs=0.1)


def udp_channels(count: int) -> list[str]:
    """``count`` udp_can channels (driver's end first) on loopback ports free right now."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2 * count)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return [f"127.0.0.1:{a}/127.0.0.1:{b}" for a, b in zip(ports[::2], ports[1::2], strict=True)]


def test_motors_in_their_own_process_follow_the_driver(qingzhui, robots) -> None:
    """``python -m climbd.drivers.sim.mit_motors`` serves the profile's motors from a process of
    its own on two udp_can channels (legs alternating, as the driver spreads them); the driver opens
    them, drives them to a goal, and the emulator exits cleanly on SIGTERM."""
    channels = udp_channels(2)
    theirs = [links.peer_channel(c) for c in channels]
    motors = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "climbd.drivers.sim.mit_motors",
            "--profile",
            str(robots / "qingzhui.toml"),
        ]
        + ["--channel", *theirs],
        stdout=subprocess.PIPE,
        text=True,
    )
    bus = MitJointBus(patient(qingzhui), channels, interface=links.UDP_INTERFACE)
    try:
        ready, _, _ = select.select([motors.stdout], [], [], 30)
        assert ready and motors.stdout.readline().split() == theirs
        bus.open()
        assert follows_goal(bus) < 0.01
        bus.torque(False)
    finally:
        bus.close()
        motors.terminate()
        assert motors.wait(10) == 0


def test_udp_link_carries_can_frames_both_ways() -> None:
    """Data frames (ids and payload lengths kept), a bus-off error frame, and everything waiting
    taken by one receive; a datagram that is not a can_frame is named as such."""
    mine = udp_channels(1)[0]
    a, b = links.UdpLink(mine), links.UdpLink(links.peer_channel(mine))
    try:
        a.send([1, 2, 0x7FF], [bytes(range(8)), b"\x05" * 6, b""])
        a.send_error(mit.CAN_ERR_BUSOFF)
        frames = b.receive(1.0)
        while len(frames) < 4:
            frames += b.receive(1.0)
        assert frames == [
            links.Frame(1, bytes(range(8))),
            links.Frame(2, b"\x05" * 6),
            links.Frame(0x7FF, b""),
            links.Frame(mit.CAN_ERR_BUSOFF, bytes(8), error=True),
        ]
        assert b.receive(0.0) == []
        a.socket.send(b"short")
        with pytest.raises(can.CanOperationError, match="5-byte datagram is not a 16-byte"):
            b.receive(1.0)
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("channel", ["127.0.0.1:1", "a:1/b", "h:1/h:x", "can0"])
def test_a_malformed_udp_channel_is_named(qingzhui, channel) -> None:
    bus = MitJointBus(qingzhui, [channel], interface=links.UDP_INTERFACE)
    with pytest.raises(DriverError, match=f"channel {channel!r} is not LOCAL_HOST:PORT/PEER"):
        bus.open()


def test_motors_not_served_over_udp_are_a_clear_error(qingzhui) -> None:
    """No emulator at the peer's port: the refusal (on the first receive or the next send)
    names the channel, not a raw OSError."""
    channel = udp_channels(1)[0]
    bus = MitJointBus(qingzhui, [channel], interface=links.UDP_INTERFACE)
    with pytest.raises(DriverError, match=f"CAN (send|receive) on {channel}: .*refused"):
        bus.open()


class EchoLink:
    """A channel whose motors answer every command at once; records what receive waited."""

    def __init__(self, channel: str, master_id: int) -> None:
        self.channel, self.master_id = channel, master_id
        self.waiting: list[links.Frame] = []
        self.waits: list[float] = []

    def send(self, ids, payloads) -> None:
        for motor in ids:
            reply = mit.pack_reply(mit.Reply(motor, 0.1, 0.0, 0.0), RANGES)
            self.waiting.append(links.Frame(self.master_id, reply))

    def send_error(self, error_class: int) -> None:
        raise AssertionError("the driver sends no error frames")

    def receive(self, timeout: float) -> list[links.Frame]:
        self.waits.append(timeout)
        frames, self.waiting = self.waiting, []
        return frames

    def fileno(self) -> None:
        return None

    def close(self) -> None:
        pass


def test_a_channel_whose_motors_answered_is_not_waited_on(qingzhui, monkeypatch) -> None:
    """With six channels, a read waits on each only while its own motors have not answered
    (waiting on one channel for the others' replies cost a tick the whole reply timeout)."""
    opened: dict[str, EchoLink] = {}

    def echo(interface: str, channel: str) -> EchoLink:
        opened[channel] = EchoLink(channel, TorqueConfig.from_profile(qingzhui).master_id)
        return opened[channel]

    monkeypatch.setattr("climbd.drivers.torque.bus.open_link", echo)
    bus = MitJointBus(patient(qingzhui), [f"can{i}" for i in range(6)])
    bus.open()
    for link in opened.values():
        link.waits.clear()
    bus.torque(True)
    bus.write(JointCommand(position=[0.0] * 18))
    state = bus.read()
    assert state.position == pytest.approx([0.1] * 18, abs=1e-3)
    for link in opened.values():  # a wait for its three replies, then a look for more
        assert len(link.waits) == 2 and link.waits[0] > 0.0 and link.waits[1] == 0.0


@pytest.fixture()
def udp_rig(qingzhui):
    """Emulated motors serving in a thread on two udp_can channels (their state as set, not
    stepped), and the driver with the profile's reply timeout (0: a read takes only what has
    arrived)."""
    channels = udp_channels(2)
    placed = joint_channels(qingzhui, channels)
    chains = [
        MitMotorChain(
            [j.id for j, c in zip(qingzhui.joints, placed, strict=True) if c == channel],
            TorqueConfig.from_profile(qingzhui).actuator,
            links.peer_channel(channel),
            links.UDP_INTERFACE,
            external_model=True,
        ).start()
        for channel in channels
    ]
    bus = MitJointBus(qingzhui, channels, interface=links.UDP_INTERFACE)
    yield chains, bus
    bus.close()
    for chain in chains:
        chain.stop()


def test_replies_are_taken_between_ticks(udp_rig) -> None:
    """``serve_until`` files the replies to a write as they arrive and returns once all are in,
    before its deadline; the read after it finds nothing missing."""
    chains, bus = udp_rig
    bus.open()
    bus.torque(True)
    bus.serve_until(time.monotonic() + 5.0)  # every reply to torque on in: none can pass as new
    bus.read()
    for chain in chains:
        for motor in chain.motors:
            chain.set_state(motor, position=0.3, velocity=0.0, torque=0.0)
    bus.write(JointCommand(position=[0.1] * 18))
    deadline = time.monotonic() + 5.0
    bus.serve_until(deadline)
    assert time.monotonic() < deadline
    assert bus.position == pytest.approx(0.3, abs=1e-3)
    late = bus.late_reads
    assert bus.read().position == pytest.approx([0.3] * 18, abs=1e-3)
    assert bus.late_reads == late


def test_a_bus_off_between_ticks_is_raised_by_the_next_read(udp_rig) -> None:
    chains, bus = udp_rig
    bus.open()
    bus.write(JointCommand(position=[0.0] * 18))
    chains[1].bus_off()
    bus.serve_until(time.monotonic() + 0.2)
    with pytest.raises(DriverError, match="bus-off on udp_can channel"):
        bus.read()


def test_the_motor_emulator_names_a_bad_profile(tmp_path, capsys) -> None:
    assert mit_motors.main(["--profile", str(tmp_path / "none.toml"), "--channel", "x"]) == 2
    assert "none.toml" in capsys.readouterr().err


def test_torque_off_leaves_motor_mode_and_still_reads(rig) -> None:
    chain, bus = rig
    bus.open()
    bus.torque(True)
    bus.torque(False)
    chain.set_state(5, position=0.25, velocity=0.0, torque=0.0)
    assert not any(m.motor_mode for m in chain.motors.values())
    assert bus.read().position[4] == pytest.approx(0.25, abs=1e-3)
    assert chain.motors[5].command is None, "polls out of motor mode never command the motor"


def test_silent_motor_at_open_is_named(rig) -> None:
    chain, bus = rig
    chain.silence(7)
    with pytest.raises(DriverError, match=r"motor 7 \(lb_abduction\) on qz-test-\d+"):
        bus.open()


def test_lost_motor_is_reported_and_readmitted(rig, qingzhui) -> None:
    chain, bus = rig
    bus.open()
    bus.torque(True)
    chain.silence(2)
    for _ in range(qingzhui.bus.lost_after + 1):
        bus.read()
        bus.write(JointCommand(position=[0.0] * 18))
    health = {h.name: h for h in bus.health()}
    assert health["mf_thigh"].lost and not health["mf_abduction"].lost
    chain.silence(2, False)
    bus.read()
    bus.write(JointCommand(position=[0.0] * 18))
    bus.read()
    assert not any(h.lost for h in bus.health())


def test_corrupt_reply_and_bus_off(rig) -> None:
    chain, bus = rig
    bus.open()
    chain.corrupt(4)
    bus.read()
    errors = {h.name: h.errors for h in bus.health()}
    assert errors["lf_abduction"] and "bad reply" in errors["lf_abduction"][0]
    chain.bus_off()
    with pytest.raises(DriverError, match="bus-off"):
        bus.read()


def test_out_of_range_reply_is_flagged(rig) -> None:
    chain, bus = rig
    bus.open()
    chain.set_state(1, position=30.0, velocity=0.0, torque=0.0)
    bus.read()
    assert bus.health()[0].errors == ["range"]


def test_a_nan_command_never_reaches_the_motors(rig) -> None:
    """The write fails naming the joint and puts no frame on the bus; the motors keep the
    last command they had."""
    chain, bus = rig
    bus.open()
    bus.torque(True)
    bus.read()
    sent = bus.sent
    goal = [0.1] * 18
    goal[4] = float("nan")
    with pytest.raises(DriverError, match="command position of lf_thigh is not finite"):
        bus.write(JointCommand(position=goal))
    assert bus.sent == sent


def test_bad_channel_is_a_clear_error(qingzhui) -> None:
    bus = MitJointBus(qingzhui, ["can9"], interface="socketcan")
    with pytest.raises(DriverError, match="cannot open CAN socketcan channel 'can9'"):
        bus.open()


def assert_stands_at_one_khz(profile: profiles.Profile, bus) -> None:
    """The 1 kHz loop (gravity feed-forward) over an open ``bus`` stands the robot: HOLD after
    "stand complete", the joints within 0.02 rad of the stand pose, none lost."""
    clock = MonotonicClock()
    stack = control_stack(profile, bus, clock, feed_forward=True)
    safety, controller, loop = stack.safety, stack.controller, stack.loop
    safety.request(Mode.STAND, clock.now())
    thread = threading.Thread(target=loop.run, kwargs={"max_ticks": 6000})
    thread.start()
    thread.join(60)
    assert safety.mode == Mode.HOLD and safety.reason == "stand complete", safety.reason
    q = np.array(bus.read().position)
    assert np.max(np.abs(q - controller.stand_q)) < 0.02
    assert loop.ticks >= 2000 and all(not h.lost for h in bus.health())


def test_one_khz_loop_stands_qingzhui_through_the_driver(rig, qingzhui) -> None:
    _, bus = rig
    bus.open()
    assert_stands_at_one_khz(qingzhui, bus)
