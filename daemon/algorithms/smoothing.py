"""Per-joint jerk-limited smoothing of joint targets with ruckig (community edition).

Every tick the smoother plans, from its current state (position, velocity, acceleration),
a time-optimal trajectory to the target state within the profile's velocity, acceleration
and jerk limits, and advances one period along it; a new target replans from the current
state, so the command stays continuous up to jerk. Joints are planned independently
(``Synchronization.No``). Ruckig's community edition ignores position limits: the guard
clamps positions (daemon/algorithms/guard.py).
"""

from __future__ import annotations

import math

import numpy as np
import ruckig

from climbd.daemon.contract.profile import Profile

_OK = (ruckig.Result.Working, ruckig.Result.Finished)
_MARGIN = 0.999
SNAP = 0.05
"""Rounding-level motion, as a fraction of what the acceleration (velocity) and jerk
(acceleration) limits change in one tick, that a failed plan zeroes and replans from rest."""
NUDGE = 1e-6
"""Radians the target positions move along the current motion for a last replan: ruckig's
step-1 solver fails on isolated states that targets this close plan from; far below encoder
resolution (a 16-bit MIT encoder over ±12.5 rad: 3.8e-4 rad)."""


class SmoothingError(RuntimeError):
    """Ruckig refused to plan or failed; the message names the joint where ruckig says."""


class Smoother:
    """Ruckig over all joints of ``profile`` at period ``dt`` (s); ``scale`` derates velocity.

    The per-tick path (``advance``) works on plain lists: with 18 joints, numpy's per-call
    overhead would cost more than the clipping arithmetic it replaces.
    """

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
        self._a_target = (self.a_max * _MARGIN).tolist()
        self._half_inv_jerk = (0.5 / self.j_max).tolist()
        self._inp.max_acceleration = self.a_max.tolist()
        self._inp.max_jerk = self.j_max.tolist()
        self._zeros = [0.0] * self.n
        self._snap_velocity = SNAP * self.a_max * dt
        self._snap_acceleration = SNAP * self.j_max * dt
        self._scale = 1.0
        self._apply_velocity_limit()
        self._q = self._qd = self._qdd = self._zeros
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
        self._v_target = (self.v_lim * _MARGIN).tolist()

    @property
    def position(self) -> np.ndarray:
        """Joint positions of the current state (rad)."""
        return np.array(self._q)

    @property
    def velocity(self) -> np.ndarray:
        """Joint velocities of the current state (rad/s)."""
        return np.array(self._qd)

    @property
    def acceleration(self) -> np.ndarray:
        """Joint accelerations of the current state (rad/s^2)."""
        return np.array(self._qdd)

    def reset(
        self, q: np.ndarray, qd: np.ndarray | None = None, qdd: np.ndarray | None = None
    ) -> None:
        """Set the current state (e.g. the measured joints on entering a mode): no jump."""
        self._q = self._vector(q, "position")
        self._qd = self._zeros if qd is None else self._vector(qd, "velocity")
        self._qdd = self._zeros if qdd is None else self._vector(qdd, "acceleration")
        inp = self._inp
        inp.current_position = self._q
        inp.current_velocity = self._qd
        inp.current_acceleration = self._qdd
        self._otg.reset()
        self.ready = True

    @staticmethod
    def _first_line(error: Exception) -> str:
        lines = [ln for ln in str(error).splitlines() if ln.strip()]
        return lines[0].strip() if lines else type(error).__name__

    def _vector(self, value: list[float] | np.ndarray, what: str) -> list[float]:
        """``value`` as a new list of ``n`` finite floats; SmoothingError naming bad joints."""
        v = list(value) if type(value) is list else np.asarray(value, float).reshape(-1).tolist()
        if len(v) != self.n:
            raise SmoothingError(f"{what}: expected {self.n} joints, got {len(v)}")
        if not math.isfinite(sum(v)):
            bad = [name for name, x in zip(self.names, v, strict=True) if not math.isfinite(x)]
            if bad:
                raise SmoothingError(f"{what}: non-finite value for {', '.join(bad)}")
        return v

    def step(
        self,
        target_q: np.ndarray,
        target_qd: np.ndarray | None = None,
        target_qdd: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance one period towards the target state; returns the new position.

        Raises SmoothingError when ruckig fails (the controller then holds).
        """
        qd = None if target_qd is None else np.asarray(target_qd, float).tolist()
        qdd = None if target_qdd is None else np.asarray(target_qdd, float).tolist()
        if qd is None and qdd is not None:
            qd = self._zeros
        return np.array(self.advance(target_q, qd, qdd)[0])

    def advance(
        self,
        target_q: list[float],
        target_qd: list[float] | None = None,
        target_qdd: list[float] | None = None,
        duration: float | None = None,
    ) -> tuple[list[float], list[float]]:
        """``step`` on lists: (new position, new velocity). Without ``target_qd`` the target is
        at rest; a given target velocity and acceleration are first made feasible: the
        acceleration within its limit, the velocity within what can still be brought to zero
        acceleration without passing the velocity limit. With ``duration`` (s) every joint
        arrives together, that long after the motion to this target began (ruckig's time
        synchronisation; the same target and duration each tick continue one plan)."""
        if not self.ready:
            raise SmoothingError("step() before reset(): the current joint state is unknown")
        inp, out = self._inp, self._out
        inp.target_position = self._vector(target_q, "target position")
        inp.minimum_duration = duration
        inp.synchronization = (
            ruckig.Synchronization.No if duration is None else ruckig.Synchronization.Time
        )
        if target_qd is None:
            inp.target_velocity = inp.target_acceleration = self._zeros
        else:
            velocity, acceleration = [], []
            for qd, qdd, a_lim, v_max, h in zip(
                target_qd,
                target_qdd or self._zeros,
                self._a_target,
                self._v_target,
                self._half_inv_jerk,
                strict=True,
            ):
                qdd = -a_lim if qdd < -a_lim else a_lim if qdd > a_lim else qdd
                v_lim = v_max - qdd * qdd * h
                v_lim = v_lim if v_lim > 0.0 else 0.0
                velocity.append(-v_lim if qd < -v_lim else v_lim if qd > v_lim else qd)
                acceleration.append(qdd)
            inp.target_velocity = velocity
            inp.target_acceleration = acceleration
        result, error = self._update()
        if result not in _OK:
            result, error = self._retry_from_rest()
        if result not in _OK:
            result, error = self._retry_nudged()
        if result not in _OK:
            why = self._first_line(error) if error is not None else result.name
            raise SmoothingError(f"ruckig: {why}")
        out.pass_to_input(inp)
        self._q, self._qd, self._qdd = out.new_position, out.new_velocity, out.new_acceleration
        return self._q, self._qd

    def _update(self) -> tuple[ruckig.Result | None, Exception | None]:
        """One ruckig step; after a failure ruckig is reset so that the next call plans afresh.

        Ruckig replans only when the input differs from the last one it planned (which it
        advances to each new state), and a failed plan has already rewritten the trajectory of
        the joints solved before the failing one, without updating that input. A retry (or the
        next tick) whose input equals it, such as the same nudged target as the tick before,
        would then sample that half-rewritten trajectory one period late: a joint moving fast
        jumps a tick ahead, far beyond the acceleration limit.
        """
        try:
            result, error = self._otg.update(self._inp, self._out), None
        except ruckig.RuckigError as e:
            result, error = None, e
        if result not in _OK:
            self._otg.reset()
        return result, error

    def _retry_from_rest(self) -> tuple[ruckig.Result | None, Exception | None]:
        """Replan with rounding-level motion zeroed: |v| < SNAP a_max dt and |a| < SNAP j_max dt.

        Ruckig's step-1 solver can fail on near-degenerate states (a ~1e-8 rad move with
        ~1e-5 rad/s and ~0.1 rad/s^2 left, at high jerk limits); from rest those joints plan
        fine. A joint at rounding-level motion whose target also moves at rounding level (a
        stance joint of a streamed gait) gets a target at rest as well: ruckig fails from rest
        to such a moving target too. Zeroing changes velocity and acceleration by < 5 % of what
        one tick at the limits may change them.
        """
        self.fallbacks += 1
        inp = self._inp
        v = np.array(inp.current_velocity)
        a = np.array(inp.current_acceleration)
        tiny = (np.abs(v) < self._snap_velocity) & (np.abs(a) < self._snap_acceleration)
        if not tiny.any():
            return self._update()
        inp.current_velocity = np.where(tiny, 0.0, v).tolist()
        inp.current_acceleration = np.where(tiny, 0.0, a).tolist()
        tv = np.array(inp.target_velocity)
        ta = np.array(inp.target_acceleration)
        still = tiny & (np.abs(tv) < self._snap_velocity) & (np.abs(ta) < self._snap_acceleration)
        inp.target_velocity = np.where(still, 0.0, tv).tolist()
        inp.target_acceleration = np.where(still, 0.0, ta).tolist()
        return self._update()

    def _retry_nudged(self) -> tuple[ruckig.Result | None, Exception | None]:
        """Replan with every target position ``NUDGE`` further along its joint's motion.

        Ruckig 0.19 fails on states such as a joint braking into its target (0.057 rad/s and
        48 rad/s^2 left, 4.5e-5 rad to go) that targets 1e-6 rad either side plan from.
        """
        inp = self._inp
        ahead = np.where(np.array(inp.current_velocity) < 0.0, -NUDGE, NUDGE)
        inp.target_position = (np.array(inp.target_position) + ahead).tolist()
        return self._update()
