"""Paper 001's free-climbing planners run in the twin: HubRobo on the hold-map slope (§4).

The planner (plugins/gaits/free_climb.py) plans in the wall frame over the map's holds; each
control tick its feet and base become joint goals through the daemon's IK (the body keeps the
wall's orientation) and its grips become the twin's grippers, which hold only on hold geoms
and slip above 9 N. The swing foot aims at its hold from where the body is and how it is
turned (as a hold seen from the body would be), so the stance legs' sag and the body's tilt
do not shorten every landing and add up; only its height over the wall stays the plan's (with
the tilt turned into height too, the foot pressed into the wall and tipped the body further
over).
The runner is given what the twin's grippers report: a swing starts only once every gripper
holds, and one that does not hold on its new hold backs off to the old one. What is
logged is the twin's truth: base position, the TSM of the grippers that hold, slips. The next
swing is planned on the planner's worker thread while the twin executes the current one, and
awaited in simulated time where it is needed (deterministic runs); ``close`` stops the worker.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import mujoco
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.profile import Profile
from climbd.daemon.contract.profile import load as load_profile
from climbd.drivers.sim.model import GRIP_FORCE
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import hold_map_holds, hold_map_tile, wall_pose
from climbd.drivers.sim.worlds import load as load_world
from climbd.plugins.gaits.free_climb import (
    GOAL,
    NORMAL,
    ClimbConfig,
    ClimbPlanner,
    ClimbRunner,
    PlanAhead,
)
from climbd.plugins.gaits.tsm import tumble_stability_margin

HUBROBO = Path(__file__).resolve().parents[2] / "robots" / "hubrobo.toml"


@dataclass
class ClimbLog:
    """Twin truth per control tick: time (s), base x up the slope (m, from the start), TSM of
    the holding grippers (m); plus slips, grips that never engaged, steps and waits."""

    t: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    tsm: list[float] = field(default_factory=list)
    slips: int = 0
    missed: int = 0
    steps: int = 0
    waits: int = 0
    max_load: float = 0.0

    @property
    def distance(self) -> float:
        """Base travel up the slope (m) over the run."""
        return self.x[-1] - self.x[0]


class SlopeScene:
    """A twin of HubRobo on ``slope_map`` with hold map ``seed``, its feet on four holds at the
    stand and its grippers closed; the wall (planner) frame and its holds. ``bus``: the twin
    serves its Dynamixel servos and grippers on a pty (a driver commands it), else it takes
    commands in-process. ``relief``: the holds as columns or as the rock they were detected on
    (worlds.HoldMap)."""

    def __init__(
        self,
        seed: int,
        profile: Profile | None = None,
        bus: bool = False,
        relief: str = "columns",
    ) -> None:
        self.profile = profile or load_profile(HUBROBO)
        self.kin = Kinematics(self.profile)
        world = load_world("slope_map")
        feet = self.kin.stand_feet(ClimbConfig().base_height)
        feet[:, 2] = 0.0
        hold_map = msgspec.structs.replace(
            world.hold_map, seed=seed, extra=feet[:, :2].tolist(), relief=relief
        )
        world = msgspec.structs.replace(world, hold_map=hold_map)
        q0 = self.kin.ik(feet - [0.0, 0.0, ClimbConfig().base_height])[0]
        self.twin = Twin(self.profile, world, stepped=True, bus=bus, initial_joints=q0)
        model = self.twin.model
        self.mass = float(model.body_subtreemass[self.twin.robot.base_body])
        self.config = ClimbConfig(mass=self.mass, gravity=world.gravity)
        self.origin, self.rotation = wall_pose(hold_map)
        r_foot = self.twin.robot.foot_radius
        tops = hold_map_tile(Path(world.source).parent / hold_map.cloud)[:, 2]
        self.z0 = float(tops.mean()) + r_foot
        self.tops = self.to_world(hold_map_holds(world) - [0.0, 0.0, self.z0])
        """The world's hold tops (m, world frame): ground truth, to score or isolate a gait."""
        self.holds = self.to_wall(self.tops) + [0.0, 0.0, r_foot]
        self.start_feet = feet
        self.force = self.mass * (self.rotation.T @ model.opt.gravity)

    def place(self, feet: np.ndarray, base: np.ndarray) -> None:
        """Put the base at ``base`` (wall frame) with the feet at ``feet``, on their holds, and
        close the four grippers."""
        twin, d = self.twin, self.twin.data
        q = self.kin.ik(feet - base)[0]
        d.qpos[:3] = self.to_world(base)
        d.qpos[3:7] = self.twin.robot.start[3:]
        d.qpos[self.twin.robot.qpos_adr] = twin.map.hinge(q)
        d.qvel[:] = 0.0
        mujoco.mj_forward(twin.model, d)
        twin.goal[:] = twin.setpoint[:] = q
        twin.command(q)
        twin.grip[:] = True
        twin.advance_to(0.3)
        if not twin.holding().all():
            raise RuntimeError(f"twin climb: start grips not engaged: {twin.holding()}")
        self.level = self.rotation.T @ rotation(d.qpos[3:7])
        """The body's orientation in the wall frame as it stands at the start (the planner's)."""

    def to_world(self, p: np.ndarray) -> np.ndarray:
        """World positions of planner-frame points (…×3)."""
        return self.origin + (np.asarray(p) + [0.0, 0.0, self.z0]) @ self.rotation.T

    def to_wall(self, p: np.ndarray) -> np.ndarray:
        """Planner-frame position of world points (…×3)."""
        return (np.asarray(p) - self.origin) @ self.rotation - [0.0, 0.0, self.z0]

    def tilt(self) -> np.ndarray:
        """Rotation (wall frame) of the body now from its orientation at the start."""
        return self.rotation.T @ rotation(self.twin.data.qpos[3:7]) @ self.level.T

    def measured_tsm(self) -> float:
        """TSM (m) of the twin now: its CoM, the feet whose grippers hold, its weight."""
        d, r = self.twin.data, self.twin.robot
        held = self.twin.holding()
        com = self.to_wall(d.subtree_com[r.base_body])
        feet = self.to_wall(d.site_xpos[r.foot_sites])[held]
        return tumble_stability_margin(com, feet, self.force, GRIP_FORCE, NORMAL)


class SlopeClimb(SlopeScene):
    """One climb: the scene's twin and a periodic or non-periodic planner over the same holds,
    its joint goals and grips set in the twin in-process."""

    def __init__(
        self, periodic: bool, seed: int, profile: Profile | None = None, relief: str = "columns"
    ) -> None:
        super().__init__(seed, profile, relief=relief)
        self.planner = ClimbPlanner(self.kin, self.config, periodic)
        feet = self.start_feet
        base = self.planner.base_for(feet)
        self.runner = ClimbRunner(self.planner, feet, base, PlanAhead(self.planner, wait=True))
        self.place(feet, base)

    def close(self) -> None:
        """Stop the planner's worker thread."""
        self.runner.close()

    def run(self, seconds: float, dt: float = 0.01) -> ClimbLog:
        """Climb for ``seconds`` of simulated time with control period ``dt`` (s)."""
        twin, runner, log = self.twin, self.runner, ClimbLog()
        t0 = twin.time
        while twin.time - t0 < seconds - 1e-9:
            tick = runner.tick(dt, self.holds, twin.holding().tolist())
            legs = tick.feet - tick.base
            if tick.swing is not None:
                tilt = self.tilt()
                aim = tick.feet[tick.swing] - self.to_wall(twin.data.qpos[:3])
                legs[tick.swing, :2] = (tilt.T @ aim)[:2]
                legs[tick.swing, 2] = aim[2]
            q, reached = self.kin.ik(legs)
            if not reached.all():  # a swing foot the real base cannot reach: the plan's aim
                planned, _ = self.kin.ik(tick.feet - tick.base)
                q.reshape(len(legs), 3)[~reached] = planned.reshape(len(legs), 3)[~reached]
            twin.command(q)
            twin.grip[:] = tick.grip
            twin.advance_to(twin.time + dt)
            log.t.append(twin.time - t0)
            log.x.append(float(self.to_wall(twin.data.qpos[:3])[0]))
            log.tsm.append(self.measured_tsm())
            log.max_load = max(log.max_load, float(twin.grip_load.max()))
        log.slips = int(twin.slips.sum())
        log.missed = runner.missed
        log.steps = sum(not s.wait for s in runner.steps)
        log.waits = sum(s.wait for s in runner.steps)
        return log


def search_reach(seed: int, swings: int, beam: int = 400) -> float:
    """Base travel (m) of the best sequence of ``swings`` feasible swings (the default
    planner's, base leads included) that a beam search (``beam`` postures per swing, base
    furthest ahead) finds on map ``seed`` from the start."""
    climb = SlopeClimb(False, seed)
    climb.close()
    planner, holds = climb.planner, climb.holds
    start = climb.runner.base
    level = [(climb.runner.feet, start)]
    best = float(start @ GOAL)
    for _ in range(swings):
        reached: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        for moves in planner.expand(level, holds):
            for move in moves:
                if move.key not in reached or reached[move.key][1] @ GOAL < move.ahead:
                    reached[move.key] = (move.after, move.step.base_end)
        if not reached:
            break
        level = sorted(reached.values(), key=lambda n: -(n[1] @ GOAL))[:beam]
        best = max(best, float(level[0][1] @ GOAL))
    return best - float(start @ GOAL)


def planned_climb(
    seed: int, swings: int, periodic: bool, overrides: dict
) -> tuple[float, list[float]]:
    """Base travel (m) up the slope of ``swings`` planned swings on map ``seed``, and the CPU
    time (s) of each plan; a climb told its ``duration`` is given the swings left in it."""
    start = SlopeClimb(periodic, seed)
    start.close()
    config = msgspec.structs.replace(start.config, **overrides)
    planner = ClimbPlanner(start.kin, config, periodic)
    feet, base = start.runner.feet.copy(), start.runner.base.copy()
    origin = float(base @ GOAL)
    told = int(config.duration // config.swing_period) if config.duration > 0 else 0
    times = []
    for i in range(swings):
        t0 = time.process_time()
        step = planner.plan(feet, base, start.holds, max(0, told - i))
        times.append(time.process_time() - t0)
        if step is None:
            break
        if not step.wait:
            feet = feet.copy()
            feet[step.limb] = step.target
            base = step.base_end
    return float(base @ GOAL) - origin, times
