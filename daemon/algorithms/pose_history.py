"""Where the body was at time t: a bounded history of body poses, interpolated between them.

A depth frame is taken tens of milliseconds before perception gets it; a turning or walking
robot has moved since. Perception pairs each frame with the pose at the frame's own stamp:
position interpolated linearly and orientation by SLERP between the two poses around it, or
extrapolated from the last two for a frame a little newer than the last pose (lock-step twin
frames, transport reordering). A frame outside the history is refused with its reason, never
paired with a pose it was not taken in. Stamps are on the control role's clock.
"""

from __future__ import annotations

import bisect
import enum
from collections import deque

from climbd.daemon.contract.geometry import slerp
from climbd.daemon.contract.messages import BodyState

SPAN = 3.0
"""Seconds of poses kept: well beyond a camera's and the network's delay (50-150 ms)."""
AHEAD = 0.05
"""Seconds a frame may be newer than the last pose and still be paired, by extrapolation."""


class Refusal(enum.Enum):
    """Why a frame was given no pose; the names are the reasons counted in health."""

    NO_POSE = "no_pose"
    """No body state has arrived yet (or the stream has stopped for longer than the span)."""
    TOO_OLD = "too_old"
    """The frame is older than the oldest pose kept."""
    TOO_NEW = "too_new"
    """The frame is newer than the last pose by more than the margin: the pose stream lags
    or has stopped, or the camera's clock is not the control role's."""
    OUT_OF_ORDER = "out_of_order"
    """The frame is older than one already paired: a camera clock that went back."""
    NOT_FINITE = "not_finite"
    """The frame's stamp is NaN or infinite."""


class PoseRefused(Exception):
    """A frame for which the history has no pose; ``reason`` says why."""

    def __init__(self, reason: Refusal, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


class PoseHistory:
    """Body poses of the last ``span`` seconds, oldest first; not thread-safe (callers lock)."""

    def __init__(self, span: float = SPAN, ahead: float = AHEAD) -> None:
        self.span = span
        self.ahead = ahead
        self._stamps: deque[float] = deque()
        self._poses: deque[BodyState] = deque()
        self._last_frame = float("-inf")
        self.out_of_order_poses = 0
        """Body states older than the newest kept, dropped (a reordered or replayed stream)."""
        self.restarts = 0
        """Times the pose stream went back by more than the span (the control role restarted
        its clock) and the history began anew."""

    def __len__(self) -> int:
        return len(self._poses)

    @property
    def newest(self) -> float | None:
        """Stamp of the newest pose, or None before the first."""
        return self._stamps[-1] if self._stamps else None

    def add(self, body: BodyState) -> None:
        """Keep ``body``; drop poses older than the span before it, and ``body`` itself if it
        is not newer than the newest kept; a stream that went back beyond the span has
        restarted and the history begins anew."""
        if self._stamps and body.stamp < self._stamps[-1] - self.span:
            self._stamps.clear()
            self._poses.clear()
            self._last_frame = float("-inf")
            self.restarts += 1
        if self._stamps and body.stamp <= self._stamps[-1]:
            self.out_of_order_poses += 1
            return
        self._stamps.append(body.stamp)
        self._poses.append(body)
        horizon = body.stamp - self.span
        while len(self._stamps) > 2 and self._stamps[1] <= horizon:
            self._stamps.popleft()
            self._poses.popleft()

    def at(self, t: float) -> BodyState:
        """The body pose at ``t``, or PoseRefused with the reason there is none."""
        if t != t or t in (float("inf"), float("-inf")):
            raise PoseRefused(Refusal.NOT_FINITE, f"frame stamp {t}")
        if not self._poses:
            raise PoseRefused(Refusal.NO_POSE, "no body state received yet")
        if t < self._last_frame:
            raise PoseRefused(
                Refusal.OUT_OF_ORDER,
                f"frame at {t:.3f} s is older than the last paired one ({self._last_frame:.3f} s)",
            )
        first, last = self._stamps[0], self._stamps[-1]
        if t > last + self.ahead:
            raise PoseRefused(
                Refusal.TOO_NEW,
                f"frame at {t:.3f} s is {t - last:.3f} s newer than the last body state "
                f"(margin {self.ahead:.3f} s)",
            )
        if t < first:
            raise PoseRefused(
                Refusal.TOO_OLD,
                f"frame at {t:.3f} s is older than the pose history ({first:.3f}-{last:.3f} s)",
            )
        self._last_frame = t
        if len(self._poses) == 1 or t == first:
            return self._stamped(self._poses[0] if t == first else self._poses[-1], t)
        i = min(bisect.bisect_left(self._stamps, t), len(self._stamps) - 1)
        a, b = self._poses[i - 1], self._poses[i]
        return interpolate(a, b, t)

    @staticmethod
    def _stamped(body: BodyState, t: float) -> BodyState:
        return BodyState(
            stamp=t,
            position=list(body.position),
            orientation=list(body.orientation),
            linear_velocity=list(body.linear_velocity),
            angular_velocity=list(body.angular_velocity),
            stance=list(body.stance),
        )


def interpolate(a: BodyState, b: BodyState, t: float) -> BodyState:
    """The pose at ``t`` on the motion from ``a`` to ``b``: linear in position and velocity,
    SLERP in orientation; ``t`` beyond ``b`` extrapolates the same motion."""
    s = (t - a.stamp) / (b.stamp - a.stamp)

    def lerp(u: list[float], v: list[float]) -> list[float]:
        return [x + s * (y - x) for x, y in zip(u, v, strict=True)]

    return BodyState(
        stamp=t,
        position=lerp(a.position, b.position),
        orientation=slerp(a.orientation, b.orientation, s),
        linear_velocity=lerp(a.linear_velocity, b.linear_velocity),
        angular_velocity=lerp(a.angular_velocity, b.angular_velocity),
        stance=list(b.stance if s >= 0.5 else a.stance),
    )
