"""Per-joint jerk-limited smoothing of joint targets with ruckig (community edition).

Every tick the smoother plans, from its current state (position, velocity, acceleration),
a time-optimal trajectory to the target state within the profile's velocity, acceleration
and jerk limits, and advances one period along it; a new target replans from the current
state, so the command stays continuous up to jerk. Joints are planned independently
(``Synchronization.No``). Ruckig's community edition ignores position limits: the guard
clamps positions (daemon/guard.py).
"""

from __future__ import annotations

import numpy as np
import ruckig

from daemon.profile import Profile

_OK = (ruckig.Result.Working, ruckig.Result.Finished)
_MARGIN = 0.999
SNAP_VELOCITY = 1e-4
SNAP_ACCELERATION = 0.1


class SmoothingError(RuntimeError):
    """Ruckig refused to plan or failed; the message names the joint where ruckig says."""


class Smoother:
    """Ruckig over all joints of ``profile`` at period ``dt`` (s); ``scale`` derates velocity."""

    def __init__(self, profile: Profile, dt: float) -> None:
        if not dt > 0:
            raise ValueError(f"smoothing period must be > 0 s, got {dt}")
        joints = profile.joints
        self.names = [j.name for j in joints]
        self.n = len(joints)
        self.dt = dt
        self.v_max = np.array([j.limits.velocity for j in joints], float)
        self.a_max = np.array([j.limits.acceleration for j in joints], float)
        self.j_max = np.array([j.limits.jerk for j in joints], float)
        self._otg = ruckig.Ruckig(self.n, dt)
        self._inp = ruckig.InputParameter(self.n)
        self._out = ruckig.OutputParameter(self.n)
        self._inp.synchronization = ruckig.Synchronization.No
        self._a_target = self.a_max * _MARGIN
        self._half_inv_jerk = 0.5 / self.j_max
        self._inp.max_acceleration = self.a_max.tolist()
        self._inp.max_jerk = self.j_max.tolist()
        self._scale = 1.0
        self._apply_velocity_limit()
        self.position = np.zeros(self.n)
        self.velocity = np.zeros(self.n)
        self.acceleration = np.zeros(self.n)
        self.ready = False
        self.fallbacks = 0

    @property
    def scale(self) -> float:
        """Fraction (0, 1] of the profile's velocity limits in force (derating on overheat)."""
        return self._scale

    @scale.setter
    def scale(self, value: float) -> None:
        if not 0.0 < value <= 1.0:
            raise ValueError(f"smoothing scale must be in (0, 1], got {value}")
        self._scale = float(value)
        self._apply_velocity_limit()

    def _apply_velocity_limit(self) -> None:
        self.v_lim = self.v_max * self._scale
        self._inp.max_velocity = self.v_lim.tolist()

    def reset(
        self, q: np.ndarray, qd: np.ndarray | None = None, qdd: np.ndarray | None = None
    ) -> None:
        """Set the current state (e.g. the measured joints on entering a mode): no jump."""
        self.position = self._vector(q, "position")
        self.velocity = np.zeros(self.n) if qd is None else self._vector(qd, "velocity")
        self.acceleration = np.zeros(self.n) if qdd is None else self._vector(qdd, "acceleration")
        inp = self._inp
        inp.current_position = self.position.tolist()
        inp.current_velocity = self.velocity.tolist()
        inp.current_acceleration = self.acceleration.tolist()
        self._otg.reset()
        self.ready = True

    @staticmethod
    def _first_line(error: Exception) -> str:
        lines = [ln for ln in str(error).splitlines() if ln.strip()]
        return lines[0].strip() if lines else type(error).__name__

    def _vector(self, value: np.ndarray, what: str) -> np.ndarray:
        v = np.array(value, float).reshape(-1)
        if v.shape != (self.n,):
            raise SmoothingError(f"{what}: expected {self.n} joints, got {v.size}")
        if not np.isfinite(v).all():
            bad = [self.names[i] for i in np.flatnonzero(~np.isfinite(v))]
            raise SmoothingError(f"{what}: non-finite value for {', '.join(bad)}")
        return v

    def feasible_target(
        self, target_qd: np.ndarray, target_qdd: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Clip a target velocity/acceleration into a state ruckig accepts under the limits.

        The acceleration is bounded by the acceleration limit and the velocity by what can
        still be brought to zero acceleration without passing the velocity limit.
        """
        if target_qdd is None:
            qdd = np.zeros(self.n)
        else:
            qdd = np.minimum(np.maximum(target_qdd, -self._a_target), self._a_target)
        v_lim = np.maximum(self.v_lim * _MARGIN - qdd * qdd * self._half_inv_jerk, 0.0)
        return np.minimum(np.maximum(target_qd, -v_lim), v_lim), qdd

    def step(
        self,
        target_q: np.ndarray,
        target_qd: np.ndarray | None = None,
        target_qdd: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance one period towards the target state; returns the new position.

        Raises SmoothingError when ruckig fails (the controller then holds).
        """
        if not self.ready:
            raise SmoothingError("step() before reset(): the current joint state is unknown")
        inp, out = self._inp, self._out
        inp.target_position = self._vector(target_q, "target position").tolist()
        if target_qd is None and target_qdd is None:
            inp.target_velocity = [0.0] * self.n
            inp.target_acceleration = [0.0] * self.n
        else:
            qd = np.zeros(self.n) if target_qd is None else target_qd
            qd, qdd = self.feasible_target(qd, target_qdd)
            inp.target_velocity = qd.tolist()
            inp.target_acceleration = qdd.tolist()
        result, error = self._update()
        if result not in _OK:
            result, error = self._retry_from_rest()
        if result not in _OK:
            why = self._first_line(error) if error is not None else result.name
            raise SmoothingError(f"ruckig: {why}")
        out.pass_to_input(inp)
        self.position = np.array(out.new_position)
        self.velocity = np.array(out.new_velocity)
        self.acceleration = np.array(out.new_acceleration)
        return self.position

    def _update(self) -> tuple[ruckig.Result | None, Exception | None]:
        try:
            return self._otg.update(self._inp, self._out), None
        except ruckig.RuckigError as e:
            return None, e

    def _retry_from_rest(self) -> tuple[ruckig.Result | None, Exception | None]:
        """Replan with rounding-level motion (|v| < SNAP_VELOCITY, |a| < SNAP_ACCELERATION) zeroed.

        Ruckig's step-1 solver can fail on near-degenerate states (a ~1e-8 rad move with
        ~1e-5 rad/s left, at high jerk limits); from rest those joints plan fine. The change
        is far inside one tick of jerk (at 100 Hz: < 0.01 + 10 rad/s^3 of finite-difference jerk).
        """
        self.fallbacks += 1
        inp = self._inp
        v = np.array(inp.current_velocity)
        a = np.array(inp.current_acceleration)
        tiny = (np.abs(v) < SNAP_VELOCITY) & (np.abs(a) < SNAP_ACCELERATION)
        if not tiny.any():
            return self._update()
        inp.current_velocity = np.where(tiny, 0.0, v).tolist()
        inp.current_acceleration = np.where(tiny, 0.0, a).tolist()
        return self._update()
