"""The Dynamixel joint bus through dynamixel_sdk against the byte-level emulator on a pty.

Ground truth comes from the e-Manual resolutions written here (AX-18A: 300° over 0–1023,
centre 512; X series: 4096 ticks a turn, centre 2048) and from the emulated servos' own
control tables, never from the driver's tables.
"""

from __future__ import annotations

import math
import time

import msgspec
import numpy as np
import pytest

from climbd.daemon.contract.hardware import DriverError, JointBus
from climbd.daemon.contract.messages import JointCommand, Mode
from climbd.daemon.contract.profile import Profile, gripper_servos, load, with_bus_options
from climbd.daemon.runtime.safety import Safety
from climbd.drivers.dynamixel.bus import DynamixelBus
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.sim.dynamixel import DynamixelEmulator, EmulatedServo, ServoChain
from climbd.drivers.sim.dynamixel.tables import XM430_W350

RESOLUTION = {1: (math.radians(300) / 1023, 512), 2: (2 * math.pi / 4096, 2048)}
MARGIN_MS = 10.0  # packet-timeout margin: tolerates a loaded CI machine


def _profile(name: str, **options):
    """A stock profile with joints turned round and offset: kinematic data the bus must ignore;
    ``options`` replace keys of its Dynamixel ``[bus]``."""
    p = load(f"robots/{name}.toml")
    legs = []
    for i, leg in enumerate(p.legs):
        joints = [
            msgspec.structs.replace(j, zero_offset=0.1 * (k - 1), direction=-1 if i % 2 else 1)
            for k, j in enumerate(leg.joints)
        ]
        legs.append(msgspec.structs.replace(leg, joints=joints))
    return with_bus_options(msgspec.structs.replace(p, legs=legs), **options)


def _dxl(profile: Profile) -> DynamixelConfig:
    """The profile's Dynamixel settings."""
    return DynamixelConfig.from_profile(profile)


@pytest.fixture(params=["widowx", "hubrobo"])
def rig(request):
    profile = _profile(request.param)
    chain = ServoChain.from_profile(profile)
    with DynamixelEmulator(chain) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port, timeout_margin_ms=MARGIN_MS)
        bus.open()
        yield profile, chain, emu, bus
        bus.close()


def _settle(bus: DynamixelBus, q: np.ndarray, tol: float, seconds: float = 3.0) -> np.ndarray:
    """Read until every joint is within ``tol`` of ``q`` (or the deadline); the last reading."""
    deadline = time.monotonic() + seconds
    while True:
        measured = np.array(bus.read().position)
        if np.max(np.abs(measured - q)) <= tol or time.monotonic() > deadline:
            return measured


def test_implements_joint_bus(rig):
    assert isinstance(rig[3], JointBus)


def test_goals_reach_servos_within_resolution(rig):
    profile, chain, _, bus = rig
    joints = profile.joints
    rng = np.random.default_rng(3)
    lo = np.array([j.limits.lower for j in joints])
    hi = np.array([j.limits.upper for j in joints])
    q = rng.uniform(lo, hi) * 0.8
    bus.torque(True)
    bus.write(JointCommand(position=q.tolist()))
    rad_per_tick, center = RESOLUTION[_dxl(profile).protocol]
    measured = _settle(bus, q, rad_per_tick / 2 + 1e-9)
    for j, qj in zip(joints, q, strict=True):
        servo = chain.servo(j.id)
        expected = round(center + qj / rad_per_tick)
        assert servo.get("goal_position") == expected, j.name
    assert np.max(np.abs(measured - q)) <= rad_per_tick / 2 + 1e-9
    assert np.max(np.abs(chain.joint_goals() - q)) <= rad_per_tick / 2 + 1e-9


def test_bring_up_sets_return_delay_and_status_level(rig):
    profile, chain, _, _ = rig
    speeds = {j.id: j.limits.velocity for j in profile.joints}
    speeds |= {g.id: g.velocity for _, _, g in gripper_servos(profile)}
    assert set(chain.servos) == set(speeds)
    for s in chain.servos.values():
        assert s.get("return_delay_time") == _dxl(profile).return_delay_us // 2
        assert s.get("status_return_level") == 2
        assert s.speed_limit == pytest.approx(speeds[s.ident], rel=0.05)


def test_bring_up_from_status_level_one():
    profile = _profile("widowx")
    chain = ServoChain.from_profile(profile)
    chain.servo(5).set("status_return_level", 1)
    with DynamixelEmulator(chain) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port, timeout_margin_ms=MARGIN_MS)
        bus.open()
        bus.close()
    assert chain.servo(5).get("status_return_level") == 2
    assert chain.servo(5).get("return_delay_time") == 0


def test_one_transaction_per_servo_or_one_sync_read_per_cycle(rig):
    profile, chain, _, bus = rig
    n = len(profile.joints)
    q = np.zeros(n)
    every = bus.health_every
    while (bus.reads + 1) % every == 0 or (bus.reads + 2) % every == 0:
        bus.read()  # the next two reads are ordinary cycles
    before = dict(chain.counts)
    bus.read()
    bus.write(JointCommand(position=q.tolist()))
    bus.read()  # a round trip: the emulator has handled the broadcast sync write before it
    delta = {k: v - before.get(k, 0) for k, v in chain.counts.items() if v != before.get(k, 0)}
    if _dxl(profile).protocol == 1:
        assert delta == {0x02: 2 * n, 0x83: 1}  # a READ per servo per cycle, one SYNC WRITE
    else:
        assert delta == {0x8A: 2, 0x83: 1}  # one FAST SYNC READ per cycle, one SYNC WRITE


def test_missing_id_wrong_model_and_missing_port_are_named():
    profile = _profile("hubrobo")
    chain = ServoChain.from_profile(profile)
    chain.silence(7)
    wrong = ServoChain(
        [EmulatedServo(XM430_W350, j.id) for j in profile.joints], 2, _dxl(profile).baud
    )
    with DynamixelEmulator(chain) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port)
        with pytest.raises(DriverError, match=rf"{emu.port}.*id 7 \(lr_coxa\) does not answer"):
            bus.open()
    with DynamixelEmulator(wrong) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port)
        with pytest.raises(DriverError, match=r"id 1 \(rf_coxa\) is XM430-W350.*XL430-W250"):
            bus.open()
    with pytest.raises(DriverError, match="/dev/nonexistent-dxl.*cannot open port"):
        DynamixelBus.from_profile(profile, port="/dev/nonexistent-dxl").open()


def test_servo_lost_mid_run_and_readmitted(rig):
    profile, chain, _, bus = rig
    joints = profile.joints
    victim = joints[4]
    bus.torque(True)
    chain.silence(victim.id)
    for _ in range(bus.lost_after + bus.health_every):
        bus.read()
    lost = [h.name for h in bus.health() if h.lost]
    assert lost == [victim.name]
    q = np.zeros(len(joints))
    q[0] = 0.3 * joints[0].limits.upper
    bus.write(JointCommand(position=q.tolist()))
    measured = _settle(
        bus, np.where(np.arange(len(joints)) == 4, bus.position[: bus.n_joints], q), 0.01
    )
    assert abs(measured[0] - q[0]) < 0.01  # the other joints keep being served
    safety = Safety(profile)
    safety.request(Mode.STAND, 0.0)
    safety.judge(bus.health(), 0.1)
    assert safety.mode == Mode.HOLD and victim.name in safety.reason
    chain.silence(victim.id, on=False)
    for _ in range(bus.health_every):
        bus.read()
    assert not any(h.lost for h in bus.health())


def test_every_servo_lost_then_back(rig):
    """With every servo silent the loop goes on (writes send nothing, no error); all come back."""
    profile, chain, _, bus = rig
    for ident in chain.servos:
        chain.silence(ident)
    for _ in range(bus.lost_after):
        bus.read()
    assert all(h.lost for h in bus.health())
    sent = bus.sent
    bus.write(JointCommand(position=np.zeros(len(profile.joints)).tolist()))
    assert bus.sent == sent
    for ident in chain.servos:
        chain.silence(ident, on=False)
    for _ in range(bus.health_every):
        bus.read()
    assert not any(h.lost for h in bus.health())


def test_overheat_derates_then_stops(rig):
    profile, chain, _, bus = rig
    s = profile.safety
    servo = chain.servo(profile.joints[2].id)
    safety = Safety(profile)
    safety.request(Mode.STAND, 0.0)
    servo.set_present(temperature=s.derate_temperature + 1)
    bus.read_health()
    health = bus.health()
    assert health[2].temperature == s.derate_temperature + 1
    safety.judge(health, 0.1)
    assert safety.speed_scale < 1.0 and safety.mode == Mode.STAND
    servo.set_present(temperature=s.max_temperature + 5)
    bus.read_health()
    health = bus.health()
    assert "overheat" in health[2].errors
    safety.judge(health, 0.2)
    assert safety.mode == Mode.FAULT


def test_overload_bit_is_reported(rig):
    profile, chain, _, bus = rig
    chain.servo(profile.joints[1].id).inject_overload()
    bus.read_health()
    assert bus.health()[1].errors == ["overload"]
    assert all(not h.errors for k, h in enumerate(bus.health()) if k != 1)


def test_fault_reset_brings_back_only_servos_a_fault_switched_off(rig):
    """Overload switches the servo off (Shutdown); the X series latch it until a REBOOT. The
    reset torques it again where its horn now is; a powered servo is never rebooted."""
    profile, chain, _, bus = rig
    bus.torque(True)
    k, other = 1, 5
    servo = chain.servo(profile.joints[k].id)
    servo.inject_overload()
    assert not servo.torque_enabled
    powered = chain.servo(profile.joints[other].id)
    powered.set_present(voltage=5.0)  # an error the default Shutdown leaves powered
    bus.read_health()
    assert bus.health()[k].errors == ["overload"] and "voltage" in bus.health()[other].errors
    servo.inject_overload(False)
    servo.set_present(angle=0.3)  # the limp horn was pushed by the load
    assert bus.clear_faults() == [profile.joints[k].name]
    deadline = time.monotonic() + 3.0
    while not servo.torque_enabled or bus.health()[k].lost:
        assert time.monotonic() < deadline, "the servo never came back"
        bus.read()
    bus.read_health()
    assert bus.health()[k].errors == [] and not bus.health()[k].lost
    step = RESOLUTION[_dxl(profile).protocol][0]
    assert abs(servo.goal_angle - 0.3) <= step and abs(bus.position[k] - 0.3) <= step
    assert powered.torque_enabled
    assert chain.counts[0x08] == (1 if _dxl(profile).protocol == 2 else 0)  # REBOOT


def test_corrupt_replies_are_misses_not_crashes(rig):
    profile, chain, _, bus = rig
    ident = profile.joints[0].id
    chain.corrupt(ident, count=2)
    for _ in range(3):
        bus.read()
    assert not bus.health()[0].lost
    chain.corrupt(ident, count=None)
    for _ in range(bus.lost_after + bus.health_every):
        bus.read()
    assert [h.name for h in bus.health() if h.lost] == [profile.joints[0].name]
    chain.corrupt(ident, count=0)


def test_port_vanishing_is_a_driver_error(rig):
    _, _, emu, bus = rig
    emu.vanish()
    with pytest.raises(DriverError, match=emu.port):
        for _ in range(3):
            bus.read()
    with pytest.raises(DriverError, match=emu.port):
        bus.write(JointCommand(position=[0.0] * len(bus.ids)))


def test_bad_commands_are_refused(rig):
    _, _, _, bus = rig
    with pytest.raises(DriverError, match="command has 2 positions"):
        bus.write(JointCommand(position=[0.0, 0.0]))
    q = [0.0] * bus.n_joints
    q[3] = math.nan
    with pytest.raises(DriverError, match=bus.names[3]):
        bus.write(JointCommand(position=q))


def test_grip_flags_close_and_open_the_gripper_servos_and_holding_is_where_the_fingers_stop():
    """The gripper servos ride the joints' sync write: closed or open as the command's grip
    says, kept when a command says nothing. A gripper closed on nothing ends at closed and
    holds nothing; one whose fingers stop between open and closed holds, once they are still."""
    profile = _profile("hubrobo")
    chain = ServoChain.from_profile(profile)
    grippers = gripper_servos(profile)
    assert [leg for leg, _, _ in grippers] == [0, 1, 2, 3]
    rad_per_tick, _ = RESOLUTION[2]
    with DynamixelEmulator(chain) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port, timeout_margin_ms=MARGIN_MS)
        bus.open()
        bus.torque(True)
        q = np.zeros(len(profile.joints)).tolist()
        grip = [True, False, True, False]
        bus.write(JointCommand(position=q, grip=grip))
        ends = np.array([g.closed if grip[leg] else g.open for leg, _, g in grippers])
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            state = bus.read()
            fingers = bus.position[bus.n_joints :]
            if np.max(np.abs(fingers - ends)) <= rad_per_tick:
                break
        assert np.max(np.abs(fingers - ends)) <= rad_per_tick, "the fingers reach their ends"
        assert len(state.position) == len(profile.joints) == len(state.names)
        assert state.holding == [False] * 4, "closed on nothing, open: no gripper holds"
        rf = chain.grippers[0]
        g = grippers[0][2]
        rf.external = True
        rf.set_present(angle=(g.open + g.closed) / 2, velocity=1.0)
        assert bus.read().holding == [False] * 4, "fingers still moving hold nothing yet"
        rf.set_present(velocity=0.0)
        assert bus.read().holding == [True, False, False, False]
        bus.write(JointCommand(position=q))
        bus.read()
        assert chain.servo(g.id).goal_angle == pytest.approx(g.closed, abs=rad_per_tick)
        assert chain.servo(grippers[1][2].id).goal_angle == pytest.approx(
            grippers[1][2].open, abs=rad_per_tick
        )
        with pytest.raises(DriverError, match=rf"{emu.port}.*2 grip flags, robot has 4 legs"):
            bus.write(JointCommand(position=q, grip=[True, True]))
        bus.close()


def test_a_silent_gripper_servo_is_a_lost_servo_named_for_its_leg():
    profile = _profile("hubrobo")
    chain = ServoChain.from_profile(profile)
    with DynamixelEmulator(chain) as emu:
        bus = DynamixelBus.from_profile(profile, port=emu.port, timeout_margin_ms=MARGIN_MS)
        bus.open()
        chain.silence(chain.grippers[2].ident)
        for _ in range(bus.lost_after + bus.health_every):
            state = bus.read()
        assert [h.name for h in bus.health() if h.lost] == ["lr_gripper"]
        assert state.holding[2] is False, "a lost gripper is not taken to hold"
        safety = Safety(profile)
        safety.request(Mode.STAND, 0.0)
        safety.judge(bus.health(), 0.1)
        assert safety.mode == Mode.HOLD and "servo lost: lr_gripper" in safety.reason
        bus.close()


def test_compiled_crc_equals_the_sdks_over_random_packets():
    """The Protocol 2.0 handler's compiled CRC-16 gives the SDK's own result on any packet,
    prefix length and starting value, and the driver's handler is that class on 2.0 only."""
    import dynamixel_sdk as sdk

    from climbd.drivers.dynamixel.packet import FastCrcProtocol2PacketHandler, packet_handler

    stock, fast = sdk.PacketHandler(2.0), FastCrcProtocol2PacketHandler()
    rng = np.random.default_rng(3)
    for _ in range(500):
        packet = rng.integers(0, 256, int(rng.integers(0, 400))).tolist()
        size = int(rng.integers(0, len(packet) + 1))
        start = int(rng.integers(0, 1 << 16)) if rng.random() < 0.5 else 0
        assert fast.updateCRC(start, packet, size) == stock.updateCRC(start, packet, size)
    # the check value of CRC-16/BUYPASS over "123456789" (CRC catalogue)
    assert fast.updateCRC(0, list(b"123456789"), 9) == 0xFEE8
    assert isinstance(packet_handler(2), FastCrcProtocol2PacketHandler)
    assert isinstance(packet_handler(1), sdk.Protocol1PacketHandler)
