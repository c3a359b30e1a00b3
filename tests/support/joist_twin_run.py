"""A joist scenario in the stepped MuJoCo twin: the joist_climb gait through IK, ruckig and the
guard to the twin's servos, deciding from a joist map (the world model's JoistTracks) fed
either the world's truth (the gait isolated) or joist perception on the twin's depth.

``run_scenario`` walks the WidowX until it has travelled ``goal`` m and reports what a user
relies on: decisions, where the body ended, its tilt, which feet are down, and every contact
of the body box or a leg link (not a foot) with a joist along the way. By default the gait's
joint goals are set in the twin in-process (fast); with ``driver=True`` the gait runs as the
daemon runs it: a gait plugin under the Controller and the safety supervisor, on the body
its leg odometry estimates fused with the twin's IMU, writing through dynamixel_sdk to the
twin's servo emulator on its pty, lock-step by count (``Twin.driver_sent``), as
``climbd run --sim --stepped`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import msgspec
import mujoco
import numpy as np

from climbd.daemon.algorithms.feature_maps import JoistTracks
from climbd.daemon.algorithms.motion import MotionPipeline
from climbd.daemon.cli.sim_host import STEPPED_TIMEOUT_MARGIN_MS
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import yaw
from climbd.daemon.contract.messages import BodyState, JoistMap, Mode
from climbd.daemon.contract.profile import stock_profiles
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.dynamixel.bus import DynamixelBus
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import JoistRow, World
from climbd.plugins.gaits.joist_climb import JoistClimb, JoistClimbConfig, Replans
from support.joist_scenes import JoistSpec
from support.joist_world import mapped, perceive

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
    held: str = ""
    """Why the safety supervisor left ACTIVE (driver path only; empty when it never did)."""
    replans: Replans = field(default_factory=Replans)
    crossings: list[float] = field(default_factory=list)
    """Simulated seconds of each crossing, from its plan's start to the walk on."""


def specs(row: JoistRow) -> list[JoistSpec]:
    """The row's joists as the oracle's specs (near face on the x axis, yaw, height)."""
    psi = math.radians(row.yaw_deg)
    face = row.distance - (row.width / 2) / math.cos(psi)
    return [
        JoistSpec(face + k * row.spacing / math.cos(psi), psi, row.height, row.width, row.length)
        for k in range(row.count)
    ]


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
    rows: list[JoistRow],
    goal: float,
    seconds: float,
    perception=None,
    driver: bool = False,
    **config,
) -> Outcome:
    """Run joist_climb in the twin until it has walked ``goal`` m (or ``seconds`` elapse).

    With ``perception`` (a JoistPerception) the joists come from the twin's ray-cast depth
    through ``process(frame, body)``; without, from the world's truth (joist_world.perceive
    at the twin's true body pose), for tests of the gait only. ``driver`` runs the daemon's
    path: Controller, Safety and the Dynamixel driver on the twin's pty.
    """
    twin = Twin(
        WIDOWX,
        World(name="joists", joists=rows),
        stepped=True,
        bus=driver,
        timestep=TIMESTEP,
    )
    twin.start()
    scene = _Scene(twin, [s for row in rows for s in specs(row)], perception)
    behaviour = JoistClimb(JoistClimbConfig(goal_distance=goal, **config), WIDOWX)
    behaviour.stepped = True  # simulated time: plans are waited for
    try:
        run = _through_driver if driver else _in_process
        unreachable, held = run(twin, scene, behaviour, seconds)
        pos, quat = twin.body_pose()
        up = 1.0 - 2.0 * (quat[1] ** 2 + quat[2] ** 2)
        return Outcome(
            events=[e for _, e in behaviour.events],
            done=behaviour.done,
            position=pos,
            tilt_deg=math.degrees(math.acos(min(1.0, up))),
            feet_down=twin.foot_contacts(),
            feet=twin.foot_positions(),
            link_hits={
                mujoco.mj_id2name(twin.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in scene.hits
            },
            base_hits=scene.base_hits,
            unreachable_ticks=unreachable,
            seconds=twin.time,
            held=held,
            replans=behaviour.replans,
            crossings=_crossings(behaviour.events),
        )
    finally:
        twin.stop()


def _crossings(events: list[tuple[float, str]]) -> list[float]:
    """Seconds from each crossing's start to its "joist crossed"."""
    starts = [t for t, e in events if e.startswith("cross: crossing")]
    ends = [t for t, e in events if e.startswith("walk: joist crossed")]
    return [end - start for start, end in zip(starts, ends, strict=False)]


class _Scene:
    """What the gait is told of the joists, and every contact of a link with one."""

    def __init__(self, twin: Twin, truth: list[JoistSpec], perception) -> None:
        self.twin = twin
        self.truth = truth
        self.perception = perception
        self.tracks = JoistTracks()
        self.geoms = _geoms(twin)
        self.hits: set[int] = set()
        self.base_hits = 0

    def joist_map(self, t: float, body: BodyState) -> JoistMap:
        """The world model's joist map once the joists seen now are folded in, placed by the
        pose ``body`` the gait is given: perceived on the twin's depth or, without perception,
        the truth inside the crop box ahead of the twin's true pose."""
        if self.perception is not None:
            seen = self.perception.process(self.twin.depth_frame("front"), body)
        else:
            pos, quat = self.twin.body_pose()
            seen = perceive(self.truth, np.array([pos[0], pos[1], yaw(quat)]), t)
        return mapped(self.tracks, msgspec.structs.replace(seen, stamp=t, frame_stamp=t), body)

    def advance(self, t: float) -> None:
        """Simulate to ``t`` and note the contacts there."""
        self.twin.advance_to(t)
        links, base = _contacts(self.twin, self.geoms)
        self.hits |= links
        self.base_hits += int(base)


def _in_process(
    twin: Twin, scene: _Scene, behaviour: JoistClimb, seconds: float
) -> tuple[int, str]:
    """The gait's joint goals set in the twin in-process, on the twin's true body pose."""
    pipeline = MotionPipeline(WIDOWX, DT)
    kin = pipeline.kinematics
    twin.command(kin.stand_joints())
    twin.advance_to(1.0)
    pipeline.start(twin.joint_positions())
    behaviour.start(BodyState(), kin.fk(twin.joint_positions()))
    world: dict = {}
    t = 1.0
    for k in range(int(seconds / DT)):
        pos, quat = twin.body_pose()
        body = BodyState(position=[float(v) for v in pos], orientation=[float(v) for v in quat])
        if k % PERCEPTION_PERIOD == 0:
            world = {JoistMap.TOPIC: scene.joist_map(t, body)}
        targets = behaviour.step(t, DT, body, world, None)
        twin.command(np.array(pipeline.feet_step(targets).position))
        t += DT
        scene.advance(t)
        if behaviour.done:
            break
    return pipeline.unreachable_ticks, ""


def _through_driver(
    twin: Twin, scene: _Scene, behaviour: JoistClimb, seconds: float
) -> tuple[int, str]:
    """The daemon's path: stand, then ACTIVE as ``climbd run --activate``; the joists reach the
    controller as features at 10 Hz; physics waits for the emulator to handle each write."""
    bus = DynamixelBus.from_profile(
        WIDOWX, port=twin.port, timeout_margin_ms=STEPPED_TIMEOUT_MARGIN_MS
    )
    bus.open()
    try:
        twin.driver_sent = lambda: bus.sent
        clock = SteppedClock(on_advance=lambda t0, t1: scene.advance(t1))
        stack = control_stack(
            WIDOWX,
            bus,
            clock,
            Isolated("joist_climb", behaviour),
            imu=SimpleNamespace(read=twin.imu_sample),
        )
        safety, controller, loop = stack.safety, stack.controller, stack.loop
        assert safety.request(Mode.STAND, clock.now(), reason="start-up")
        while safety.mode == Mode.STAND and clock.now() < 1.0 + 3 * WIDOWX.safety.stand_time:
            loop.run(max_ticks=loop.ticks + PERCEPTION_PERIOD)
        assert safety.mode == Mode.HOLD, safety.reason
        controller.on_feature(scene.joist_map(clock.now(), controller.body))
        assert safety.request(Mode.ACTIVE, clock.now(), reason="autonomy")
        end = clock.now() + seconds
        while clock.now() < end and safety.mode == Mode.ACTIVE and not behaviour.done:
            controller.on_feature(scene.joist_map(clock.now(), controller.body))
            loop.run(max_ticks=loop.ticks + PERCEPTION_PERIOD)
        held = "" if safety.mode == Mode.ACTIVE or behaviour.done else safety.reason
        return controller.motion.unreachable_ticks, held
    finally:
        bus.close()
