"""MIT-mode torque legs: the codec against the published bit layout, the driver against emulated
motors on python-can's virtual bus, faults, and the 1 kHz control loop through the driver."""

from __future__ import annotations

import itertools
import threading

import msgspec
import numpy as np
import pytest

from daemon import profile as profiles
from daemon.control import Controller
from daemon.loop import ControlLoop, MonotonicClock
from daemon.messages import JointCommand, Mode
from daemon.profile import ActuatorRanges
from daemon.safety import Safety
from drivers.base import DriverError
from drivers.sim.mit_motors import MitMotorChain
from drivers.torque import mit
from drivers.torque.bus import MitJointBus

RANGES = ActuatorRanges()
_channels = itertools.count()


def test_command_bytes_follow_the_published_layout() -> None:
    """p 16 bits, v 12, kp 12, kd 12, t 12, big-endian nibble packing (mini-cheetah firmware)."""
    c = mit.Command(position=0.0, velocity=0.0, kp=0.0, kd=0.0, torque=0.0)
    # mid-scale: p = 0x7FFF, v = 0x7FF, kp = kd = 0, t = 0x7FF
    assert mit.pack_command(c, RANGES) == bytes([0x7F, 0xFF, 0x7F, 0xF0, 0x00, 0x00, 0x07, 0xFF])
    top = mit.Command(position=99.0, velocity=99.0, kp=999.0, kd=99.0, torque=99.0)
    assert mit.pack_command(top, RANGES) == bytes([0xFF] * 8)
    reply = mit.pack_reply(mit.Reply(7, -12.5, -45.0, -18.0), RANGES)
    assert reply == bytes([7, 0, 0, 0, 0, 0])


def test_round_trip_within_quantisation() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        p, v, t = rng.uniform(-10, 10), rng.uniform(-40, 40), rng.uniform(-17, 17)
        kp, kd = rng.uniform(0, 500), rng.uniform(0, 5)
        back = mit.unpack_command(mit.pack_command(mit.Command(p, v, kp, kd, t), RANGES), RANGES)
        assert abs(back.position - p) <= 25.0 / 65535
        assert abs(back.velocity - v) <= 90.0 / 4095 and abs(back.torque - t) <= 36.0 / 4095
        assert abs(back.kp - kp) <= 500.0 / 4095 and abs(back.kd - kd) <= 5.0 / 4095
    with pytest.raises(mit.ProtocolError, match="5 bytes, expected 6"):
        mit.unpack_reply(b"\x01\x02\x03\x04\x05", RANGES)


@pytest.fixture()
def qingzhui(robots):
    return profiles.load(robots / "qingzhui.toml")


@pytest.fixture()
def rig(qingzhui):
    """Emulated motors and the driver; the driver waits 50 ms for replies (not the profile's
    0.5 ms) so a loaded test machine's late emulator thread is not taken for a fault."""
    channel = f"qz-test-{next(_channels)}"
    chain = MitMotorChain([j.id for j in qingzhui.joints], qingzhui.bus.actuator, channel).start()
    patient = msgspec.structs.replace(qingzhui.bus, reply_timeout=0.05)
    profile = msgspec.structs.replace(qingzhui, bus=patient)
    bus = MitJointBus(profile, [channel], interface="virtual")
    yield chain, bus
    bus.close()
    chain.stop()


def test_motors_follow_impedance_commands(rig) -> None:
    chain, bus = rig
    bus.open()
    bus.torque(True)
    goal = np.linspace(-0.4, 0.4, 18)
    for _ in range(600):
        bus.read()
        bus.write(JointCommand(position=goal.tolist()))
    state = bus.read()
    assert np.max(np.abs(np.array(state.position) - goal)) < 0.01
    assert all(m.motor_mode for m in chain.motors.values())
    chain.motors[3].load = 2.0  # a steady load on one joint shows up as measured torque
    for _ in range(600):
        bus.read()
        bus.write(JointCommand(position=goal.tolist()))
    assert bus.read().effort[2] == pytest.approx(2.0, abs=0.1)


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


def test_bad_channel_is_a_clear_error(qingzhui) -> None:
    bus = MitJointBus(qingzhui, ["can9"], interface="socketcan")
    with pytest.raises(DriverError, match="cannot open CAN socketcan channel 'can9'"):
        bus.open()


def test_one_khz_loop_stands_qingzhui_through_the_driver(rig, qingzhui) -> None:
    chain, bus = rig
    bus.open()
    clock = MonotonicClock()
    safety = Safety(qingzhui)
    controller = Controller(qingzhui, bus, safety, clock.now, feed_forward=True)
    loop = ControlLoop(qingzhui.rate_hz, clock, controller.tick)
    safety.request(Mode.STAND, clock.now())
    thread = threading.Thread(target=loop.run, kwargs={"max_ticks": 6000})
    thread.start()
    thread.join(60)
    assert safety.mode == Mode.HOLD and safety.reason == "stand complete", safety.reason
    q = np.array(bus.read().position)
    assert np.max(np.abs(q - controller.stand_q)) < 0.02
    assert loop.ticks >= 2000 and all(not h.lost for h in bus.health())
