"""A joist scenario in the stepped MuJoCo twin: the joist_climb gait through IK, ruckig and the
guard to the twin's servos, with the gait fed either the world's truth or joist perception.

``run_scenario`` walks the WidowX until it has travelled ``goal`` m and reports what a user
relies on: decisions, where the body ended, its tilt, which feet are down, and every contact
of the body box or a leg link (not a foot) with a joist along the way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
from joist_scenes import JoistSpec
from joist_world import perceive

from daemon import profile as profiles
from daemon.messages import BodyState, Joists
from daemon.motion import MotionPipeline
from daemon.profile import stock_profiles
from drivers.sim.twin import Twin
from drivers.sim.worlds import JoistRow, World
from plugins.gaits.joist_climb import JoistClimb, JoistClimbConfig

WIDOWX = profiles.load(stock_profiles()["widowx"])
DT = 0.01
TIMESTEP = 0.002
"""Physics step (s): 2 ms keeps the servos and contacts stable and the tests fast."""
PERCEPTION_PERIOD = 10
"""Ticks between joist messages (10 Hz, the paper's L515 pipeline rate or better)."""


@dataclass
class Outcome:
    """What happened in one scenario."""

    events: list[str]
    done: bool
    position: np.ndarray
    tilt_deg: float
    feet_down: np.ndarray
    feet: np.ndarray
    link_hits: set[str] = field(default_factory=set)
    base_hits: int = 0
    unreachable_ticks: int = 0
    seconds: float = 0.0


def specs(row: JoistRow) -> list[JoistSpec]:
    """The row's joists as the oracle's specs (near face on the x axis, yaw, height)."""
    psi = math.radians(row.yaw_deg)
    face = row.distance - (row.width / 2) / math.cos(psi)
    return [
        JoistSpec(face + k * row.spacing / math.cos(psi), psi, row.height, row.width, row.length)
        for k in range(row.count)
    ]


def _yaw(quat: np.ndarray) -> float:
    w, x, y, z = quat
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _geoms(twin: Twin) -> tuple[np.ndarray, np.ndarray, int]:
    """Geom ids of the joists and of the leg links (not feet), and the body box's."""
    m = twin.model
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(m.ngeom)]
    joists = np.array([g for g, n in enumerate(names) if n.startswith("joist")], int)
    links = np.array([g for g, n in enumerate(names) if n.endswith("_link")], int)
    return joists, links, names.index("base")


def _contacts(twin: Twin, geoms: tuple[np.ndarray, np.ndarray, int]) -> tuple[set[int], bool]:
    """Leg links (geom ids) and whether the body box touch a joist now."""
    joists, links, base = geoms
    d = twin.data
    with twin.lock:
        g1, g2 = d.contact.geom1[: d.ncon].copy(), d.contact.geom2[: d.ncon].copy()
    other = np.concatenate([g2[np.isin(g1, joists)], g1[np.isin(g2, joists)]])
    return set(other[np.isin(other, links)].tolist()), bool((other == base).any())


def run_scenario(
    rows: list[JoistRow], goal: float, seconds: float, perception=None, **config
) -> Outcome:
    """Run joist_climb in the twin until it has walked ``goal`` m (or ``seconds`` elapse).

    With ``perception`` (a JoistPerception) the joists come from the twin's ray-cast depth
    through ``process(frame, body)``; without, from the world's truth (joist_world.perceive
    at the twin's true body pose), for tests of the gait only.
    """
    twin = Twin(
        WIDOWX, World(name="joists", joists=rows), stepped=True, bus=False, timestep=TIMESTEP
    )
    twin.start()
    truth = [s for row in rows for s in specs(row)]
    try:
        pipeline = MotionPipeline(WIDOWX, DT)
        kin = pipeline.kinematics
        twin.command(kin.stand_joints())
        twin.advance_to(1.0)
        pipeline.start(twin.joint_positions())
        behaviour = JoistClimb(JoistClimbConfig(goal_distance=goal, **config), WIDOWX)
        behaviour.start(BodyState(), kin.fk(twin.joint_positions()))
        world: dict = {}
        geoms = _geoms(twin)
        hits: set[int] = set()
        base_hits = 0
        t = 1.0
        for k in range(int(seconds / DT)):
            pos, quat = twin.body_pose()
            body = BodyState(position=[float(v) for v in pos], orientation=[float(v) for v in quat])
            if k % PERCEPTION_PERIOD == 0:
                if perception is not None:
                    world = {Joists.TOPIC: perception.process(twin.depth_frame("front"), body)}
                else:
                    pose = np.array([pos[0], pos[1], _yaw(quat)])
                    world = {Joists.TOPIC: perceive(truth, pose, t)}
            targets = behaviour.step(t, DT, body, world, None)
            twin.command(np.array(pipeline.feet_step(targets).position))
            t += DT
            twin.advance_to(t)
            links, base = _contacts(twin, geoms)
            hits |= links
            base_hits += int(base)
            if behaviour.done:
                break
        pos, quat = twin.body_pose()
        up = 1.0 - 2.0 * (quat[1] ** 2 + quat[2] ** 2)
        return Outcome(
            events=[e for _, e in behaviour.events],
            done=behaviour.done,
            position=pos,
            tilt_deg=math.degrees(math.acos(min(1.0, up))),
            feet_down=twin.foot_contacts(),
            feet=twin.foot_positions(),
            link_hits={mujoco.mj_id2name(twin.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in hits},
            base_hits=base_hits,
            unreachable_ticks=pipeline.unreachable_ticks,
            seconds=t,
        )
    finally:
        twin.stop()
