"""JointBus for torque-controlled legs: MIT-mode actuators on one or more CAN buses (python-can).

Per joint the command is position, velocity, feed-forward torque, kp and kd; the state back
is position, velocity and the measured torque, all at the actuator's output shaft about its
encoder zero (the joint convention of every driver; daemon/algorithms/kinematics.py maps it to the
leg's kinematic angles with the profile's zero offsets and directions). A tick writes one
frame per motor; each answers once, and ``read`` collects the answers to the last write
(polling with zero-gain frames, which motors out of motor mode ignore, when torque is off).
Between ticks, ``serve_until`` takes the replies as they arrive, on the loop's own thread (a
thread of their own would wait on the GIL while the tick computes), so the read finds them
filed.
"""

from __future__ import annotations

import logging
import select
import time

import can
import numpy as np

from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import JointCommand, JointHealth, JointState
from climbd.daemon.contract.profile import Profile, with_bus_options
from climbd.drivers.torque.config import TorqueConfig
from climbd.drivers.torque.links import Frame, FrameLink, open_link
from climbd.drivers.torque.mit import (
    CAN_ERR_BUSOFF,
    ENTER_MOTOR_MODE,
    EXIT_MOTOR_MODE,
    ProtocolError,
    check_reply,
    pack_commands,
    unpack_replies,
)

log = logging.getLogger("climbd.torque")

OPEN_TIMEOUT = 0.1
"""Seconds every motor has to answer at open() before it is reported missing."""
IDLE_MARGIN = 0.0001
"""Seconds before the next tick's deadline that ``serve_until`` stops taking replies, so
filing a burst of them does not make the tick late."""


def waiting_for_replies(profile: Profile, wait: float) -> Profile:
    """The profile with its reply timeout raised to at least ``wait`` s: for a driver that can
    afford to wait (a bridge process, motors emulated in the same interpreter)."""
    timeout = TorqueConfig.from_profile(profile).reply_timeout
    return with_bus_options(profile, reply_timeout=max(timeout, wait))


def joint_channels(profile: Profile, channels: list[str]) -> list[str]:
    """The CAN channel of every joint, in joint order: leg i's joints on channel i mod n."""
    return [channels[i % len(channels)] for i, leg in enumerate(profile.legs) for _ in leg.joints]


class MitJointBus:
    """The joints of a torque-controlled robot, behind MIT-mode actuators on CAN."""

    Config = TorqueConfig
    """Its keys of the profile's ``[bus]`` table."""

    def __init__(
        self,
        profile: Profile,
        channels: list[str] | None = None,
        interface: str | None = None,
    ) -> None:
        cfg = TorqueConfig.from_profile(profile)
        self.profile = profile
        self.config = cfg
        self.ranges = cfg.actuator
        self.interface = interface or cfg.can_interface
        legs_channels = channels or cfg.channels
        joints = profile.joints
        self.names = [j.name for j in joints]
        self.ids = np.array([j.id for j in joints])
        self.channel_of = joint_channels(profile, legs_channels)
        self.joints_on = {
            c: [i for i, joint_channel in enumerate(self.channel_of) if joint_channel == c]
            for c in dict.fromkeys(self.channel_of)
        }
        """Joint indices by channel, in joint order."""
        self._ids_on = {c: [int(self.ids[i]) for i in js] for c, js in self.joints_on.items()}
        self.index = {int(m): i for i, m in enumerate(self.ids)}
        n = len(joints)
        self.position = np.zeros(n)
        self.velocity = np.zeros(n)
        self.effort = np.zeros(n)
        self.missed = np.zeros(n, int)
        self.errors: list[list[str]] = [[] for _ in range(n)]
        self.lost_after = profile.bus.lost_after
        self.reply_timeout = cfg.reply_timeout
        self.kp, self.kd = cfg.kp, cfg.kd
        self.master_id = cfg.master_id
        self.links: dict[str, FrameLink] = {}
        self._readable: dict[int, str] = {}
        """Channels by their links' descriptors; empty unless every link has one."""
        self._failure: DriverError | None = None
        """What went wrong between ticks, for the next read to raise."""
        self.torque_on = False
        self._answered = np.zeros(n, bool)
        self._unanswered = dict.fromkeys(self.joints_on, 0)
        """Per channel, the motors yet to answer the last frames sent."""
        self._expecting = False
        self._last_frames: list[bytes] | None = None
        self.sent = 0
        """Frames put on the buses since construction (a lock-step twin waits for them)."""
        self.late_reads = 0
        """Reads that found some motor's reply to the last write still on the wire (its state
        then comes from an earlier reply; with ``reply_timeout`` 0 the next read takes it)."""

    @classmethod
    def from_profile(cls, profile: Profile, port: str | None = None, **options) -> MitJointBus:
        """``port`` names one CAN channel for all legs (e.g. a vcan or a virtual channel)."""
        return cls(profile, [port] if port else None, **options)

    # --- lifecycle --------------------------------------------------------------------

    def open(self) -> None:
        for channel in self.joints_on:
            try:
                self.links[channel] = open_link(self.interface, channel)
            except (can.CanError, OSError, ValueError) as e:
                self.close()
                raise DriverError(
                    f"cannot open CAN {self.interface} channel {channel!r}: {e}"
                ) from e
        fds = {link.fileno(): channel for channel, link in self.links.items()}
        self._readable = {} if None in fds else fds
        self._send_all(self._zero_gain())
        self._collect(OPEN_TIMEOUT)
        self._expecting = False
        if not self._answered.all():
            missing = ", ".join(
                f"motor {self.ids[i]} ({self.names[i]}) on {self.channel_of[i]}"
                for i in np.flatnonzero(~self._answered)
            )
            self.close()
            raise DriverError(f"no reply within {OPEN_TIMEOUT * 1e3:.0f} ms from {missing}")

    def close(self) -> None:
        for link in self.links.values():
            link.close()
        self.links.clear()
        self._readable = {}

    def torque(self, on: bool) -> None:
        """Enter (on) or leave (off) motor mode on every actuator."""
        frame = ENTER_MOTOR_MODE if on else EXIT_MOTOR_MODE
        self._send_all([frame] * len(self.names))
        self.torque_on = on
        self._last_frames = None

    # --- cycle ------------------------------------------------------------------------

    def _zero_gain(self) -> list[bytes]:
        """Frames that ask every motor for its state and, in motor mode, hold it limp."""
        zero = [0.0] * len(self.names)
        return pack_commands(self.position, zero, zero, zero, zero, self.ranges)

    def write(self, command: JointCommand) -> None:
        n = len(self.names)
        if len(command.position) != n:
            raise DriverError(f"command has {len(command.position)} positions, bus has {n} joints")
        v = command.velocity or [0.0] * n
        t = command.effort or [0.0] * n
        kp = command.kp or [self.kp] * n
        kd = command.kd or [self.kd] * n
        try:
            frames = pack_commands(command.position, v, kp, kd, t, self.ranges, self.names)
        except ProtocolError as e:
            raise DriverError(f"torque joint bus: {e}") from e
        self._send_all(frames)
        self._last_frames = frames

    def read(self) -> JointState:
        if not self.links:
            raise DriverError("torque joint bus: read before open()")
        failure, self._failure = self._failure, None
        if failure is not None:
            raise failure
        if not self._expecting:
            frames = self._last_frames if self.torque_on and self._last_frames else None
            self._send_all(frames or self._zero_gain())
        self._collect(self.reply_timeout)
        self.late_reads += not self._answered.all()
        self.missed = np.where(self._answered, 0, self.missed + 1)
        self._expecting = False
        return JointState(
            stamp=time.monotonic(),
            names=self.names,
            position=self.position.tolist(),
            velocity=self.velocity.tolist(),
            effort=self.effort.tolist(),
        )

    def health(self) -> list[JointHealth]:
        return [
            JointHealth(
                name=name,
                error=len(self.errors[i]),
                errors=list(self.errors[i]),
                lost=bool(self.missed[i] >= self.lost_after),
            )
            for i, name in enumerate(self.names)
        ]

    def serve_until(self, deadline: float) -> None:
        """The control loop's idle time before ``deadline`` (monotonic s): take the replies to
        the last write as they arrive, until all are in or ``IDLE_MARGIN`` before the deadline;
        a failure is kept for the next read. Returns at once for links ``select`` cannot
        wait on."""
        if not self._readable or not self._expecting:
            return
        replies: dict[int, bytes] = {}
        try:
            while not self._answered.all():
                wait = deadline - IDLE_MARGIN - time.monotonic()
                if wait <= 0.0:
                    break
                ready, _, _ = select.select(list(self._readable), [], [], wait)
                for fd in ready:
                    channel = self._readable[fd]
                    for frame in self._receive(channel, 0.0):
                        self._take(channel, frame, replies)
        except DriverError as e:
            self._failure = self._failure or e
        if replies:
            self._decode(replies)

    # --- wire -------------------------------------------------------------------------

    def _send_all(self, frames: list[bytes]) -> None:
        self._answered[:] = False
        for channel, joints in self.joints_on.items():
            self._unanswered[channel] = len(joints)
            try:
                self.links[channel].send(self._ids_on[channel], [frames[i] for i in joints])
            except can.CanError as e:
                raise DriverError(f"CAN send on {channel}: {e}") from e
            self.sent += len(joints)
        self._expecting = True

    def _collect(self, timeout: float) -> None:
        """Take every reply waiting, then wait up to ``timeout`` for the missing ones (on each
        channel only for its own motors); decode the replies together."""
        deadline = time.monotonic() + timeout
        replies: dict[int, bytes] = {}
        for channel in self.links:
            while True:
                pending = self._unanswered[channel]
                wait = max(0.0, deadline - time.monotonic()) if pending else 0.0
                frames = self._receive(channel, wait)
                if not frames:
                    break
                for frame in frames:
                    self._take(channel, frame, replies)
        if replies:
            self._decode(replies)

    def _receive(self, channel: str, timeout: float) -> list[Frame]:
        """The frames waiting on ``channel`` (after up to ``timeout`` s); failures named."""
        try:
            return self.links[channel].receive(timeout)
        except can.CanError as e:
            raise DriverError(f"CAN receive on {channel}: {e}") from e

    def _take(self, channel: str, frame: Frame, replies: dict[int, bytes]) -> None:
        """File one frame: a bus-off raises, a reply of a known motor is kept by joint."""
        if frame.error:
            if frame.can_id & CAN_ERR_BUSOFF:
                raise DriverError(f"CAN bus-off on {self.interface} channel {channel!r}")
            return
        if frame.can_id != self.master_id:
            return
        data = frame.data
        i = self.index.get(data[0]) if data else None
        if i is None:
            log.warning("reply from unknown motor %s on %s", data[:1].hex(), channel)
            return
        try:
            check_reply(data)
        except ProtocolError as e:
            self.errors[i] = [f"bad reply: {e}"]
            return
        replies[i] = data
        if not self._answered[i]:
            self._answered[i] = True
            self._unanswered[self.channel_of[i]] -= 1

    def _decode(self, replies: dict[int, bytes]) -> None:
        """The state of every joint that answered; a reply at the end of a range is flagged."""
        joints = list(replies)
        _, position, velocity, torque = unpack_replies(b"".join(replies.values()), self.ranges)
        r = self.ranges
        for i, p, v in zip(joints, position, velocity, strict=True):
            self.errors[i] = ["range"] if abs(p) >= r.position or abs(v) >= r.velocity else []
        self.position[joints] = position
        self.velocity[joints] = velocity
        self.effort[joints] = torque
