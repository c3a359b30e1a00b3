"""Hardware interfaces every driver implements and everything above a driver uses.

``JointBus``, ``Camera`` and ``Imu`` are the seams of ros2_control's hardware interfaces: the
runtime and the algorithms see only these types, in SI units and the body frame; a driver
converts its device's units at its own boundary.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from climbd.daemon.contract.messages import BusSchedule, JointCommand, JointHealth, JointState
from climbd.daemon.contract.profile import CameraConfig


class DriverError(RuntimeError):
    """A device problem the safety supervisor must hear about; the message names the device."""


@runtime_checkable
class JointBus(Protocol):
    """The joints of one robot, in profile order, in SI units at this boundary."""

    def open(self) -> None: ...

    def read(self) -> JointState: ...

    def write(self, command: JointCommand) -> None: ...

    def torque(self, on: bool) -> None: ...

    def health(self) -> list[JointHealth]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a depth stream (pixels); distortion is ignored for depth."""

    width: int
    height: int
    fx: float
    fy: float
    ppx: float
    ppy: float


@dataclass(frozen=True)
class DepthFrame:
    """One depth image: uint16 depth × ``depth_scale`` = metres; 0 means no return.

    ``extrinsics`` is the 4×4 camera-to-body transform (optical frame: x right, y down,
    z forward) at ``timestamp`` (s, the control role's clock: the host's monotonic clock, or
    simulated time in lock-step; drivers move device stamps onto it).
    """

    depth: np.ndarray
    depth_scale: float
    intrinsics: Intrinsics
    extrinsics: np.ndarray
    timestamp: float
    number: int = 0


@dataclass
class CameraHealth:
    """What the safety supervisor and health topic need: link state and frame accounting."""

    connected: bool = False
    frames: int = 0
    dropped: int = 0
    reconnects: int = 0
    last_error: str = ""


@runtime_checkable
class Camera(Protocol):
    """A depth camera: ``frames()`` yields frames until ``close()``."""

    def open(self) -> None: ...

    def frames(self) -> Iterator[DepthFrame]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class ImuSample:
    """Angular velocity (rad/s), linear acceleration (m/s², incl. gravity), body frame."""

    timestamp: float
    gyro: np.ndarray
    accel: np.ndarray


@runtime_checkable
class Imu(Protocol):
    def read(self) -> ImuSample: ...


def mount_extrinsics(camera: CameraConfig) -> np.ndarray:
    """4×4 camera-optical-to-body transform from the profile mount (tilt down about body y)."""
    optical_to_forward = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    m = camera.mount
    tilt, yaw, roll = np.radians([m.tilt_deg, m.yaw_deg, m.roll_deg])
    rx = np.array(
        [[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]]
    )
    ry = np.array(
        [[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0], [-math.sin(tilt), 0, math.cos(tilt)]]
    )
    rz = np.array(
        [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    )
    t = np.eye(4)
    t[:3, :3] = rz @ ry @ rx @ optical_to_forward
    t[:3, 3] = m.position
    return t


# Optional abilities: a driver declares one by implementing it; the runtime checks each once,
# at start-up, with isinstance (ros2_control's optional command and state interfaces).


@runtime_checkable
class CompliantServos(Protocol):
    """Servos that yield under load (a compliance slope or margin, as Dynamixel AX/MX have):
    ``compliant`` says whether this bus runs them so, and the controller then offsets stance
    goals by the sag their stiffness predicts."""

    compliant: bool


@runtime_checkable
class ClearableFaults(Protocol):
    """A joint bus that can clear latched servo faults (an explicit operator reset); returns
    the names of the joints it brought back."""

    def clear_faults(self) -> list[str]: ...


@runtime_checkable
class ServedBetweenTicks(Protocol):
    """A joint bus that takes its replies between ticks, until ``deadline`` (monotonic s)."""

    def serve_until(self, deadline: float) -> None: ...


@runtime_checkable
class ReportsSchedule(Protocol):
    """A joint bus that reads its joints on a schedule (not all every tick) and reports it."""

    def schedule(self) -> BusSchedule: ...


@runtime_checkable
class CountsSent(Protocol):
    """A joint bus that counts what it sent, so a lock-step twin can wait until its emulated
    bus has handled all of it."""

    sent: int


@runtime_checkable
class ReportsCameraHealth(Protocol):
    """A camera that reports its link state and frame accounting."""

    def health(self) -> CameraHealth: ...
