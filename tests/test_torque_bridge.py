"""The torque bridge: ``python -m climbd.drivers.torque.bridge`` serving MIT motors (emulated in a
thread here, over udp_can) to the control role's ``BridgeJointBus``."""

from __future__ import annotations

import contextlib
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_torque import assert_stands_at_one_khz, udp_channels

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import JointCommand
from climbd.drivers.sim.mit_motors import MitMotorChain
from climbd.drivers.torque import links
from climbd.drivers.torque.bridge import BridgeJointBus
from climbd.drivers.torque.config import TorqueConfig

WATCHDOG = 0.2
"""The bridge's watchdog in the test that trips it (a loaded test machine can stall the test's
requests for the production default's 50 ms)."""


@contextlib.contextmanager
def started(module: str, *args: str, ready: str) -> Iterator[subprocess.Popen]:
    """``python -m MODULE ARGS`` once it printed ``ready`` (within 30 s), terminated after."""
    process = subprocess.Popen(
        [sys.executable, "-m", module, *args], stdout=subprocess.PIPE, text=True
    )
    try:
        readable, _, _ = select.select([process.stdout], [], [], 30)
        assert readable and process.stdout.readline().strip() == ready, f"{module} did not start"
        yield process
    finally:
        process.terminate()
        process.wait(10)


@contextlib.contextmanager
def bridged(profile_path: Path, watchdog: float = 5.0, motors_in_process: bool = True):
    """Emulated motors (a thread of this process, or else a process of their own, as hardware
    is), the bridge process to them and the control role's bus (not opened)."""
    profile = profiles.load(profile_path)
    can_channel, bridge_channel = udp_channels(2)
    with contextlib.ExitStack() as stack:
        chain = None
        if motors_in_process:
            ids = [j.id for j in profile.joints]
            actuator = TorqueConfig.from_profile(profile).actuator
            chain = MitMotorChain(
                ids, actuator, links.peer_channel(can_channel), links.UDP_INTERFACE
            ).start()
            stack.callback(chain.stop)
        else:
            emulator = (
                "--profile",
                str(profile_path),
                "--channel",
                links.peer_channel(can_channel),
            )
            stack.enter_context(
                started("climbd.drivers.sim.mit_motors", *emulator, ready=emulator[-1])
            )
        listen = links.peer_channel(bridge_channel)
        bridge = stack.enter_context(
            started(
                "climbd.drivers.torque.bridge",
                *("--profile", str(profile_path), "--interface", links.UDP_INTERFACE),
                *("--channel", can_channel, "--listen", listen, "--watchdog", str(watchdog)),
                ready=listen,
            )
        )
        bus = BridgeJointBus(profile, bridge_channel)
        stack.callback(bus.close)
        yield chain, bridge, bus


def drive(bus: BridgeJointBus, goal: np.ndarray, cycles: int = 600, **command) -> float:
    """Largest joint error (rad) after commanding ``goal`` once a millisecond."""
    for _ in range(cycles):
        bus.read()
        bus.write(JointCommand(position=goal.tolist(), **command))
        time.sleep(0.001)
    time.sleep(0.01)
    bus.read()
    return float(np.max(np.abs(np.array(bus.read().position) - goal)))


def test_the_bridge_serves_the_motors_to_the_control_role(robots) -> None:
    with bridged(robots / "qingzhui.toml") as (chain, bridge, bus):
        bus.open()
        bus.torque(True)
        assert drive(bus, np.linspace(-0.4, 0.4, 18)) < 0.01
        assert all(m.motor_mode for m in chain.motors.values())
        bus.torque(False)
        drive(bus, np.zeros(18), cycles=20)  # the emulator's thread takes the frames
        assert not any(m.motor_mode for m in chain.motors.values())
        bus.close()
        bridge.terminate()
        assert bridge.wait(10) == 0


@pytest.mark.parametrize("policy", ["hold", "torque_off"])
def test_a_silent_control_role_gets_the_estop_policy(robots, tmp_path, policy) -> None:
    """Commands stop (the control role died): after the watchdog the motors hold the last
    commanded pose with its velocity zeroed, or leave motor mode, as the profile says; the
    control role's next command is refused and it hears what happened."""
    held = {"hold": "holding the last commanded pose", "torque_off": "torque off"}
    text = (robots / "qingzhui.toml").read_text()
    assert 'estop_policy = "hold"' in text
    profile_path = tmp_path / "qingzhui.toml"
    profile_path.write_text(text.replace('estop_policy = "hold"', f'estop_policy = "{policy}"'))
    with bridged(profile_path, WATCHDOG) as (chain, _, bus):
        bus.open()
        bus.torque(True)
        time.sleep(2 * WATCHDOG)  # armed by the first command: a slow first tick is no fault
        goal = np.full(18, 0.2)
        drive(bus, goal, cycles=50, velocity=[0.5] * 18)
        assert all(m.command.velocity > 0.4 for m in chain.motors.values())
        time.sleep(5 * WATCHDOG)
        motors = chain.motors.values()
        if policy == "torque_off":
            assert not any(m.motor_mode for m in motors)
        else:
            assert all(m.motor_mode for m in motors)
            assert all(abs(m.command.velocity) < 0.05 for m in motors)
            assert [m.command.position for m in motors] == pytest.approx(goal, abs=1e-3)
        bus.write(JointCommand(position=[0.0] * 18))  # the silent role's next command is refused
        with pytest.raises(DriverError, match=f"no request for 200 ms: {held[policy]}"):
            for _ in range(200):
                bus.read()
                time.sleep(0.002)
        time.sleep(0.05)
        assert [m.command is None or m.command.position for m in motors] != pytest.approx(
            np.zeros(18), abs=1e-3
        )


def test_a_bridge_gone_silent_is_lost_joints(robots) -> None:
    """The bridge process dies: every joint is reported lost after ``lost_after`` reads."""
    profile = profiles.load(robots / "qingzhui.toml")
    with bridged(robots / "qingzhui.toml") as (_, bridge, bus):
        bus.open()
        bridge.kill()
        bridge.wait(10)
        for _ in range(profile.bus.lost_after + 1):
            with contextlib.suppress(DriverError):  # the refused port may be named first
                bus.read()
        assert all(h.lost for h in bus.health())


def test_a_bus_off_behind_the_bridge_reaches_the_control_role(robots) -> None:
    with bridged(robots / "qingzhui.toml") as (chain, _, bus):
        bus.open()
        chain.bus_off()
        with pytest.raises(DriverError, match="torque bridge on .*: CAN bus-off"):
            for _ in range(200):
                bus.read()
                time.sleep(0.002)


def test_a_malformed_request_is_dropped_and_the_bridge_serves_on(robots) -> None:
    """A datagram that is no request is dropped; a NaN command is refused before it is sent."""
    with bridged(robots / "qingzhui.toml") as (_, bridge, bus):
        bus.open()
        bus.sock.send(b"\x93not a request")
        goal = [0.0] * 18
        goal[4] = float("nan")
        with pytest.raises(DriverError, match="command position of lf_thigh is not finite"):
            bus.write(JointCommand(position=goal))
        bus.torque(True)
        assert drive(bus, np.zeros(18), cycles=100) < 0.01
        assert bridge.poll() is None


def test_no_bridge_is_a_clear_error(robots) -> None:
    bus = BridgeJointBus(profiles.load(robots / "qingzhui.toml"), udp_channels(1)[0])
    with pytest.raises(DriverError, match="torque bridge"):
        bus.open()
    with pytest.raises(DriverError, match="no channel"):
        BridgeJointBus.from_profile(profiles.load(robots / "qingzhui.toml"))


def test_one_khz_loop_stands_qingzhui_through_the_bridge(robots) -> None:
    with bridged(robots / "qingzhui.toml", motors_in_process=False) as (_, _, bus):
        bus.open()
        assert_stands_at_one_khz(profiles.load(robots / "qingzhui.toml"), bus)
