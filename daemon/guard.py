"""The limit guard: the last check on every joint command before it reaches a driver.

Ruckig's community edition ignores position limits, so the guard clamps each command into
the profile's position limits and reports which joints it clamped. A command with a wrong
length or a non-finite value is rejected outright (GuardError): nothing sensible can be
sent, and the controller must hold.
"""

from __future__ import annotations

import math

import numpy as np

from daemon.profile import Profile


class GuardError(ValueError):
    """A joint command the guard refuses; the message names the joints."""


class Guard:
    """Position-limit clamp and sanity check of joint commands for ``profile``."""

    def __init__(self, profile: Profile) -> None:
        joints = profile.joints
        self.names = [j.name for j in joints]
        self.lower = np.array([j.limits.lower for j in joints], float)
        self.upper = np.array([j.limits.upper for j in joints], float)
        self.clamps = 0

    def clamp(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clamp ``q`` into the position limits: (clamped copy, per-joint clamped mask)."""
        q = np.asarray(q, float)
        if q.shape != self.lower.shape:
            raise GuardError(f"joint command has shape {q.shape}, expected ({self.lower.size},)")
        if not math.isfinite(q.sum()):
            bad = [self.names[i] for i in np.flatnonzero(~np.isfinite(q))]
            if bad:
                raise GuardError(f"non-finite joint command for {', '.join(bad)}")
        out = np.minimum(np.maximum(q, self.lower), self.upper)
        clamped = out != q
        if clamped.any():
            self.clamps += 1
        return out, clamped
