"""Free-climbing gaits (paper 001 §3) in a kinematic simulation over generated hold maps."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.kinematics import Kinematics
from daemon.messages import BodyState, FootTargets, GraspablePoints
from daemon.plugins import instantiate
from daemon.profile import load
from plugins.gaits.free_climb import (
    PERIODIC_ORDER,
    ClimbConfig,
    ClimbPlanner,
    ClimbRunner,
    diagonal_crossing,
    swing_lift,
)

PROFILE = load("robots/hubrobo.toml")
KIN = Kinematics(PROFILE)
CFG = ClimbConfig()


def start_feet() -> np.ndarray:
    feet = KIN.stand_feet(CFG.base_height)
    feet[:, 2] = 0.0
    return feet


def hold_map(seed: int, density: float = 80.0) -> np.ndarray:
    """Uniform random graspable points on the slope (m⁻²), plus the four starting grips."""
    rng = np.random.default_rng(seed)
    n = int(density * 1.4 * 0.8)
    holds = np.column_stack((rng.uniform(-0.3, 1.1, n), rng.uniform(-0.4, 0.4, n), np.zeros(n)))
    return np.vstack((holds, start_feet()))


def climb(periodic: bool, seed: int, seconds: float = 45.0, dt: float = 0.1):
    planner = ClimbPlanner(KIN, CFG, periodic)
    feet = start_feet()
    runner = ClimbRunner(planner, feet, planner.base_for(feet))
    holds = hold_map(seed)
    return planner, holds, [runner.tick(dt, holds) for _ in range(int(seconds / dt))]


def test_swing_spline_height_and_ends():
    s = np.linspace(0, 1, 101)
    lift = np.array([swing_lift(x, 0.02) for x in s])
    assert lift[0] == 0 and lift[-1] == 0 and lift.max() == pytest.approx(0.02)
    assert np.all(np.diff(lift[:51]) >= 0) and np.all(np.diff(lift[50:]) <= 0)


@pytest.mark.parametrize("periodic", [False, True])
def test_climb_keeps_grip_rules_tsm_and_reach(periodic):
    planner, holds, ticks = climb(periodic, seed=0)
    swings = 0
    for tick in ticks:
        assert tick.tsm >= 0.0
        assert sum(not g for g in tick.grip) <= 1  # release only while the three others hold
        assert KIN.ik(tick.feet - tick.base)[1].all()
        if tick.swing is None:
            continue
        stance = [i for i in range(4) if i != tick.swing]
        on_hold = np.linalg.norm(tick.feet[:, None, :] - holds[None], axis=2).min(axis=1)
        assert on_hold[stance].max() < 1e-9  # stance feet grip graspable points
        if tick.grip[tick.swing]:  # touchdown: gripper closed before the limb takes load
            swings += 1
            assert on_hold[tick.swing] < 1e-9
            com = tick.base - tick.base[2] * planner.down / planner.down[2]
            np.testing.assert_allclose(com[:2], diagonal_crossing(tick.feet), atol=1e-9)
        else:
            assert tick.feet[tick.swing, 2] >= 0.0  # swinging above the wall
    assert swings >= 5
    assert ticks[-1].base[0] - ticks[0].base[0] > 0.05


def test_periodic_gait_follows_its_fixed_order():
    _, _, ticks = climb(True, seed=3, seconds=16.0)
    limbs = [t.swing for t in ticks if t.swing is not None]
    order = [limbs[0]] + [b for a, b in zip(limbs, limbs[1:], strict=False) if b != a]
    start = PERIODIC_ORDER.index(order[0])
    assert order == [PERIODIC_ORDER[(start + i) % 4] for i in range(len(order))]


def test_non_periodic_swings_the_limb_with_most_holds_ahead():
    feet = start_feet()
    planner = ClimbPlanner(KIN, CFG, periodic=False)
    base = planner.base_for(feet)
    lf = feet[3]
    ahead = np.array([lf + [dx, dy, 0.0] for dx in (0.02, 0.035, 0.05) for dy in (-0.01, 0.02)])
    holds = np.vstack((feet, ahead, feet[0] + [0.03, 0.0, 0.0]))
    step = planner.plan(feet, base, holds)
    assert step is not None and step.limb == 3
    # the longest feasible stride among its options
    assert step.target[0] == pytest.approx(
        max(h[0] for h in ahead if planner._feasible(feet, base, 3, h) is not None)
    )


def test_plugins_from_entry_points_emit_foot_targets():
    for name in ("free_climb", "periodic_climb"):
        gait = instantiate("climbd.gaits", name, {}, PROFILE, f"test: {name}")
        feet = KIN.stand_feet(CFG.base_height)
        gait.start(BodyState(position=[0.0, 0.0, CFG.base_height]), feet)
        holds = GraspablePoints(points=hold_map(1)[:, :].tolist())
        world = {GraspablePoints.TOPIC: holds}
        out = [gait.step(i * 0.1, 0.1, BodyState(), world, None) for i in range(50)]
        assert all(isinstance(o, FootTargets) and len(o.positions) == 4 for o in out)
        assert any(not all(o.grip) for o in out)  # at least one swing began
