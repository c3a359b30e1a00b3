"""Driver interfaces (JointBus, Camera, Imu) and an in-memory fake of each.

The fakes follow ros2_control's generic mock system: a command echoes back as state through
a first-order lag. They serve unit tests of what sits above a driver, never of a driver.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from daemon.messages import JointCommand, JointHealth, JointState
from daemon.profile import CameraConfig, Profile


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
    z forward) at ``timestamp`` (device clock, s).
    """

    depth: np.ndarray
    depth_scale: float
    intrinsics: Intrinsics
    extrinsics: np.ndarray
    timestamp: float
    number: int = 0


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


@dataclass
class FakeJointBus:
    """In-memory joint bus: state follows commands through a first-order lag ``tau`` (s).

    ``freeze`` stops feedback from moving; ``fail_reads``/``fail_writes`` make the next N
    calls raise DriverError; ``lost`` marks joints as not answering; ``temperature`` sets
    per-joint temperatures for health tests.
    """

    profile: Profile
    tau: float = 0.02
    initial: np.ndarray | None = None
    clock: object = time.monotonic
    freeze: bool = False
    fail_reads: int = 0
    fail_writes: int = 0
    lost: set[int] = field(default_factory=set)
    is_open: bool = False
    torque_on: bool = False

    def __post_init__(self) -> None:
        n = len(self.profile.joints)
        self.names = self.profile.joint_names
        self.position = np.zeros(n) if self.initial is None else np.array(self.initial, float)
        self.velocity = np.zeros(n)
        self.goal = self.position.copy()
        self.temperature = np.full(n, 35.0)
        s = self.profile.safety
        self.voltage = np.full(n, (s.min_voltage + s.max_voltage) / 2)
        self.writes = 0
        self._last = None

    @classmethod
    def from_profile(cls, profile: Profile, **options) -> FakeJointBus:
        return cls(profile, **options)

    def open(self) -> None:
        self.is_open = True
        self._last = self.clock()

    def _advance(self) -> None:
        now = self.clock()
        dt = 0.0 if self._last is None else max(0.0, now - self._last)
        self._last = now
        if self.freeze or not self.torque_on:
            self.velocity[:] = 0.0
            return
        alpha = 1.0 - math.exp(-dt / self.tau) if self.tau > 0 else 1.0
        step = alpha * (self.goal - self.position)
        self.position += step
        self.velocity = step / dt if dt > 0 else np.zeros_like(step)

    def read(self) -> JointState:
        if not self.is_open:
            raise DriverError("fake joint bus: read before open()")
        if self.fail_reads:
            self.fail_reads -= 1
            raise DriverError("fake joint bus: injected read error")
        self._advance()
        return JointState(
            stamp=self.clock(),
            names=self.names,
            position=self.position.tolist(),
            velocity=self.velocity.tolist(),
            effort=[0.0] * len(self.names),
        )

    def write(self, command: JointCommand) -> None:
        if not self.is_open:
            raise DriverError("fake joint bus: write before open()")
        if self.fail_writes:
            self.fail_writes -= 1
            raise DriverError("fake joint bus: injected write error")
        if len(command.position) != len(self.names):
            raise DriverError(
                f"fake joint bus: command has {len(command.position)} positions, "
                f"bus has {len(self.names)} joints"
            )
        goal = np.asarray(command.position, float)
        keep = list(self.lost)
        goal[keep] = self.goal[keep]
        self.goal = goal
        self.writes += 1

    def torque(self, on: bool) -> None:
        self.torque_on = on
        if on:
            self.goal = self.position.copy()

    def health(self) -> list[JointHealth]:
        return [
            JointHealth(
                name=n,
                temperature=float(self.temperature[i]),
                voltage=float(self.voltage[i]),
                lost=i in self.lost,
            )
            for i, n in enumerate(self.names)
        ]

    def close(self) -> None:
        self.is_open = False


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


@dataclass
class FakeCamera:
    """Yields pre-made depth images in a loop: for tests of what sits above a camera."""

    images: list[np.ndarray]
    intrinsics: Intrinsics
    extrinsics: np.ndarray
    depth_scale: float = 0.001
    period: float = 1 / 30
    is_open: bool = False

    def open(self) -> None:
        self.is_open = True

    def frames(self) -> Iterator[DepthFrame]:
        n = 0
        while self.is_open:
            yield DepthFrame(
                depth=self.images[n % len(self.images)],
                depth_scale=self.depth_scale,
                intrinsics=self.intrinsics,
                extrinsics=self.extrinsics,
                timestamp=n * self.period,
                number=n,
            )
            n += 1

    def close(self) -> None:
        self.is_open = False


@dataclass
class FakeImu:
    """A level, still IMU: zero rates and gravity along +z of the body."""

    clock: object = time.monotonic

    def read(self) -> ImuSample:
        return ImuSample(self.clock(), np.zeros(3), np.array([0.0, 0.0, 9.80665]))
