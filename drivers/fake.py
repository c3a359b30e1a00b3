"""In-memory fakes of the hardware interfaces (JointBus, Camera, Imu), and a flat-floor camera.

The fakes follow ros2_control's generic mock system: a command echoes back as state through
a first-order lag. They serve unit tests of what sits above a driver, never of a driver.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from climbd.daemon.contract.hardware import (
    DepthFrame,
    DriverError,
    ImuSample,
    Intrinsics,
    mount_extrinsics,
)
from climbd.daemon.contract.messages import JointCommand, JointHealth, JointState
from climbd.daemon.contract.profile import DriverConfig, Profile, gripper_servos


class FakeConfig(DriverConfig, forbid_unknown_fields=True, kw_only=True):
    """The fake joint bus has no keys of its own in the profile's ``[bus]`` table."""


@dataclass
class FakeJointBus:
    """In-memory joint bus: state follows commands through a first-order lag ``tau`` (s).

    ``freeze`` stops feedback from moving; ``fail_reads``/``fail_writes`` make the next N
    calls raise DriverError; ``lost`` marks joints as not answering; ``temperature`` sets
    per-joint temperatures for health tests. A profile's gripper servos hold as soon as they
    are closed, except on the legs in ``empty_grips`` (closed on nothing).
    """

    Config: ClassVar[type[DriverConfig]] = FakeConfig
    """Its keys of the profile's ``[bus]`` table: none."""

    profile: Profile
    tau: float = 0.02
    initial: np.ndarray | None = None
    clock: object = time.monotonic
    freeze: bool = False
    fail_reads: int = 0
    fail_writes: int = 0
    lost: set[int] = field(default_factory=set)
    empty_grips: set[int] = field(default_factory=set)
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
        legs = len(self.profile.legs)
        self.grip: list[bool] | None = [False] * legs if gripper_servos(self.profile) else None
        """The grippers as the last command left them (None: the profile has none)."""

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
            holding=None
            if self.grip is None
            else [closed and leg not in self.empty_grips for leg, closed in enumerate(self.grip)],
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
        if self.grip is not None and command.grip is not None:
            self.grip = list(command.grip)
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


class FloorCamera:
    """A test source: the profile camera looking at flat ground ``height`` m below the body.

    Depth is exact ray-plane intersection from the mount's pose and nominal intrinsics, paced at
    the camera's frame rate with monotonic timestamps: the perception path runs as with a camera.
    """

    def __init__(self, camera, intrinsics: Intrinsics, height: float, depth_scale: float = 1e-3):
        self.config = camera
        self.intrinsics = intrinsics
        self.extrinsics = mount_extrinsics(camera)
        self.depth_scale = depth_scale
        self.period = 1.0 / camera.fps
        self.depth = self._render(height)
        self._open = threading.Event()

    def _render(self, height: float) -> np.ndarray:
        k = self.intrinsics
        u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
        rays = np.stack([(u - k.ppx) / k.fx, (v - k.ppy) / k.fy, np.ones(u.shape)], axis=-1)
        rot, origin = self.extrinsics[:3, :3], self.extrinsics[:3, 3]
        down = rays @ rot[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (-height - origin[2]) / down
        valid = (down < 0) & (z > self.config.min_range) & (z < self.config.max_range)
        return np.where(valid, np.round(z / self.depth_scale), 0).astype(np.uint16)

    def open(self) -> None:
        self._open.set()

    def frames(self) -> Iterator[DepthFrame]:
        n = 0
        next_at = time.monotonic()
        while self._open.is_set():
            time.sleep(max(0.0, next_at - time.monotonic()))
            next_at += self.period
            yield DepthFrame(
                self.depth, self.depth_scale, self.intrinsics, self.extrinsics, time.monotonic(), n
            )
            n += 1

    def close(self) -> None:
        self._open.clear()
