"""Qingzhui's stair run in the twin (paper 004, section 4), shared by the twin test and
bench/stairs.py: the stair gait at 1 kHz through the torque-leg driver on the rig of
tests/support/qingzhui_twin.py, with collision, foothold and estimate checks from the twin's truth.

The stair model is the world's own geometry as a ``Stairs`` message in the odometry frame (what
perception reports, without its noise: the camera sees the stairs from the true pose and places
them with the estimated one, so the estimate's drift moves them with the body; tests/test_stairs.py
measures perception separately), folded into the world model's stair map, which the gait reads:
these runs isolate the gait from perception. With ``icp``, every ``CLOUD_PERIOD`` the front
camera's cloud goes through the stairs perception plugin's ICP onto its stitched map, and the
message carries that alignment to the estimator's filter 2, as the plugin's own does.

With ``perceived`` the stair model is perception's instead (issue 35): every ``CLOUD_PERIOD``
the front camera's ray-cast depth frame goes through the stairs perception plugin's ``process``
with the controller's estimated body pose at the frame's time (never the twin's), and the
``Stairs`` it reports (its alignment included) is folded into the stair map as the perception
role does (a frame without steps adds nothing). The world's geometry then only scores the run:
at each half cycle's plan the rise and tread the gait planned on are recorded for every step a
foot is first placed on (``Commit``), beside the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec
import numpy as np

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.algorithms.estimation import StateEstimator, log_so3, quaternion
from climbd.daemon.algorithms.feature_maps import StairTracks, ViewCone
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.self_filter import SelfFilter
from climbd.daemon.algorithms.tracks import Track
from climbd.daemon.algorithms.world import world_config
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import MotionCommand, Stair, StairMap, Stairs
from climbd.daemon.runtime.loader import Isolated
from climbd.drivers.sim.worlds import Staircase, World, load
from climbd.plugins.gaits.stair_gait import StairGait, StairGaitConfig
from climbd.plugins.gaits.stair_plan import StairModel
from climbd.plugins.perception.stairs import StairPerception, StairsConfig
from support.qingzhui_twin import QingzhuiRig, contact_forces

CLOUD_PERIOD = 0.5
"""Seconds (simulated) between the front camera's clouds that ICP aligns (``icp``)."""
CLOUD_VOXEL = 0.02
"""Voxel (m) the clouds are thinned to: the treads' planes, at a cost the run can afford."""
EDGE_NORMAL = 0.95
"""A foot contact whose normal is tilted more than this cosine allows touches an edge or riser."""
LIFTING = 0.5
"""Swing phase before which a foot's new contact is its lift-off's (it rolled back onto its
tread), not a foothold: footholds are where swings come down."""


def stair_world(rise: float = 0.13, tread: float = 0.30, count: int = 3, landing: float = 1.6):
    """The stock stairs world with another flight: ``count`` steps of ``rise`` × ``tread``."""
    world = load("stairs")
    flight = world.stairs[0]
    world.stairs = [
        Staircase(
            rise=rise,
            tread=tread,
            count=count,
            distance=flight.distance,
            width=flight.width,
            landing=landing,
        )
    ]
    return world


def front_cloud(twin) -> np.ndarray:
    """The front camera's depth frame now as a body-frame cloud (m), within 2 m."""
    return frame_to_points(twin.depth_frame("front"), decimation=2, max_range=2.0).astype(float)


def world_stairs(world: World) -> Stairs:
    """The world's flight as perception reports it: bottom step first, edges left then right."""
    st = world.stairs[0]
    steps = []
    for k in range(st.count):
        x, top = st.distance + k * st.tread, (k + 1) * st.rise
        depth = st.tread if k < st.count - 1 else st.landing
        edge = [[x, st.width / 2, top], [x, -st.width / 2, top]]
        steps.append(Stair(height=top, rise=st.rise, depth=depth, edge=edge))
    return Stairs(steps=steps)


def odometry_stairs(stairs: Stairs, true_pose: tuple, estimate: tuple) -> Stairs:
    """``stairs`` (world frame) as seen from the true body pose (position, quaternion) and placed
    with the estimated one (rotation, position)."""
    pos, quat = true_pose
    est_rot, est_pos = estimate
    rot = est_rot @ rotation(quat).T
    steps = []
    for st in stairs.steps:
        edge = (np.asarray(st.edge, float) - pos) @ rot.T + est_pos
        steps.append(
            Stair(height=float(edge[:, 2].mean()), rise=st.rise, depth=st.depth, edge=edge.tolist())
        )
    return Stairs(steps=steps)


@dataclass(frozen=True)
class Commit:
    """The stair map a foothold was planned on, for the first foothold on a true step (1 is
    the first tread above the floor; the top one is the landing): the rise and tread of the
    step the gait's model had there (m, tread along the foot's lane, edge to next edge; for
    the top step its seen depth), where it put the step's edge along the ascent, against the
    world's truth (edge placed by the estimate as perception would: the drift is not an
    error of perception), and the view it came from."""

    t: float
    step: int
    leg: int
    rise: float
    tread: float
    rise_error: float
    tread_error: float
    edge_error: float
    sightings: int  # times the world model's track of the step was seen
    body_x: float  # the twin's body x (m) at the commit
    first_seen_x: float  # the twin's body x (m) when perception first reported the step
    same_step: bool  # the gait's model put the foothold on this step too


@dataclass
class RunLog:
    """What the checks read: truth, estimate, collisions and footholds."""

    pos: list = field(default_factory=list)
    quat: list = field(default_factory=list)
    est_pos: list = field(default_factory=list)
    est_rot: list = field(default_factory=list)
    plain_pos: list = field(default_factory=list)  # the estimator without IMU: the fusion's gain
    plain_rot: list = field(default_factory=list)
    shin_hits: list = field(default_factory=list)
    foot_edge_hits: list = field(default_factory=list)
    cap_hits: list = field(default_factory=list)  # (t, leg): shank end cap inside the foot sphere
    touchdowns: list = field(default_factory=list)  # (t, leg, foot centre) while walking
    scuffs: list = field(default_factory=list)  # (t, leg, foot centre): back down while lifting
    tracking: list = field(default_factory=list)  # (phase, foot error, joint-level error) (m)
    support: list = field(default_factory=list)  # the feet's total upward contact force (N)
    commits: dict = field(default_factory=dict)  # true step -> its first Commit
    placements: list = field(default_factory=list)  # every planned foothold's Commit
    frames: list = field(default_factory=list)  # (t, body x, steps reported) per perceived frame
    seconds: float = 0.0

    def swing_tracking(self, lo: float, hi: float) -> tuple[float, float]:
        """Largest swing-foot error (m) at swing phases in [lo, hi]: the twin's foot against its
        planned place, and the commanded against the measured joints' foot (body frame)."""
        rows = np.array([r for r in self.tracking if lo <= r[0] <= hi]).reshape(-1, 3)
        return (float(rows[:, 1].max()), float(rows[:, 2].max())) if len(rows) else (0.0, 0.0)

    def pose_errors(self, plain: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and rotation (deg) error of the estimate (``plain``: the one without
        IMU) against the twin's truth."""
        est_pos, est_rot = (
            (self.plain_pos, self.plain_rot) if plain else (self.est_pos, self.est_rot)
        )
        pos = np.linalg.norm(np.array(est_pos) - np.array(self.pos), axis=1)
        rot = [
            np.degrees(np.linalg.norm(log_so3(r @ rotation(q).T)))
            for r, q in zip(est_rot, self.quat, strict=True)
        ]
        return pos, np.array(rot)


class StairRun:
    """The rig with the stair gait, recording the checks at every tick."""

    def __init__(
        self,
        world: World,
        start_x: float = 0.0,
        feed_forward: bool = False,
        icp: bool = False,
        perceived: bool = False,
        **config,
    ) -> None:
        self.world = world
        self.perceived = perceived
        if perceived:  # the profile's stairs plugin: its default config
            self.perception = StairPerception()
        else:
            self.perception = StairPerception(StairsConfig(voxel=CLOUD_VOXEL)) if icp else None
        self.stairs = world_stairs(world)
        self.stair_map = StairTracks()
        rig = QingzhuiRig(world, start_x=start_x, feed_forward=feed_forward)
        cfg = StairGaitConfig(foot_radius=rig.twin.robot.foot_radius, **config)
        self.gait = StairGait(cfg, rig.profile)
        rig.controller.gait = Isolated("stairs", self.gait)
        self.rig = rig
        self.log = RunLog()
        model = rig.twin.model
        self.names = names = [model.geom(i).name for i in range(model.ngeom)]
        self.stair_geoms = {i for i, n in enumerate(names) if n.startswith("stair")}
        self.world_geoms = self.stair_geoms | {names.index("floor")}
        self.shin_geoms = {i for i, n in enumerate(names) if n.endswith("_shank_link")}
        self.foot_geoms = {int(g): k for k, g in enumerate(rig.twin.robot.foot_geoms)}
        self._down = np.ones(6, bool)
        self.walking = False
        self._planned = 0
        self._first_seen: dict[int, float] = {}
        world = world_config(rig.profile)
        self._view_range = world.view_range
        self.self_filter = SelfFilter(Kinematics(rig.profile), world.self_filter.radius)
        rig.hooks.append(self._record)

    def _record(self, t: float) -> None:
        twin, rig = self.rig.twin, self.rig
        d = twin.data
        touching = np.zeros(6, bool)
        feet = twin.foot_positions()
        for i in range(d.ncon):
            c = d.contact[i]
            pair = {int(c.geom1), int(c.geom2)}
            if not pair & self.world_geoms:
                continue
            leg = next((self.foot_geoms[g] for g in pair if g in self.foot_geoms), None)
            if pair & self.shin_geoms and pair & self.stair_geoms:
                # the shank capsule ends at the foot's centre: its end cap lies inside the foot
                # sphere and meets the tread under a foot pressed into it; that is the foot's
                gap = np.linalg.norm(feet - c.pos, axis=1)
                if gap.min() >= twin.robot.foot_radius:
                    self.log.shin_hits.append((t, sorted(self.names[g] for g in pair)))
                    continue
                self.log.cap_hits.append((t, int(np.argmin(gap))))
                leg = int(np.argmin(gap))
            if leg is not None:
                touching[leg] = True
                if abs(c.frame[2]) < EDGE_NORMAL:
                    self.log.foot_edge_hits.append((t, leg))
        swing = self.gait.swing if self.walking else None
        lifting = swing[1] if swing is not None and swing[0] < LIFTING else ()
        for leg in np.flatnonzero(touching & ~self._down & self.walking):
            record = self.log.scuffs if leg in lifting else self.log.touchdowns
            record.append((t, int(leg), feet[leg].copy()))
        self._down = touching
        if self.walking:
            self.log.support.append(float(contact_forces(twin)[:, 2].sum()))
        if len(self.gait.plans) > self._planned:
            self._planned = len(self.gait.plans)
            self._commit(t)
        if swing is not None:
            tau, legs, planned = swing
            kin, c = rig.controller.kinematics, rig.controller
            error = np.linalg.norm(feet[legs] - planned, axis=1).max()
            joints = kin.fk(np.asarray(c.command.position)) - kin.fk(
                np.asarray(c.measured.position)
            )
            self.log.tracking.append((tau, error, np.linalg.norm(joints[legs], axis=1).max()))
        est = rig.controller.estimator
        if est is not None:
            pos, quat = twin.body_pose()
            rot, p = est.pose()
            self.log.pos.append(pos)
            self.log.quat.append(quat)
            self.log.est_pos.append(p)
            self.log.est_rot.append(rot)
            measured = rig.controller.measured
            self.plain.update(measured.position, measured.effort, planned=rig.controller.stance)
            rot, p = self.plain.pose()
            self.log.plain_pos.append(p)
            self.log.plain_rot.append(rot)

    def start(self) -> None:
        """Stand, start the estimator on the true pose, publish the stairs, go ACTIVE."""
        self.rig.stand()
        est = self.rig.start_estimator()
        self.plain = StateEstimator(self.rig.profile, est.config, est.pos, quaternion(est.rot))
        if self.perceived:
            self._perceive()
        else:
            self._see(self.stairs)

    def walk(self, vx: float, seconds: float) -> None:
        """Walk with forward speed ``vx`` (m/s; negative walks backward) for ``seconds``."""
        rig = self.rig
        self.walking = True
        if rig.command is None:
            rig.activate(MotionCommand(vx=vx))
        else:
            rig.command = MotionCommand(vx=vx, session=rig.command.session)
        step = 1.0 if self.perception is None else CLOUD_PERIOD
        done = 0.0
        while done < seconds - 1e-9:
            if self.perceived:
                self._perceive()
            else:
                seen = odometry_stairs(
                    self.stairs, rig.twin.body_pose(), rig.controller.estimator.pose()
                )
                self._see(seen if self.perception is None else self._aligned(seen))
            rig.run(min(step, seconds - done))
            done += step
        self.log.seconds += seconds

    def _see(self, seen: Stairs, cone: ViewCone | None = None) -> None:
        """What the perception role sends the controller of a frame's stairs: the frame's
        Stairs (its alignment is the estimator's drift measurement) and the stair map the
        world model folds it into (which the gait plans on); ``cone``: the frame's view, where
        a step not seen again counts a miss."""
        controller = self.rig.controller
        controller.on_feature(seen)
        self.stair_map.update(seen, cone)
        controller.on_feature(self.stair_map.message(seen.stamp, seen.frame_stamp))

    def _perceive(self) -> None:
        """One front-camera frame through the stairs plugin, as the perception role runs it:
        the frame now, the legs' pixels dropped by the profile's self filter at the joints the
        controller measured, the controller's estimated pose now (the frame's time; the twin's
        true pose stays out), the Stairs it reports stamped with that pose and folded in through
        ``_see`` with the frame's view cone; nothing when it reports no steps."""
        twin = self.rig.twin
        frame = twin.depth_frame("front")
        if self.self_filter.radius > 0:
            measured = self.rig.controller.measured
            frame, _ = self.self_filter.apply(frame, np.asarray(measured.position, float))
        body = self.rig.controller.estimator.body(frame.timestamp)
        result = self.perception.process(frame, body)
        found = [r for r in (result if isinstance(result, tuple) else (result,)) if r is not None]
        seen = next((r for r in found if isinstance(r, Stairs)), None)
        x = float(twin.body_pose()[0][0])
        self.log.frames.append((frame.timestamp, x, 0 if seen is None else len(seen.steps)))
        if seen is None or not seen.steps:
            return
        seen.frame_position = list(body.position)
        seen.frame_orientation = list(body.orientation)
        cone = ViewCone(frame, body.position, body.orientation, self._view_range)
        self._see(seen, cone)
        for track in self.stair_map.tracker.tracks:
            self._first_seen.setdefault(track.id, x)

    def _commit(self, t: float) -> None:
        """Record, for each true step a foot of the plan just made is placed on, the rise and
        tread the gait's model had there (``Commit``) against the world's truth: every one in
        ``placements``, the first on each step in ``commits``."""
        gait, twin = self.gait, self.rig.twin
        plan, model = gait.step_plan, gait.model
        if plan is None or plan.length <= 0.0 or model is None:
            return
        pos, quat = twin.body_pose()
        est_rot, est_pos = self.rig.controller.estimator.pose()
        to_world = rotation(quat) @ est_rot.T
        truth = odometry_stairs(self.stairs, (pos, quat), (est_rot, est_pos))
        true_model = StairModel(truth, model.origin, model.yaw, model.lanes[:-1], 0.0)
        landing_world = (plan.landing - est_pos) @ to_world.T + pos
        world_model = StairModel(self.stairs, np.zeros(3), 0.0, landing_world[:, 1], 0.0)
        steps = world_model.segment(np.arange(len(plan.group)), landing_world[:, 0])
        flight = self.world.stairs[0]
        for k, (leg, step) in enumerate(zip(plan.group, steps, strict=True)):
            step = int(step)
            if not 1 <= step <= flight.count:
                continue
            s, _ = model.to_plane(plan.landing[k : k + 1])
            j = int(model.segment(np.array([leg]), s)[0])
            mapped = 1 <= j <= len(model.levels) - 2 and model.known[j]
            if not mapped:
                j = min(max(step, 1), len(model.levels) - 2)
            rise = float(model.levels[j] - model.levels[j - 1])
            tread = float(model.bounds[leg, j] - model.bounds[leg, j - 1])
            true_rise = float(true_model.levels[step] - true_model.levels[step - 1])
            true_tread = float(true_model.bounds[leg, step] - true_model.bounds[leg, step - 1])
            edge_error = float(model.bounds[leg, j - 1] - true_model.bounds[leg, step - 1])
            track = self._track_at(model.levels[j])
            commit = Commit(
                t=t,
                step=step,
                leg=int(leg),
                rise=rise,
                tread=tread,
                rise_error=rise - true_rise,
                tread_error=tread - true_tread,
                edge_error=edge_error,
                sightings=0 if track is None else track.seen,
                body_x=float(pos[0]),
                first_seen_x=np.nan if track is None else self._first_seen.get(track.id, np.nan),
                same_step=mapped and j == step,
            )
            self.log.placements.append(commit)
            self.log.commits.setdefault(step, commit)

    def _track_at(self, height: float) -> Track | None:
        """The stair map's track of the step whose tread is at ``height`` (m), if any."""
        tracks = self.stair_map.tracker.tracks
        if not tracks:
            return None
        best = min(tracks, key=lambda tr: abs(tr.estimate[2] - height))
        return best if abs(best.estimate[2] - height) < 0.02 else None

    def stair_map_now(self) -> StairMap:
        """The world model's stair map now (odometry frame)."""
        return self.stair_map.message(0.0, 0.0)

    def _aligned(self, seen: Stairs) -> Stairs:
        """``seen`` with the alignment of the front camera's cloud now, placed with the
        estimate, onto the perception's stitched map (empty when ICP did not align it)."""
        self.perception.add_cloud(front_cloud(self.rig.twin), self.rig.controller.estimator.body())
        shift, dirs = self.perception.last_correction or (np.zeros(0), np.zeros((0, 3)))
        return msgspec.structs.replace(seen, alignment=shift.tolist(), constrained=dirs.tolist())

    def foothold_margins(self) -> np.ndarray:
        """Distance (m) of every touch-down to the nearer end of its tread (true geometry)."""
        if not self.log.touchdowns:
            return np.zeros(0)
        feet = np.array([p for _, _, p in self.log.touchdowns])
        model = StairModel(self.stairs, np.zeros(3), 0.0, feet[:, 1], 0.0)
        s, _ = model.to_plane(feet)
        return model.margin(np.arange(len(feet)), s)

    def close(self) -> None:
        self.rig.close()
