"""The limit guard: the last check on every joint command before it reaches a driver.

Ruckig's community edition ignores position limits, so the guard clamps each command into
the profile's position limits, its velocity and feed-forward effort into their limits, and
counts the commands it clamped. A command with a wrong length or a non-finite value is
rejected outright (GuardError): nothing sensible can be sent, and the controller must hold.
"""

from __future__ import annotations

import math

import numpy as np

from climbd.daemon.contract.messages import JointCommand
from climbd.daemon.contract.profile import Profile


class GuardError(ValueError):
    """A joint command the guard refuses; the message names the joints."""


class Guard:
    """Position-limit clamp and sanity check of joint commands for ``profile``."""

    def __init__(self, profile: Profile) -> None:
        joints = profile.joints
        self.names = [j.name for j in joints]
        self.lower = np.array([j.limits.lower for j in joints], float)
        self.upper = np.array([j.limits.upper for j in joints], float)
        self._bounds = list(zip(self.lower.tolist(), self.upper.tolist(), strict=True))
        self._velocity = [j.limits.velocity for j in joints]
        self._effort = [j.limits.effort for j in joints]
        self.legs = len(profile.legs)
        self.clamps = 0

    def command(self, command: JointCommand) -> JointCommand:
        """``command`` with position, velocity and effort clamped into the profile's limits (in
        place, and returned); the last thing that touches a command before the driver writes it."""
        command.position = self.limit(command.position)
        command.velocity = self._symmetric(command.velocity, self._velocity, "velocity")
        command.effort = self._symmetric(command.effort, self._effort, "effort")
        if command.grip is not None and len(command.grip) != self.legs:
            raise GuardError(
                f"joint command grip has {len(command.grip)} flags, expected {self.legs} legs"
            )
        return command

    def _symmetric(
        self, values: list[float] | None, bounds: list[float], what: str
    ) -> list[float] | None:
        """``values`` clamped into ±``bounds``; None or empty (not commanded) stays as it is."""
        if not values:
            return values
        if len(values) != len(bounds):
            raise GuardError(
                f"joint command {what} has {len(values)} values, expected {len(bounds)}"
            )
        if not math.isfinite(sum(values)):
            bad = [n for n, x in zip(self.names, values, strict=True) if not math.isfinite(x)]
            raise GuardError(f"non-finite joint command {what} for {', '.join(bad)}")
        out = [b if x > b else -b if x < -b else x for x, b in zip(values, bounds)]  # noqa: B905
        if out != values:
            self.clamps += 1
        return out

    def clamp(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clamp ``q`` into the position limits: (clamped copy, per-joint clamped mask)."""
        q = np.asarray(q, float)
        if q.shape != self.lower.shape:
            raise GuardError(f"joint command has shape {q.shape}, expected ({self.lower.size},)")
        out = np.array(self.limit(q.tolist()))
        return out, out != q

    def limit(self, q: list[float]) -> list[float]:
        """``clamp`` on a list (the control tick's path): a new list inside the limits."""
        if len(q) != len(self._bounds):
            raise GuardError(
                f"joint command has shape ({len(q)},), expected ({len(self._bounds)},)"
            )
        if not math.isfinite(sum(q)):
            bad = [name for name, x in zip(self.names, q, strict=True) if not math.isfinite(x)]
            if bad:
                raise GuardError(f"non-finite joint command for {', '.join(bad)}")
        out = [
            lo if x < lo else hi if x > hi else x
            for x, (lo, hi) in zip(q, self._bounds, strict=True)
        ]
        if out != q:
            self.clamps += 1
        return out
