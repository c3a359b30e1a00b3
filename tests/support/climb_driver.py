"""Paper 001's free climb through the control role's own path in the twin (issue 36, item 3).

HubRobo's Dynamixel Protocol 2.0 driver talks to the twin's emulated X-series servos and
gripper servos on a pty; the controller, limit guard and loop run on a stepped clock; the
``free_climb`` plugin plans on its worker thread, off the tick, and the body it plans from is
the control role's leg odometry with the twin's IMU. The grippers close and open through the
driver and the gait acts on what the driver reports they hold.

The hold map reaches the controller as the world model publishes it, in the odometry frame
at 2 Hz. With ``perceive``, it is the perception role's (support/role_perception.py): each
period the twin ray-casts HubRobo's D435 into the pyrealsense2 software device, the role takes
the legs out of the frame, finds its graspable points (the profile's plugin) and tracks them
in its world model with the body's estimate at the frame's time, and its hold map crosses
Zenoh to the controller; before the climb the role is given the frames the camera took on the
way up to the start (``approach``), since from the start it cannot see the holds its rear
limbs reach. The world's holds only score the run. Without, it is built from the world's true holds
(``SlopeScene.tops``) placed by the body's estimate: such a run isolates the gait from
perception. What is logged is the twin's truth: base position up the slope, the TSM of the
grippers that hold, slips.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import HoldMap, MappedHold, Mode
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.dynamixel.bus import DynamixelBus
from climbd.plugins.gaits.free_climb import ClimbConfig, ClimbPlanner, FreeClimb, PeriodicClimb
from support.climb_run import ClimbLog, SlopeScene
from support.role_perception import SteppedPerception

SETTLE = 5.0
"""s: standing still before the climb, the odometry's tilt on the IMU's gravity (the gait takes
the wall's slope from it at start)."""
MARGIN_MS = 2000.0
"""Reply timeout margin of the driver: physics waits for the bus in a stepped run, so on a loaded
machine a late reply must not become a miss (which would change the run); no servo is silenced
here."""
HOLD_MAP_PERIOD = 0.5
"""s: how often the hold map reaches the controller (the world model's 2 Hz)."""
APPROACH = tuple(round(0.45 - 0.01 * k, 2) for k in range(41))
"""m down the wall: where the camera looked from on the way up to the start (``approach``),
one frame a centimetre (at paper 001's pace, 0.17 m in 45 s, its 2 Hz frames lie 2 mm apart)."""
APPROACH_PERIOD = 0.1
"""s between the frames of the way up."""


@dataclass(frozen=True)
class MapCheck:
    """A hold map against the world's true holds in the wall's plane (odometry frame): each
    mapped hold's distance to the nearest true hold (``to_true``) and that hold's index
    (``nearest``), each true hold's distance to the nearest mapped one (``to_mapped``; inf on an
    empty map)."""

    map: HoldMap
    mapped: np.ndarray
    true: np.ndarray
    to_true: np.ndarray
    nearest: np.ndarray
    to_mapped: np.ndarray


class DriverClimb(SlopeScene):
    """The scene's twin serving its bus, and HubRobo's control stack driving it through the
    Dynamixel driver with the ``free_climb`` gait, or with ``periodic`` its periodic baseline
    (``periodic_climb``), ``config`` over the scene's mass and gravity; with ``perceive``, on the
    holds its own camera finds (``relief``: see SlopeScene)."""

    def __init__(
        self,
        seed: int,
        relief: str = "columns",
        perceive: bool = False,
        periodic: bool = False,
        **config,
    ) -> None:
        super().__init__(seed, bus=True, relief=relief)
        self.config = ClimbConfig(mass=self.mass, gravity=self.config.gravity, **config)
        feet = self.start_feet
        self.place(feet, ClimbPlanner(self.kin, self.config, periodic=False).base_for(feet))
        twin = self.twin.start()
        self.bus = DynamixelBus.from_profile(
            self.profile, port=twin.port, timeout_margin_ms=MARGIN_MS
        )
        self.bus.open()
        twin.driver_sent = lambda: self.bus.sent
        self.gait = (PeriodicClimb if periodic else FreeClimb)(self.config, self.profile)
        self.clock = SteppedClock(start=twin.time, on_advance=twin.advance_to)
        self.stack = control_stack(
            self.profile,
            self.bus,
            self.clock,
            Isolated(self.gait.name, self.gait),
            imu=SimpleNamespace(read=twin.imu_sample),
        )
        self.ids = np.arange(len(self.tops))
        """The world model's id of each of ``tops``: a hold taken off keeps the others' ids."""
        self.left = ""
        self.releases = 0
        self.x0 = self.t0 = 0.0
        self.perception = SteppedPerception(self.profile, self.twin) if perceive else None

    def hold_map(self) -> HoldMap:
        """The hold map the controller is given now: the perception role's, else the truth's."""
        return self.truth_map() if self.perception is None else self.perceived_map()

    def perceived_map(self) -> HoldMap:
        """One D435 frame now through the perception role: the hold map it publishes, as the
        controller receives it over Zenoh (the last one if this frame brought none). The role
        has the body states and joints up to now (``begin``, ``run``)."""
        seen = self.perception.look()
        if seen is None:
            raise RuntimeError("driver climb: the perception role has published no hold map")
        return seen

    def approach(self) -> None:
        """The frames the camera took on the way up to the start, ``APPROACH`` m down the
        wall, ``APPROACH_PERIOD`` apart before now, perceived at those poses: the holds under
        the robot at its start, which its camera (its view begins 0.13 m ahead of the body,
        the rear feet stand 0.17 m behind) cannot see from there. The way up is taken as the
        odometry would have measured it, exactly (the wall's slope line carried into the
        odometry frame by the body's estimate now), the legs as they stand now."""
        twin, controller = self.twin, self.stack.controller
        body, joints = controller.body, controller.measured
        here, quaternion = twin.body_pose()
        down_world = self.rotation[:, 0]
        down_odometry = rotation(body.orientation) @ rotation(quaternion).T @ down_world
        now = self.clock.now()
        try:
            for k, back in enumerate(APPROACH):
                stamp = now - (len(APPROACH) - k) * APPROACH_PERIOD
                twin.data.qpos[:3] = here - back * down_world
                before = np.asarray(body.position) - back * down_odometry
                self.perception.sense(
                    msgspec.structs.replace(body, stamp=stamp, position=before.tolist()),
                    msgspec.structs.replace(joints, stamp=stamp),
                )
                self.perception.look(stamp)
        finally:
            twin.data.qpos[:3] = here

    def map_check(self) -> MapCheck:
        """The hold map the controller is given now (``hold_map``) against the true holds."""
        seen = self.hold_map()
        mapped = np.reshape([h.position for h in seen.holds], (-1, 3))
        true = np.reshape([h.position for h in self.truth_map().holds], (-1, 3))
        normal = self.rotation[:, 2]
        flat = np.eye(3) - np.outer(normal, normal)  # the wall plane, near enough in odometry
        if not len(mapped):
            none = np.full(len(true), np.inf)
            return MapCheck(seen, mapped, true, np.zeros(0), np.zeros(0, int), none)
        to_true, nearest = cKDTree(true @ flat).query(mapped @ flat)
        to_mapped = cKDTree(mapped @ flat).query(true @ flat)[0]
        return MapCheck(seen, mapped, true, to_true, nearest, to_mapped)

    def truth_map(self) -> HoldMap:
        """The world's holds in the odometry frame, placed by the body's estimate now."""
        body = self.stack.controller.body
        position, quaternion = self.twin.body_pose()
        seen = (self.tops - position) @ rotation(quaternion)
        mapped = np.asarray(body.position) + seen @ rotation(body.orientation).T
        t = self.clock.now()
        return HoldMap(
            stamp=t,
            frame_stamp=t,
            frame_position=list(body.position),
            frame_orientation=list(body.orientation),
            holds=[
                MappedHold(id=int(k), confidence=1.0, seen=1, age=0.0, position=p.tolist())
                for k, p in zip(self.ids, mapped, strict=True)
            ],
        )

    def take_off(self, hold: int) -> None:
        """Take hold ``hold`` (its id) off the wall: no longer solid nor graspable, and out of
        the hold map from the next one."""
        model, robot = self.twin.model, self.twin.robot
        geom = model.geom(f"hold_{hold}").id
        model.geom_contype[geom] = model.geom_conaffinity[geom] = 0
        robot.graspable_geoms = robot.graspable_geoms[robot.graspable_geoms != geom]
        keep = self.ids != hold
        self.tops, self.ids = self.tops[keep], self.ids[keep]

    def begin(self) -> None:
        """Stand, stand still while the tilt settles, then ACTIVE with the first hold map."""
        stack, safety = self.stack, self.stack.safety
        if not stack.stand():
            raise RuntimeError(f"driver climb: the stand did not complete: {safety.reason}")
        stack.run(SETTLE)
        if self.perception is not None:
            self.approach()
            self.perception.sense(stack.controller.body, stack.controller.measured)
        stack.controller.on_feature(self.hold_map())
        if not safety.request(Mode.ACTIVE, self.clock.now(), reason="climb"):
            raise RuntimeError(f"driver climb: ACTIVE refused: {safety.reason}")
        self.x0 = float(self.to_wall(self.twin.data.qpos[:3])[0])
        self.t0 = self.clock.now()

    def run(self, seconds: float) -> ClimbLog:
        """Climb on for ``seconds`` of simulated time, a hold map every ``HOLD_MAP_PERIOD``;
        stops early if the robot leaves ACTIVE (``left`` says why). Counts the grippers'
        releases (``releases``: a gripper the driver opened)."""
        stack, twin, log = self.stack, self.twin, ClimbLog()
        period = round(HOLD_MAP_PERIOD * self.profile.rate_hz)
        end = self.clock.now() + seconds
        while self.clock.now() < end - 1e-9 and not self.left:
            stack.controller.on_feature(self.hold_map())
            for _ in range(period):
                grip = twin.grip.copy()
                stack.run(1.0 / self.profile.rate_hz)
                twin.advance_to(twin.time)  # the tick's writes reach the twin; no physics step
                if self.perception is not None:
                    self.perception.sense(stack.controller.body, stack.controller.measured)
                self.releases += int((grip & ~twin.grip).sum())
                log.t.append(self.clock.now() - self.t0)
                log.x.append(float(self.to_wall(twin.data.qpos[:3])[0]) - self.x0)
                log.tsm.append(self.measured_tsm())
                log.max_load = max(log.max_load, float(twin.grip_load.max()))
            if stack.safety.mode != Mode.ACTIVE:
                self.left = f"{stack.safety.mode.value}: {stack.safety.reason}"
        runner = self.gait.runner
        log.slips = int(twin.slips.sum())
        log.missed = runner.missed
        log.steps = sum(not s.wait for s in runner.steps)
        log.waits = sum(s.wait for s in runner.steps)
        return log

    def close(self) -> None:
        """Stop the gait's worker, the perception role's camera and sessions, the driver and
        the twin."""
        self.gait.stop()
        if self.perception is not None:
            self.perception.close()
        self.bus.close()
        self.twin.stop()
