"""Swing-foot profiles over normalised swing time tau in [0, 1].

Horizontal progress is the quintic ``s = 10 tau^3 - 15 tau^4 + 6 tau^5`` (s(0) = 0, s(1) = 1,
zero velocity and acceleration at both ends); the lift is ``64 tau^3 (1 - tau)^3`` (peak 1 at
tau = 1/2, zero height, velocity and acceleration at both ends). Both are applied relative to
the ground, so the foot leaves and touches down at rest on the ground.
"""

from __future__ import annotations

import numpy as np


def progress(tau: float | np.ndarray) -> float | np.ndarray:
    """Quintic horizontal progress from lift-off (0) to touch-down (1)."""
    return tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau))


def lift(tau: float | np.ndarray) -> float | np.ndarray:
    """Normalised height above the lift-off/touch-down line: 0 at the ends, 1 mid-swing."""
    u = tau * (1.0 - tau)
    return 64.0 * u * u * u
