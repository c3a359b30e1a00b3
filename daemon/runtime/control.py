"""The control role's tick: read → estimate → behave → IK → smooth → feed-forward → guard → write.

One ``Controller`` per robot. ``tick(t, dt)`` runs on the ControlLoop's thread; the ``on_*``
handlers run on the asyncio thread (fed by the bus) and only record what arrived, under the
safety supervisor's lock, so a tick always sees a consistent picture. Nothing here raises
out of ``tick``: a device error becomes FAULT, a plugin error becomes HOLD.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from climbd.daemon.algorithms.estimation import StateEstimator, SupportTorques, support_forces
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.motion import MotionPipeline
from climbd.daemon.algorithms.odometry import LegOdometry
from climbd.daemon.algorithms.smoothing import SmoothingError
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import (
    ClearableFaults,
    CompliantServos,
    DriverError,
    Imu,
    ImuSample,
    JointBus,
    ReportsSchedule,
)
from climbd.daemon.contract.messages import (
    AlignedFeature,
    BodyState,
    EStop,
    EstopPolicy,
    FootTargets,
    Health,
    Heartbeat,
    JointCommand,
    JointState,
    Message,
    Mode,
    ModeRequest,
    MotionCommand,
    MotionStats,
    OverrideClaim,
    ResetRequest,
    SessionClaim,
)
from climbd.daemon.contract.profile import Profile, gripper_servos
from climbd.daemon.runtime.counting import Tally
from climbd.daemon.runtime.loader import Isolated, slowest
from climbd.daemon.runtime.safety import Safety

log = logging.getLogger("climbd.control")

STAND_TOLERANCE = 0.01
"""Joint error (rad) under which the stand is complete and the robot holds."""

HEALTH_PERIOD = 0.5
"""Seconds between Health/ModeState publications."""

ODOMETRY_RATE_HZ = 200.0
"""Leg odometry runs at most this often, and at every change of the stance set."""

SIT_SETTLE = 0.5
"""Seconds the sitting pose is held before torque goes off, so the body settles first."""

REST_FRACTION = 0.35
"""Body height at rest (sitting, before torque off) as a fraction of the standing height."""

LOAD_RAMP = 0.1
"""Seconds over which a foot's share of the weight feed-forward fades in once it touches down
(a step in torque would jolt the body); at lift-off it goes at once, or it would press the swing
foot down and read as a load the estimator takes for stance (a gait that marks the foot
``unload`` first has it handed on before)."""

UNLOAD_TIME = 0.4
"""Seconds an unloading foot's share fades over at the slowest: the others may touch too lightly
to sense (the feed-forward holds the body at its height), and the body settles onto them."""

TOUCH_SUPPORT = 10.0
"""Support (N) a stance foot must carry by its position loop alone (force sensing: eq. 5 minus
the feed-forward's share) before its feed-forward fades in: a late foot is not pushed down."""


def current_joints(state: JointState, velocity_limits: np.ndarray) -> np.ndarray:
    """Where the joints are now, for the estimator: a joint read ``age`` s ago has moved on by
    its velocity (within its limit) since; a lost joint (age NaN) stays where it was read."""
    q = np.asarray(state.position)
    if not state.age:
        return q
    qd = np.clip(np.asarray(state.velocity), -velocity_limits, velocity_limits)
    return q + np.nan_to_num(qd * np.asarray(state.age))


def fusable(feature: AlignedFeature) -> bool:
    """Whether an aligned feature carries an alignment filter 2 can take: a finite shift (3)
    and unit directions (k x 3); anything else from the wire is dropped rather than poison the
    estimate."""
    if len(feature.alignment) != 3 or any(len(d) != 3 for d in feature.constrained):
        return False
    dirs = np.array(feature.constrained, float).reshape(-1, 3)
    norms = np.linalg.norm(dirs, axis=1)
    return bool(np.isfinite(feature.alignment).all() and np.allclose(norms, 1.0, atol=1e-6))


class Shutdown(enum.Enum):
    """The safe stop, beside the mode machine: SIT lowers the body before the e-stop policy's
    torque off, HOLD keeps the pose, FORCE applies the policy now (the safe pose took too
    long), DONE when the robot is in its safe pose."""

    SIT = "sit"
    HOLD = "hold"
    FORCE = "force"
    DONE = "done"


@dataclass
class Timed:
    """A message and the controller-clock time it arrived."""

    message: Message
    at: float


class Controller:
    """Runs one robot's control tick against a JointBus under the safety supervisor."""

    def __init__(
        self,
        profile: Profile,
        bus: JointBus,
        safety: Safety,
        now: Callable[[], float],
        gait: Isolated | None = None,
        publish: Callable[[Message], None] | None = None,
        state_rate_hz: float = 100.0,
        estimator: StateEstimator | None = None,
        imu: Imu | None = None,
        feed_forward: bool = False,
    ) -> None:
        self.profile = profile
        self.bus = bus
        self._schedule = bus.schedule if isinstance(bus, ReportsSchedule) else None
        self.safety = safety
        self.now = now
        self.gait = gait
        self.publish = publish or (lambda message: None)
        self.kinematics = Kinematics(profile)
        self.motion: MotionPipeline | None = None
        self.dt = 1.0 / profile.rate_hz
        self._velocity_limits = np.array([j.limits.velocity for j in profile.joints])
        self.stand_q = self.kinematics.stand_joints()
        self._q = self.stand_q.copy()
        self.mode = Mode.OFF
        self.target: np.ndarray | None = None
        self.measured: JointState | None = None
        self.command: JointCommand | None = None
        self.feet: FootTargets | None = None
        """The gait's foot targets of the current tick (None when no gait stepped)."""
        self._unpublishable: set[str] = set()
        self.motion_command: Timed | None = None
        self.features: dict[str, Timed] = {}
        self._alignment: AlignedFeature | None = None
        self.body = BodyState()
        self.estimator = estimator
        self.odometry = (
            LegOdometry.from_profile(profile, self.kinematics) if estimator is None else None
        )
        self.stance = np.ones(len(profile.legs), bool)
        self._stance_changed = False
        self._supported = self.stance.copy()
        """The feet the odometry was last given as its support (``_odometry``)."""
        self._odometry_every = max(1, round(profile.rate_hz / ODOMETRY_RATE_HZ))
        self.imu = imu
        self.messages: list[str] = []
        self.loop_stats: Callable | None = None
        self.unauthorised: Callable[[], int] = lambda: 0
        self.undecodable = Tally()
        """Payloads the role's network dropped, by topic (the role hands over its network's)."""
        self.refused_by = Tally()
        """Safety.refused broken down by the topic of the refused command."""
        self.sit_q = self._sit_joints()
        self.shutdown: Shutdown | None = None
        self.sat_down = False
        self._sat_at: float | None = None
        self._health_every = max(1, round(profile.rate_hz / profile.bus.health_rate_hz))
        self._state_every = max(1, round(profile.rate_hz / state_rate_hz))
        self._ticks = 0
        self._last_health_publish = -1e9
        self.fault_reset = False
        self.feed_forward = feed_forward and profile.bus.kind == "torque"
        self.stiffness = (
            profile.bus.stiffness if isinstance(bus, CompliantServos) and bus.compliant else 0.0
        )
        self.support: SupportTorques | None = None
        self.load = np.zeros(len(profile.legs))
        self.landed = np.zeros(len(profile.legs), bool)
        self.unload = np.zeros(len(profile.legs), bool)
        self.all_grips = [True] * len(profile.legs) if gripper_servos(profile) else None
        """Grippers a bus drives start closed (a climber lets go only when its gait says so),
        and close again at an e-stop or fault under the ``hold_grip`` policy."""

    def _sit_joints(self) -> np.ndarray:
        """Joint pose with the body lowered to rest: where a torque_off robot is switched off."""
        feet = self.kinematics.stand_feet()
        feet[:, 2] = -REST_FRACTION * self.profile.stand.body_height
        q, reachable = self.kinematics.ik(feet)
        return q if bool(np.all(reachable)) else self.stand_q

    # --- shutdown (asyncio thread) ----------------------------------------------------

    def begin_shutdown(self, t: float) -> None:
        """Start the safe stop: hold (and for ``torque_off``, sit down first, then torque off)."""
        if not self.safety.torque_on or self.safety.mode in (Mode.ESTOP, Mode.FAULT, Mode.OFF):
            self.shutdown = Shutdown.DONE
            return
        sit = self.safety.policy == EstopPolicy.TORQUE_OFF
        self.shutdown = Shutdown.SIT if sit else Shutdown.HOLD
        self.safety.hold(t, "shutdown")

    @property
    def shutdown_done(self) -> bool:
        return self.shutdown == Shutdown.DONE

    def finish_shutdown(self) -> None:
        """Have the next tick apply the e-stop policy, whatever the pose (the motion timed out).

        The loop thread owns the joint bus, so the asyncio side only asks."""
        if self.shutdown != Shutdown.DONE:
            self.shutdown = Shutdown.FORCE

    # --- handlers (asyncio thread) ----------------------------------------------------

    def _count_refused(self, topic: str, before: int) -> None:
        """Count under ``topic`` what a handler added to Safety.refused since ``before``; the
        handlers run on the asyncio thread, the only one whose requests Safety refuses."""
        added = self.safety.refused - before
        if added > 0:
            self.refused_by.add(topic, added)

    def on_motion(self, cmd: MotionCommand) -> None:
        before = self.safety.refused
        if self.safety.accepts(cmd.session):
            self.motion_command = Timed(cmd, self.now())
        self._count_refused(MotionCommand.TOPIC, before)

    def on_mode(self, req: ModeRequest) -> None:
        """A mode request on ``cmd/mode``. A reset there is refused and counted: resets ride on
        ``cmd/reset``, which Zenoh's ACL admits only from identities with the reset right."""
        before = self.safety.refused
        if req.reset:
            self.safety.refused += 1
            log.warning(
                "refused a reset on cmd/mode from session %s: send it on cmd/reset", req.session
            )
        else:
            self.safety.request(req.mode, self.now(), req.session)
        self._count_refused(ModeRequest.TOPIC, before)

    def on_reset(self, req: ResetRequest) -> None:
        """Reset a latched e-stop or fault for the session holder (``cmd/reset``)."""
        before = self.safety.refused
        if self.safety.accepts(req.session):
            self.safety.reset(self.now(), req.session)
            self.fault_reset = True  # the loop thread owns the bus: the next tick clears
        self._count_refused(ResetRequest.TOPIC, before)

    def on_estop(self, msg: EStop) -> None:
        now = self.now()
        if msg.engage:
            self.safety.estop(now, msg.source, msg.reason)

    def on_claim(self, msg: SessionClaim) -> None:
        """Claim or release the session (``cmd/session``). An override there is refused and
        counted: it rides on ``cmd/override``, which Zenoh's ACL admits only from identities
        with the override right."""
        now, before = self.now(), self.safety.refused
        if msg.release:
            self.safety.release(msg.session, now, msg.handoff)
        elif msg.override:
            self.safety.refused += 1
            log.warning(
                "refused an override claim on cmd/session by %s: send it on cmd/override",
                msg.client,
            )
        else:
            self.safety.claim(msg.session, msg.client, now)
        self._count_refused(SessionClaim.TOPIC, before)

    def on_override(self, msg: OverrideClaim) -> None:
        """Claim the session even when another holds it (``cmd/override``)."""
        before = self.safety.refused
        self.safety.claim(msg.session, msg.client, self.now(), override=True)
        self._count_refused(OverrideClaim.TOPIC, before)

    def on_heartbeat(self, msg: Heartbeat) -> None:
        """Renew the session's heartbeat; replayed or stale ones are refused (Safety.heartbeat)."""
        self.safety.heartbeat(msg.session, self.now(), msg.seq, msg.stamp)

    def on_feature(self, msg: Message) -> None:
        self.features[msg.TOPIC] = Timed(msg, self.now())
        if isinstance(msg, AlignedFeature) and fusable(msg):
            self._alignment = msg  # filter 2's input, fused by the loop thread

    # --- the tick (loop thread) -------------------------------------------------------

    def tick(self, t: float, dt: float) -> None:
        """One control cycle; never raises: a bug in a tick is a FAULT, not a dead loop."""
        try:
            self._tick(t, dt)
        except Exception as e:
            if self.safety.mode != Mode.FAULT:
                log.exception("control tick failed")
            self.safety.fault(t, f"control tick failed: {type(e).__name__}: {e}")

    def _tick(self, t: float, dt: float) -> None:
        self._ticks += 1
        try:
            state = self.bus.read()
        except DriverError as e:
            self._fault(t, f"joint bus read failed: {e}")
            if self.safety.mode != self.mode and self.measured is not None:
                self._enter(self.safety.mode, np.asarray(self.measured.position), t)
            return
        state.stamp = t  # the control clock's, as the body state's: the self filter pairs both
        self.measured = state
        self.safety.check_state_age(state, t)
        q = np.asarray(state.position)
        q_now = current_joints(state, self._velocity_limits)
        if self.estimator is not None:
            self._estimate(t, dt, q_now, state)
        else:
            self._odometry(t, q_now, state)
        self.body.holding = state.holding
        if self.fault_reset:
            self.fault_reset = False
            self._clear_faults(t)
        safety = self.safety
        safety.check_heartbeat(t)
        if self._ticks % self._health_every == 0:
            try:
                safety.judge(self.bus.health(), t)
            except DriverError as e:
                self._fault(t, f"joint bus health failed: {e}")
        mode = safety.mode
        if mode != self.mode:
            self._enter(mode, q, t)
        self._q = q
        self.feet = None
        command = self._behave(t, dt, q)
        if command is not None:
            try:
                self.bus.write(command)
            except DriverError as e:
                self._fault(t, f"joint bus write failed: {e}")
                return
            self.command = command
        if self._ticks % self._state_every == 0:
            self._publish_state(t, state, command)
        if t - self._last_health_publish >= HEALTH_PERIOD:
            self._last_health_publish = t
            self.publish_health(t)

    def _publish_state(self, t: float, state: JointState, command: JointCommand | None) -> None:
        """The state messages of a state tick: measured joints, body, the command written to
        the bus this tick (after the guard; none while nothing was written) and the gait's
        foot targets it came from (only while a gait steps). The tick's own objects are sent."""
        self.publish(state)
        self.publish(self.body)
        if command is not None:
            command.stamp = t
            self._publish_sent(command)
        if self.feet is not None:
            self._publish_sent(self.feet)

    def _publish_sent(self, message: JointCommand | FootTargets) -> None:
        """Publish what was sent; one the wire cannot encode (a gait's numpy arrays, which the
        motion pipeline takes) is skipped and noted once per topic: telemetry never faults."""
        try:
            self.publish(message)
        except (TypeError, ValueError, OverflowError) as e:
            if message.TOPIC not in self._unpublishable:
                self._unpublishable.add(message.TOPIC)
                self.messages.append(f"{message.TOPIC} not published: {e}")
                log.warning("%s not published (further ones skipped): %s", message.TOPIC, e)

    def _estimate(self, t: float, dt: float, q: np.ndarray, state: JointState) -> None:
        """Body state from the stance feet and the IMU (paper 004 eqs. 5-9, filter 1), with the
        latest stair cloud's ICP alignment (filter 2)."""
        sample = self._read_imu()
        gyro = sample.gyro if sample is not None else None
        accel = sample.accel if sample is not None else None
        aligned, self._alignment = self._alignment, None
        if aligned is not None:
            self.estimator.icp_correction(
                np.asarray(aligned.alignment), np.asarray(aligned.constrained)
            )
        self.body = self.estimator.update(q, state.effort, gyro, accel, dt, t, self.stance)

    def _odometry(self, t: float, q_now: np.ndarray, state: JointState) -> None:
        """Leg odometry at its rate, and at once when its support changes: the gait's stance
        feet, less those whose gripper reports it holds nothing while three or more stance
        feet's grippers hold (the body hangs on its grips; a foot on rock its gripper does not
        hold may slide, and would turn the stance feet's fit with it). A robot walking on its
        feet, grippers holding nothing, keeps every stance foot."""
        support = self.stance
        if state.holding is not None:
            gripped = support & np.asarray(state.holding, bool)
            if gripped.sum() >= 3:
                support = gripped
        due = self._ticks % self._odometry_every == 0 or self._stance_changed
        if not due and np.array_equal(support, self._supported):
            return
        sample = self._read_imu()
        if sample is None:
            self.body = self.odometry.update(q_now, support, t)
        else:
            self.body = self.odometry.update(q_now, support, t, sample.gyro, sample.accel)
        self._stance_changed = False
        self._supported = support

    def _read_imu(self) -> ImuSample | None:
        """The IMU's sample now, or None without an IMU or when it fails (noted in messages)."""
        try:
            return self.imu.read() if self.imu is not None else None
        except DriverError as e:
            self.messages.append(f"imu: {e}")
            return None

    def _feed_forward(self, command: JointCommand) -> None:
        """Each stance foot's share of the weight (paper 004 eq. 5 inverted): torque legs with
        ``feed_forward`` get it as feed-forward torque, so they hold the body's height at the
        profile's gains; compliant position servos get their goals offset by torque / stiffness,
        the sag that load would deflect them by. The motion pipeline calls it before its guard."""
        q = self._q
        masses = self.estimator.config.link_masses if self.estimator is not None else []
        if self.support is None or self.support.link_masses != masses:
            self.support = SupportTorques(self.kinematics, self.profile.mass, masses)
        rot = rotation(self.body.orientation)
        if self.feed_forward:
            self.landed = self.stance & (self.landed | (self._own_support(q, rot) > TOUCH_SUPPORT))
        else:
            self.landed = self.stance
        self._transfer_load()
        legs = self.estimator.legs if self.estimator is not None else None
        tau = self.support(q, self.load, rot, legs)
        if self.feed_forward:
            command.effort = tau.tolist()
        else:
            command.position = (np.asarray(command.position) + tau / self.stiffness).tolist()

    def _transfer_load(self) -> None:
        """Landed feet take their share over LOAD_RAMP; an unloading foot gives its share up as
        fast as the others take it (no faster than LOAD_RAMP, no slower than UNLOAD_TIME), so
        the weight feed-forward stays whole across a double-support transfer."""
        load = np.minimum(self.load + self.dt / LOAD_RAMP, self.landed & ~self.unload)
        fading = self.landed & self.unload
        if fading.any():
            needed = (self.support.carriers - load[~fading].sum()) / np.count_nonzero(fading)
            was = self.load[fading]
            given = np.clip(needed, was - self.dt / LOAD_RAMP, was - self.dt / UNLOAD_TIME)
            load[fading] = np.maximum(given, 0.0)
        self.load = load

    def _own_support(self, q: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Support (N) each foot carries by its position loop alone: sensed minus feed-forward."""
        if self.estimator is not None:
            support = self.estimator.support
        else:
            forces = self.kinematics.foot_forces(q, self.measured.effort)
            support = np.nan_to_num(support_forces(forces, rot))
        return support - self.support.shares(self.load)

    def _clear_faults(self, t: float) -> None:
        """The operator's reset, while nothing moves (not STAND/ACTIVE): a bus that can bring
        back servos a fault switched off does (Dynamixel: REBOOT of latched X-series servos)."""
        if not isinstance(self.bus, ClearableFaults):
            return
        if self.safety.mode in (Mode.STAND, Mode.ACTIVE):
            log.warning(
                "fault reset ignored in %s: servos are reset only at rest", self.safety.mode.value
            )
            return
        try:
            names = self.bus.clear_faults()
        except DriverError as e:
            self._fault(t, f"fault reset failed: {e}")
            return
        if names:
            log.warning("fault reset brings back %s", ", ".join(names))

    def _fault(self, t: float, reason: str) -> None:
        if self.safety.mode != Mode.FAULT:
            log.error("%s", reason)
        self.safety.fault(t, reason)

    def _enter(self, mode: Mode, q: np.ndarray, t: float) -> None:
        """Mode entry actions. While the joints are powered the command stops where it was (not
        where load deflected the joints: that would sink a loaded robot at every HOLD); else it
        starts from the measured state. Either way, no jump."""
        previous, self.mode = self.mode, mode
        if previous == Mode.ACTIVE and self.gait is not None:
            self.gait.call(self.gait.plugin.stop)
        self.stance[:] = True
        self.unload[:] = False
        self._stance_changed = True
        self.publish(self.safety.mode_state(t))
        if mode == Mode.OFF or (
            mode in (Mode.ESTOP, Mode.FAULT) and self.safety.policy == EstopPolicy.TORQUE_OFF
        ):
            self._torque(False, t)
            self.target = None
            return
        if mode in (Mode.STAND, Mode.ACTIVE, Mode.HOLD, Mode.ESTOP, Mode.FAULT):
            powered = self.motion if self.safety.torque_on else None
            if not self.safety.torque_on:
                self._torque(True, t)
            needed = self.feed_forward or self.stiffness
            grip = self.all_grips if self.motion is None else self.motion.grip
            if mode in (Mode.ESTOP, Mode.FAULT) and self.safety.policy == EstopPolicy.HOLD_GRIP:
                grip = self.all_grips
            self.motion = MotionPipeline(
                self.profile, self.dt, self._feed_forward if needed else None
            )
            self.motion.grip = grip
            self.motion.start(q if powered is None else powered.command)
        if mode == Mode.STAND:
            self.target = self.stand_q
        elif mode == Mode.ACTIVE:
            self.target = None
            if self.gait is None:
                self.safety.hold(t, "no gait configured")
                return
            self.gait.call(self.gait.plugin.start, self.body, self.kinematics.fk(q))
        else:
            self.target = self.motion.command.copy()
        log.debug("entered %s from %s", mode.value, previous.value)

    def _torque(self, on: bool, t: float) -> None:
        try:
            self.bus.torque(on)
            self.safety.torque_on = on
        except DriverError as e:
            self._fault(t, f"torque {'on' if on else 'off'} failed: {e}")

    def _behave(self, t: float, dt: float, q: np.ndarray) -> JointCommand | None:
        mode = self.mode
        motion = self.motion
        if motion is None or not self.safety.torque_on:
            return None
        motion.set_speed_scale(self.safety.speed_scale)
        if self.shutdown is not None and mode == Mode.HOLD:
            return self._shutdown_step(t, q)
        try:
            if mode == Mode.ACTIVE:
                world = self._world(t)
                stale = self.missing(world)
                if stale:
                    self.safety.hold(t, f"{self.gait.name} needs {', '.join(stale)}: stale")
                    return motion.joint_step(q)
                feet = self.gait.call(
                    self.gait.plugin.step, t, dt, self.body, world, self._command(t)
                )
                if feet is None:
                    self.safety.hold(t, f"gait {self.gait.name} failed: {self.gait.status}")
                    return motion.joint_step(q)
                if self._ticks % self._state_every == 0:
                    for message in self.gait.call(self.gait.plugin.telemetry) or ():
                        self.publish(message)
                if self.gait.plugin.done:
                    self.safety.hold(t, f"behaviour {self.gait.name} done")
                command = motion.feet_step(feet)
                self.feet = feet
                stance = np.asarray(feet.stance, bool)
                self._stance_changed = not np.array_equal(stance, self.stance)
                self.stance = stance
                self.unload = stance & np.asarray(feet.unload or False, bool)
                return command
            stand = self.profile.safety.stand_time if mode == Mode.STAND else None
            command = motion.joint_step(self.target, stand)
        except SmoothingError as e:
            self.messages.append(f"smoothing: {e}")
            self.safety.hold(t, f"smoothing failed: {e}")
            return None
        if mode == Mode.STAND and self.stand_reached(q):
            self.safety.request(Mode.HOLD, t, reason="stand complete")
        return command

    def _shutdown_step(self, t: float, q: np.ndarray) -> JointCommand | None:
        """Hold, or sit down and settle (the commanded pose, not the loaded servos' error,
        decides when the sit is done), then switch off under ``torque_off``."""
        if self.shutdown == Shutdown.HOLD:
            self.shutdown = Shutdown.DONE
            return self.motion.joint_step(self.target)
        if self.shutdown == Shutdown.FORCE:
            if self.safety.policy == EstopPolicy.TORQUE_OFF:
                self._torque(False, t)
            self.shutdown = Shutdown.DONE
            return None
        if self.shutdown == Shutdown.SIT:
            if self.reached(self.motion.command, self.sit_q):
                self._sat_at = t if self._sat_at is None else self._sat_at
                if t - self._sat_at >= SIT_SETTLE:
                    self._torque(False, t)
                    self.shutdown = Shutdown.DONE
                    self.sat_down = True
                    return None
            return self.motion.joint_step(self.sit_q, self.profile.safety.stand_time)
        return self.motion.joint_step(self.target)

    @staticmethod
    def reached(q: np.ndarray, target: np.ndarray) -> bool:
        return bool(np.max(np.abs(q - target)) < STAND_TOLERANCE)

    def stand_reached(self, q: np.ndarray) -> bool:
        """The command has arrived at the stand pose and the joints followed it there."""
        followed = np.max(np.abs(q - self.stand_q)) < self.profile.safety.stand_tolerance
        return self.reached(self.motion.command, self.stand_q) and bool(followed)

    def _command(self, t: float) -> MotionCommand | None:
        timed = self.motion_command
        if timed is None or t - timed.at > self.profile.safety.command_timeout:
            return None
        return timed.message

    def missing(self, world: dict[str, Message]) -> list[str]:
        """The gait's needed features that ``world`` (``_world``'s fresh ones) lacks."""
        return [k for k in self.gait.plugin.needs if k not in world] if self.gait else []

    def awaiting(self, t: float) -> list[str]:
        """The gait's needed features not fresh at ``t``: ACTIVE would hold on them at once."""
        return self.missing(self._world(t))

    def _world(self, t: float) -> dict[str, Message]:
        """Features younger than the profile's limit; older ones count as absent."""
        limit = self.profile.safety.feature_max_age
        return {k: v.message for k, v in list(self.features.items()) if t - v.at <= limit}

    def health(self, t: float) -> Health:
        joints = []
        try:
            joints = self.bus.health()
        except DriverError as e:
            self.messages.append(str(e))
        isolated = [self.gait] if self.gait is not None else []
        return Health(
            stamp=t,
            role="control",
            mode=self.safety.mode,
            joints=joints,
            loop=self.loop_stats() if self.loop_stats is not None else Health().loop,
            bus=self._schedule() if self._schedule is not None else None,
            motion=self.motion_stats(),
            plugins={p.name: p.status for p in isolated},
            **slowest(isolated),
            decode_errors=self.undecodable.total,
            decode_errors_by=self.undecodable.counts(),
            refused_commands=self.safety.refused,
            refused_by=self.refused_by.counts(),
            refused_heartbeats=self.safety.refused_heartbeats,
            unauthorised_commands=self.unauthorised(),
            features={k: t - v.at for k, v in list(self.features.items())},
            session=held.client if (held := self.safety.session) is not None else "",
            messages=self.messages[-10:],
        )

    def motion_stats(self) -> MotionStats:
        m = self.motion
        if m is None:
            return MotionStats()
        return MotionStats(
            unreachable_legs=m.unreachable_legs,
            unreachable_ticks=m.unreachable_ticks,
            clamps=m.guard.clamps,
            smoothing_fallbacks=m.smoother.fallbacks,
        )

    def publish_health(self, t: float) -> None:
        self.publish(self.health(t))
        self.publish(self.safety.mode_state(t))
