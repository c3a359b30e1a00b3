"""The physics twin: a robot from its profile in a world, speaking the hardware's protocols.

    twin = Twin(profile, "attic", stepped=True)   # or a World, or a path to a world file
    twin.start()                    # serves the emulated Dynamixel chain; real time unless stepped
    bus = DynamixelBus.from_profile(profile, port=twin.port)   # the real driver, on the pty
    twin.advance_to(t)              # stepped: physics to t (s); SteppedClock(on_advance=…)
    twin.step(n)                    # stepped: n physics steps
    twin.body_pose(); twin.foot_positions(); twin.foot_contacts()   # ground truth for tests
    twin.depth_frame("front"); twin.on_depth(callback)              # ray-cast depth
    camera = twin.software_camera("front")     # …entering pyrealsense2 through software_device
    twin.imu_sample()
    twin.overheat("rf_femur", 80.0); twin.silence("rf_femur"); twin.unplug()   # faults
    twin.stop()

Joint-space values ``q`` are servo horn angles about the centre (rad), in profile order: the
kinematic angle is θ = direction · (q − zero_offset), as in daemon/algorithms/kinematics.py.
Servos follow the chain's
goal positions, torque enable, moving speed and torque limit; the twin writes back present
position, speed, load, temperature (a thermal model) and voltage. Without a bus
(``bus=False``) ``command()`` / ``command_mit()`` set the goals in-process. Torque legs answer
MIT-mode CAN frames on a python-can ``virtual`` channel (``twin.port``) from the physics.
Stepped mode is deterministic: the same inputs give the same joint logs. Real-time mode runs
physics in a thread that follows the monotonic clock and renders depth at each camera's rate,
in a child process (drivers/sim/camera_process.py) unless ``camera_process=False``.
"""

from __future__ import annotations

import dataclasses
import fcntl
import inspect
import logging
import math
import sys
import termios
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from climbd.daemon.contract.hardware import DepthFrame, ImuSample
from climbd.daemon.contract.profile import Profile, gripper_servos
from climbd.daemon.contract.profile import load as load_profile
from climbd.drivers.sim import rest_pose, servos
from climbd.drivers.sim.camera_process import CameraProcess
from climbd.drivers.sim.depth import RayCastDepth
from climbd.drivers.sim.dynamixel import DynamixelEmulator, ServoChain
from climbd.drivers.sim.mit_motors import MitMotorChain
from climbd.drivers.sim.model import GRIP_FORCE, RobotModel, build
from climbd.drivers.sim.worlds import World
from climbd.drivers.sim.worlds import load as load_world
from climbd.drivers.torque.config import TorqueConfig

if TYPE_CHECKING:
    from climbd.drivers.realsense.software import SoftwareDepthCamera

log = logging.getLogger("climbd.sim")

DepthCallback = Callable[[str, DepthFrame], None]

SETTLE_COUNT_TIMEOUT = 5.0
"""Wall seconds the emulated bus has to handle what the driver sent before a step fails."""
FINGERS_ON_HOLD = 0.5
"""How far a gripper's fingers close (0 open, 1 closed on nothing) before they grasp a hold
between them: where they stop while it holds."""
IMU_WINDOW = 10
"""Physics steps the accelerometer averages over (10 ms at 1 kHz), as a MEMS accelerometer's
low-pass does: it reads the base's velocity change over them less gravity. MuJoCo's own
accelerometer reads the explicit qacc, which under the implicit integrator, the servos' stiff
damping and the grips' welds is not what the base does (HubRobo's odometry pitched 2.2° off
through its first swing on its wall; tests/test_sim.py)."""
GRASP_OFFSET = 0.016
"""How far (m, in the wall's plane) a foot may stand from a hold of a rock relief and still
close on it: the palm's radius (ClimbLab's gripper, 32 mm across), so the hold lies under the
palm as the spines close round it. A graspable point is one spot of a hold's graspable top,
which the camera's detection may place elsewhere on it by millimetres."""


@dataclass(frozen=True)
class HingeMap:
    """Joint space q ↔ physical hinge angles p: p = A · direction · (q − zero_offset).

    ``A`` is block-diagonal per leg: identity, or for absolute shank angles (paper 004) the
    knee hinge turns by θ_s − θ_t. Torques map by the transpose so power is preserved.
    """

    direction: np.ndarray
    zero_offset: np.ndarray
    a: np.ndarray
    a_inv: np.ndarray

    @classmethod
    def from_profile(cls, profile: Profile) -> HingeMap:
        n = len(profile.joints)
        a = np.eye(n)
        for i, leg in enumerate(profile.legs):
            if leg.kind == "abduction_thigh_shank":
                a[3 * i + 2, 3 * i + 1] = -1.0
        joints = profile.joints
        return cls(
            np.array([j.direction for j in joints], float),
            np.array([j.zero_offset for j in joints], float),
            a,
            np.linalg.inv(a),
        )

    def hinge(self, q: np.ndarray) -> np.ndarray:
        return self.a @ (self.direction * (np.asarray(q, float) - self.zero_offset))

    def joint(self, p: np.ndarray) -> np.ndarray:
        return self.direction * (self.a_inv @ p) + self.zero_offset

    def joint_rate(self, pd: np.ndarray) -> np.ndarray:
        return self.direction * (self.a_inv @ pd)

    def hinge_torque(self, tau_q: np.ndarray) -> np.ndarray:
        return self.a_inv.T @ (self.direction * tau_q)

    def joint_torque(self, tau_p: np.ndarray) -> np.ndarray:
        return self.direction * (self.a.T @ tau_p)


class PhysicsChain(ServoChain):
    """The emulated servo chain, answering from the physics at the instant of each packet.

    Before an instruction runs, the servos' present values are written from the twin's state;
    after it, goals and limits are read back — under the twin's lock, so a reply is a
    consistent snapshot and a write takes effect from the next physics step.
    """

    twin: Twin | None = None

    def handle(self, instr):
        twin = self.twin
        if twin is None:
            return super().handle(instr)
        with twin.lock, self.lock:
            twin._write_present()
            replies = super().handle(instr)
            twin._read_goals()
            return replies


class PhysicsMitChain(MitMotorChain):
    """Emulated MIT-mode motors on a virtual CAN channel, answering from the physics.

    Before a frame is handled the motor's state is written from the twin; after it, its
    motor mode and impedance command are read back, under the twin's lock.
    """

    twin: Twin | None = None

    def _handle(self, m, data: bytes) -> bytes | None:
        twin = self.twin
        if twin is None:
            return super()._handle(m, data)
        with twin.lock:
            k = twin.motor_index[m.motor]
            r, d = twin.robot, twin.data
            m.position = float(twin.map.joint(d.qpos[r.qpos_adr])[k])
            m.velocity = float(twin.map.joint_rate(d.qvel[r.dof_adr])[k])
            m.torque = float(twin.effort[k])
            reply = super()._handle(m, data)
            c = m.command
            twin.torque_on[k] = m.motor_mode and c is not None
            if c is not None:
                twin.goal[k], twin.mit_rate[k] = c.position, c.velocity
                twin.mit_kp[k], twin.mit_kd[k], twin.mit_ff[k] = c.kp, c.kd, c.torque
            return reply


class Twin:
    """MuJoCo physics of ``profile`` in ``world`` with emulated devices; see the module doc."""

    def __init__(
        self,
        profile: Profile | str | Path,
        world: World | str | Path = "attic",
        *,
        stepped: bool = False,
        timestep: float = 0.001,
        seed: int = 0,
        initial_joints: np.ndarray | None = None,
        bus: bool = True,
        depth_threads: int = 1,
        depth_backend: str = "auto",
        camera_duty: float = 0.5,
        camera_process: bool = True,
    ) -> None:
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        self.world = world if isinstance(world, World) else load_world(world)
        self.stepped = stepped
        self.camera_duty = camera_duty
        self.camera_process = camera_process
        self._depth_options = {
            "seed": seed,
            "depth_backend": depth_backend,
            "depth_threads": depth_threads,
        }
        self._camera_worker: CameraProcess | None = None
        self.robot: RobotModel = build(self.profile, self.world, timestep)
        self.model = self.robot.model
        self.data = mujoco.MjData(self.model)
        self.map = HingeMap.from_profile(self.profile)
        self.names = self.profile.joint_names
        self.ids = {j.name: j.id for j in self.profile.joints}
        r = self.robot
        self.stall = r.motor_array("stall_torque")
        self.no_load = r.motor_array("no_load_speed")
        self.kp_servo = r.motor_array("kp")
        self._heat = tuple(
            r.motor_array(k) for k in ("stall_power", "thermal_resistance", "heat_capacity")
        )
        self.lock = threading.RLock()
        n = r.joint_count
        self.goal = np.zeros(n)
        self.setpoint = np.zeros(n)
        self.torque_on = np.zeros(n, bool)
        self.speed_limit = self.no_load.copy()
        self.torque_limit = self.stall.copy()
        self.mit_rate = np.zeros(n)
        self.mit_kp = np.zeros(n)
        self.mit_kd = np.zeros(n)
        self.mit_ff = np.zeros(n)
        self.effort = np.zeros(n)
        self.thermal = servos.ThermalState(np.full(n, 30.0), ambient=30.0)
        self.voltage = 12.0
        self.grip = np.zeros(len(self.profile.legs), bool)
        self.fingers = np.zeros(len(self.profile.legs))
        """Per gripper, how far its fingers have closed: 0 open, 1 closed on nothing; they
        hold a hold at ``FINGERS_ON_HOLD``. The profile's gripper servo moves them at its speed
        (with or without an emulated bus); a gripper without one follows ``grip`` at once."""
        self.finger_rate = np.full(len(self.profile.legs), np.inf)
        """Per gripper, its fingers' speed (travel per s)."""
        for leg, _, g in gripper_servos(self.profile):
            self.finger_rate[leg] = g.velocity / abs(g.closed - g.open)
        self.slips = np.zeros(len(self.profile.legs), int)
        """Per gripper, how often it let go under more than GRIP_FORCE."""
        self.slipped = np.zeros(len(self.profile.legs), bool)
        self.grip_load = np.zeros(len(self.profile.legs))
        """Per gripper, the force (N) its hold needed at the last step (0 when not holding)."""
        self.chain = None
        self.emulator = None
        self.can_chain: PhysicsMitChain | None = None
        self.motor_index = {j.id: k for k, j in enumerate(self.profile.joints)}
        if bus and r.torque_legs:
            cfg = TorqueConfig.from_profile(self.profile)
            self.can_chain = PhysicsMitChain(
                [j.id for j in self.profile.joints],
                cfg.actuator,
                channel=f"climbd-twin-{self.profile.name}-{id(self):x}",
                interface="virtual",
                master_id=cfg.master_id,
                external_model=True,
            )
            self.can_chain.twin = self
        if bus and not r.torque_legs:
            self.chain = PhysicsChain.from_profile(self.profile)
            self.chain.twin = self
            for s in self.chain.servos.values():
                s.external = True
            self.emulator = DynamixelEmulator(self.chain, realtime_motor=False)
        self.cameras = {
            cam.name: RayCastDepth(
                self.model,
                cam,
                r.base_body,
                seed=seed + k,
                threads=depth_threads,
                backend=depth_backend,
            )
            for k, cam in enumerate(self.profile.cameras)
        }
        self._next_frame = dict.fromkeys(self.cameras, 0.0)
        self._depth_callbacks: list[DepthCallback] = []
        self._render_data = mujoco.MjData(self.model)
        sensor = self.model.sensor
        self._gyro = self.model.sensor_adr[sensor("imu_gyro").id]
        self._steps = 0
        self._velocities: deque[tuple[float, np.ndarray]] = deque(maxlen=IMU_WINDOW + 1)
        self._select_line: int | None = None
        self.driver_sent: Callable[[], int] | None = None
        """What the in-process driver put on the bus (bytes on the pty, frames on CAN): a
        stepped run then waits until the emulator handled exactly that much, so a loaded
        machine cannot change what physics sees."""
        self._recv_line: int | None = None
        self._thread: threading.Thread | None = None
        self._camera_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.lag = 0.0
        self.clock_offset = 0.0
        """Monotonic clock minus simulated time in real-time mode (0 in lock-step): frames are
        stamped on the clock the control role stamps body poses on."""
        self.reset(initial_joints)

    # --- lifecycle ----------------------------------------------------------------------

    @property
    def port(self) -> str:
        """Where the emulated bus answers: the Dynamixel pty path, or for torque legs the
        python-can ``virtual`` channel name; empty before ``start`` or without a bus."""
        if self.emulator is not None:
            return self.emulator.port
        if self.can_chain is not None and self.can_chain._thread is not None:
            return self.can_chain.channel
        return ""

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.data.time

    def start(self) -> Twin:
        """Serve the emulated devices; in real-time mode also run physics and cameras."""
        if self.emulator is not None and not self.emulator.port:
            self.emulator.start()
            self._sync_bus()
        if self.can_chain is not None and self.can_chain._thread is None:
            self.can_chain._stop.clear()
            self.can_chain.start()
        if not self.stepped and self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="twin-physics", daemon=True)
            self._thread.start()
            if self.cameras:
                if self.camera_process:
                    self._camera_worker = CameraProcess(
                        serve_cameras,
                        self.profile,
                        self.world,
                        self.model.opt.timestep,
                        **self._depth_options,
                    )
                self._camera_thread = threading.Thread(
                    target=self._run_cameras, name="twin-cameras", daemon=True
                )
                self._camera_thread.start()
        return self

    def stop(self) -> None:
        """Stop the threads and the emulated devices (idempotent)."""
        self._stop.set()
        for thread in (self._thread, self._camera_thread):
            if thread is not None:
                thread.join(timeout=2.0)
        self._thread = self._camera_thread = None
        if self._camera_worker is not None:
            self._camera_worker.close()
            self._camera_worker = None
        for cam in self.cameras.values():
            cam.close()
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator.port = ""
        if self.can_chain is not None and self.can_chain._thread is not None:
            self.can_chain.stop()
            self.can_chain._thread = None

    def __enter__(self) -> Twin:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def reset(self, initial_joints: np.ndarray | None = None) -> None:
        """Put the robot at the world's start, joints at ``initial_joints`` (q) or the rest pose."""
        m, d, r = self.model, self.data, self.robot
        with self.lock:
            mujoco.mj_resetData(m, d)
            self._velocities.clear()
            q = self.rest_joints() if initial_joints is None else np.asarray(initial_joints, float)
            d.qpos[:7] = r.start
            d.qpos[r.qpos_adr] = self.map.hinge(q)
            self._drop_onto_ground()
            self.goal[:] = self.setpoint[:] = q
            self.thermal.temperature[:] = self.thermal.ambient
            if self.chain is not None:
                with self.chain.lock:
                    for servo, qi in zip(self.chain.joints, q, strict=True):
                        servo.set("goal_position", servo.tick(qi))
            self._sync_bus()

    def rest_joints(self) -> np.ndarray:
        """The robot lying on its belly, feet on the ground at the nearest reach its limits allow.

        Reaches from the stand's ``foot_reach`` outward are tried with the closed-form leg IK
        of drivers/sim/rest_pose.py (the daemon's conventions, same knee branch).
        """
        found = rest_pose.rest_joints(
            self.profile, self.robot.foot_radius - self.robot.body_half_height
        )
        if found is None:
            raise ValueError(
                f"twin of {self.profile.name}: no rest pose (belly down, feet on the ground) "
                "within the joint limits; pass initial_joints"
            )
        return found[0]

    def _drop_onto_ground(self) -> None:
        """Raise the base until no robot geom touches the world, then 1 mm more."""
        m, d = self.model, self.data
        for _ in range(400):
            mujoco.mj_forward(m, d)
            if not any(d.contact.dist[: d.ncon] < 0):
                break
            d.qpos[2] += 0.005
        d.qpos[2] += 0.001
        mujoco.mj_forward(m, d)

    # --- physics ------------------------------------------------------------------------

    def _control(self) -> None:
        """Motor torques for this step, from the servo or MIT law in joint space."""
        r, d = self.robot, self.data
        p, pd = d.qpos[r.qpos_adr], d.qvel[r.dof_adr]
        q, qd = self.map.joint(p), self.map.joint_rate(pd)
        dt = self.model.opt.timestep
        if r.torque_legs:
            tau = servos.mit_torque(
                self.goal - q,
                self.mit_rate - qd,
                self.mit_kp,
                self.mit_kd,
                self.mit_ff,
                qd,
                self.stall,
                self.no_load,
            )
        else:
            step = self.speed_limit * dt
            self.setpoint += np.clip(self.goal - self.setpoint, -step, step)
            tau = servos.servo_torque(
                self.setpoint - q, qd, self.kp_servo, self.stall, self.no_load, self.torque_limit
            )
        tau = np.where(self.torque_on, tau, 0.0)
        self.effort = tau
        d.ctrl[r.motor_actuators] = self.map.hinge_torque(tau)
        if len(r.grip_equalities):
            self._grip_update()

    def _grip_update(self) -> None:
        """Grippers as connect constraints: one engages as its closing fingers reach
        ``FINGERS_ON_HOLD`` while its foot touches a graspable geom (fingers closed all the way
        grasp nothing), and slips (lets go, counted in ``slips``) when the force it needs
        exceeds GRIP_FORCE; it engages again only after it has been opened. While it holds, the
        grip replaces the foot's contact (the spines enclose the hold)."""
        d, r, m = self.data, self.robot, self.model
        was = d.eq_active[r.grip_equalities].astype(bool)
        held = was.copy()
        step = self.finger_rate * self.model.opt.timestep
        goal = np.where(self.grip, np.where(held, FINGERS_ON_HOLD, 1.0), 0.0)
        self.fingers += np.clip(goal - self.fingers, -step, step)
        closed = self.fingers >= FINGERS_ON_HOLD - 1e-9
        closing = closed & ((self.fingers < 1.0) | np.isinf(self.finger_rate))
        if held.any():
            rows = slice(0, d.ne)
            square = np.bincount(d.efc_id[rows], d.efc_force[rows] ** 2, minlength=m.neq)
            self.grip_load[:] = np.sqrt(square[r.grip_equalities])
            slip = held & (self.grip_load > GRIP_FORCE)
            self.slips += slip
            self.slipped |= slip
            held &= ~slip
        self.slipped &= self.grip
        engage = closing & ~held & ~self.slipped
        if engage.any():
            engage &= self._on_hold()
            for i in np.flatnonzero(engage):
                m.eq_data[r.grip_equalities[i], 3:6] = d.site_xpos[r.foot_sites[i]]
        held = (held | engage) & closed
        self.grip_load[~held] = 0.0
        if (held != was).any():
            d.eq_active[r.grip_equalities] = held
            m.geom_contype[r.foot_geoms] = np.where(held, 0, 1)

    def _on_hold(self) -> np.ndarray:
        """Which feet touch a graspable geom; on a rock relief, only within ``GRASP_OFFSET`` of
        one of its holds (in the wall's plane), as the spines close only around a hold."""
        d, r = self.data, self.robot
        g1, g2 = d.contact.geom1[: d.ncon], d.contact.geom2[: d.ncon]
        foot, other = np.concatenate([g1, g2]), np.concatenate([g2, g1])
        grasped = np.isin(other, r.graspable_geoms)
        on = np.isin(r.foot_geoms, foot[grasped & (other != r.relief_geom)])
        on_rock = np.isin(r.foot_geoms, foot[grasped & (other == r.relief_geom)]) & ~on
        for leg in np.flatnonzero(on_rock):
            on[leg] = self._near_hold(d.site_xpos[r.foot_sites[leg]])
        return on

    def _near_hold(self, foot: np.ndarray) -> bool:
        r = self.robot
        if not len(r.relief_holds):
            return False
        offset = r.relief_holds - foot
        offset -= np.outer(offset @ r.wall_normal, r.wall_normal)
        return bool(np.min(np.linalg.norm(offset, axis=1)) <= GRASP_OFFSET)

    def _physics_step(self) -> None:
        self._control()
        mujoco.mj_step(self.model, self.data)
        self._steps += 1
        self._velocities.append((self.data.time, self.data.qvel[:3].copy()))
        self.thermal.advance(self.effort / self.stall, *self._heat, self.model.opt.timestep)

    def _read_goals(self) -> None:
        """Goal position, torque enable, speed and torque limits from the chain's tables; a
        powered gripper servo whose goal lies past the first quarter of its travel from open
        closes its gripper (a goal where the fingers stopped on a hold keeps it closed)."""
        for k, servo in enumerate(self.chain.joints):
            self.goal[k] = servo.goal_angle
            self.torque_on[k] = servo.torque_enabled
            self.speed_limit[k] = servo.speed_limit
            limit = "torque_limit" if servo.spec.protocol == 1 else "pwm_limit"
            cap = servo.get(limit) / servo.spec.fields[limit].default
            self.torque_limit[k] = self.stall[k] * cap
        for leg, servo in self.chain.grippers.items():
            g = self.profile.legs[leg].gripper_servo
            closing = (servo.goal_angle - g.open) / (g.closed - g.open) > 0.25
            self.grip[leg] = closing and servo.torque_enabled

    def _write_present(self) -> None:
        """Present position, speed, load, temperature and voltage into the chain's tables."""
        r, d = self.robot, self.data
        q = self.map.joint(d.qpos[r.qpos_adr])
        qd = self.map.joint_rate(d.qvel[r.dof_adr])
        for k, servo in enumerate(self.chain.joints):
            servo.set_present(
                angle=q[k],
                velocity=qd[k],
                effort=self.effort[k],
                temperature=self.thermal.temperature[k],
                voltage=self.voltage,
            )
        held = self.holding()
        for leg, servo in self.chain.grippers.items():
            g = self.profile.legs[leg].gripper_servo
            at = self.fingers[leg]
            goal = (FINGERS_ON_HOLD if held[leg] else 1.0) if self.grip[leg] else 0.0
            speed = 0.0 if at == goal else np.sign(goal - at) * g.velocity
            servo.set_present(
                angle=g.open + at * (g.closed - g.open),
                velocity=speed * np.sign(g.closed - g.open),
                temperature=30.0,
                voltage=self.voltage,
            )

    def _sync_bus(self) -> None:
        """Exchange with the emulated chain now (physics lock held by the caller)."""
        if self.chain is not None:
            with self.chain.lock:
                self._write_present()
                self._read_goals()

    def step(self, n: int = 1) -> None:
        """Advance physics by ``n`` steps (stepped mode, or before ``start``)."""
        with self.lock:
            for _ in range(n):
                self._physics_step()
                self._cameras_due()

    def advance_to(self, t: float, t1: float | None = None) -> None:
        """Step physics until simulated time reaches ``t`` (s).

        Also accepts ``(t0, t1)`` as SteppedClock's ``on_advance`` passes them. Waits first for
        the emulated bus to finish the bytes the driver wrote, so goals are applied in order.
        """
        target = t if t1 is None else t1
        self._settle_bus()
        h = self.model.opt.timestep
        with self.lock:
            while self.data.time < target - 0.5 * h:
                self._physics_step()
                self._cameras_due()

    def _settle_bus(self) -> None:
        """Wait until the emulated bus has handled everything the driver sent."""
        if self.driver_sent is not None:
            self._settle_count()
        elif self.can_chain is not None:
            self._settle_can()
        else:
            self._settle_pty()

    def _settle_can(self) -> None:
        """The virtual CAN channel's queue is empty and the chain's thread waits in receive(),
        twice 0.5 ms apart."""
        chain = self.can_chain
        if chain._thread is None or chain._link is None:
            return
        if self._recv_line is None:
            source, first = inspect.getsourcelines(type(chain)._serve)
            self._recv_line = first + next(
                i for i, line in enumerate(source) if ".receive(" in line
            )
        deadline = time.monotonic() + 0.5
        idle = 0
        while idle < 2 and time.monotonic() < deadline:
            frame = sys._current_frames().get(chain._thread.ident)
            while frame is not None and frame.f_code is not type(chain)._serve.__code__:
                frame = frame.f_back
            quiet = chain._link.bus.queue.empty() and frame is not None
            quiet = quiet and frame.f_lineno == self._recv_line
            idle = idle + 1 if quiet else 0
            time.sleep(0.0005)

    def _settle_pty(self) -> None:
        """Wait until the emulator has handled every byte the driver wrote to the pty.

        True when the pty holds no unread bytes and the emulator thread sits in its select()
        (a thread that has read bytes is past that line until it has handled them), twice
        0.5 ms apart: the kernel hands bytes from the pty's slave to its master asynchronously.
        """
        emu = self.emulator
        if emu is None or emu._master < 0 or emu._thread is None:
            return
        if self._select_line is None:
            source, first = inspect.getsourcelines(type(emu)._serve)
            self._select_line = first + next(
                i for i, line in enumerate(source) if "select.select(" in line
            )
        pending = np.zeros(1, np.int32)
        deadline = time.monotonic() + 0.5
        idle = 0
        while idle < 2 and time.monotonic() < deadline:
            fcntl.ioctl(emu._master, termios.FIONREAD, pending)
            frame = sys._current_frames().get(emu._thread.ident)
            quiet = pending[0] == 0 and frame is not None and frame.f_lineno == self._select_line
            idle = idle + 1 if quiet else 0
            time.sleep(0.0005)

    def _handled(self) -> int:
        """What the emulator has handled, in the units of ``driver_sent``."""
        if self.can_chain is not None:
            return sum(m.frames for m in self.can_chain.motors.values())
        return self.emulator.bytes_handled

    def _settle_count(self) -> None:
        """Wait until the emulator handled all the driver sent (``driver_sent``)."""
        want = self.driver_sent()
        deadline = time.monotonic() + SETTLE_COUNT_TIMEOUT
        while self._handled() < want:
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"{self.profile.name} twin: the emulated bus handled {self._handled()} of "
                    f"{want} sent in {SETTLE_COUNT_TIMEOUT:g} s"
                )
            time.sleep(0.0001)

    def _run(self) -> None:
        """Real-time mode: keep simulated time on the monotonic clock, in 2 ms batches."""
        h = self.model.opt.timestep
        wall0, sim0 = time.monotonic(), self.data.time
        self.clock_offset = wall0 - sim0
        while not self._stop.is_set():
            target = sim0 + time.monotonic() - wall0
            with self.lock:
                behind = target - self.data.time
                if behind > 0.1:
                    wall0 += behind
                    self.lag += behind
                    self.clock_offset = wall0 - sim0
                    target = sim0 + time.monotonic() - wall0
            while self.data.time < target - 0.5 * h and not self._stop.is_set():
                with self.lock:  # per step: a bus packet waits one step, not a catch-up batch
                    self._physics_step()
            time.sleep(0.002)

    def _run_cameras(self) -> None:
        """Real-time mode: render every camera at its rate and hand frames to the callbacks.

        The thread may use at most ``camera_duty`` of a core of this process: after frames that
        cost it c seconds of CPU it rests c · (1/duty − 1), so a camera too costly for its rate
        drops frames (as a USB camera on a busy host does) instead of starving the daemon
        beside it. With the camera process it only waits for the child, which costs no rest.
        """
        rest = 1.0 / self.camera_duty - 1.0
        while not self._stop.is_set():
            c0 = time.thread_time()
            if self._depth_callbacks:
                self._cameras_due()
            time.sleep(max(0.002, (time.thread_time() - c0) * rest))

    def _cameras_due(self) -> None:
        if not self._depth_callbacks:
            return
        now = self.data.time
        for name, cam in self.cameras.items():
            if now + 1e-9 >= self._next_frame[name]:
                self._next_frame[name] = max(self._next_frame[name] + cam.period, now)
                frame = self._render(name)
                if self.clock_offset:
                    frame = dataclasses.replace(
                        frame, timestamp=frame.timestamp + self.clock_offset
                    )
                for callback in self._depth_callbacks:
                    callback(name, frame)

    def _render(self, name: str) -> DepthFrame:
        """A frame of camera ``name`` now: from the camera process in real time, else here."""
        worker = self._camera_worker
        if worker is None:
            return self.depth_frame(name)
        with self.lock:
            qpos, t = self.data.qpos.copy(), self.data.time
        return worker.render(self.cameras[name], name, qpos, t)

    # --- commands without a bus -------------------------------------------------------------

    def command(self, positions: np.ndarray, torque: bool = True) -> None:
        """Set servo goals (q, rad) and torque in-process, for robots run without a bus."""
        with self.lock:
            self.goal[:] = positions
            self.torque_on[:] = torque

    def command_mit(self, position, velocity, kp, kd, effort) -> None:
        """Set MIT-mode targets of torque legs: q, q̇, kp, kd, τ_ff (arrays in joint order)."""
        with self.lock:
            self.goal[:] = position
            self.mit_rate[:] = velocity
            self.mit_kp[:] = kp
            self.mit_kd[:] = kd
            self.mit_ff[:] = effort
            self.torque_on[:] = True

    def set_grip(self, leg: int | str, closed: bool) -> None:
        """Close or open one gripper (HubRobo); it holds only on graspable geoms, up to 9 N."""
        i = leg if isinstance(leg, int) else [g.name for g in self.profile.legs].index(leg)
        self.grip[i] = closed

    # --- ground truth -----------------------------------------------------------------------

    def body_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Base position (m, world) and orientation quaternion (w, x, y, z)."""
        with self.lock:
            return self.data.qpos[:3].copy(), self.data.qpos[3:7].copy()

    def joint_positions(self) -> np.ndarray:
        """Joint positions q (rad) in profile order."""
        with self.lock:
            return self.map.joint(self.data.qpos[self.robot.qpos_adr])

    def joint_velocities(self) -> np.ndarray:
        with self.lock:
            return self.map.joint_rate(self.data.qvel[self.robot.dof_adr])

    def joint_efforts(self) -> np.ndarray:
        """Joint torques (N·m, joint space): the motors' output, as a torque sensor reads it."""
        with self.lock:
            return self.effort.copy()

    def foot_positions(self) -> np.ndarray:
        """Foot centres (m, world frame), one row per leg."""
        with self.lock:
            return self.data.site_xpos[self.robot.foot_sites].copy()

    def foot_orientations(self) -> np.ndarray:
        """Foot balls' rotations (world frame, 3×3 each), one per leg: with the centres, how far
        a foot rolled and how far it slid."""
        with self.lock:
            return self.data.geom_xmat[self.robot.foot_geoms].reshape(-1, 3, 3).copy()

    def foot_contacts(self) -> np.ndarray:
        """Whether each foot touches the world now."""
        feet = self.robot.foot_geoms
        with self.lock:
            d = self.data
            touching = set(d.contact.geom1[: d.ncon]) | set(d.contact.geom2[: d.ncon])
            return np.array([f in touching for f in feet])

    def holding(self) -> np.ndarray:
        """Whether each gripper holds a graspable geom now (its grip constraint is engaged)."""
        r = self.robot
        with self.lock:
            held = np.zeros(len(self.profile.legs), bool)
            if len(r.grip_equalities):
                held[:] = self.data.eq_active[r.grip_equalities]
            return held

    def base_contacts(self) -> bool:
        """Whether the body box touches the world (a belly landing or a fall)."""
        base_geom = self.model.body_geomadr[self.robot.base_body]
        with self.lock:
            d = self.data
            return bool(
                np.any(d.contact.geom1[: d.ncon] == base_geom)
                or np.any(d.contact.geom2[: d.ncon] == base_geom)
            )

    # --- devices ----------------------------------------------------------------------------

    def depth_frame(self, camera: str) -> DepthFrame:
        """Ray-cast one frame of ``camera`` at the current state (a copy of it, off the lock)."""
        cam = self.cameras[camera]
        with self.lock:
            rd = self._render_data
            rd.qpos[:] = self.data.qpos
            rd.time = self.data.time
        mujoco.mj_kinematics(self.model, rd)
        return cam.render(rd, rd.time)

    def on_depth(self, callback: DepthCallback) -> None:
        """Call ``callback(camera, frame)`` at each camera's frame rate (simulated time)."""
        self._depth_callbacks.append(callback)

    def software_camera(self, camera: str, fed: bool = True, **options) -> SoftwareDepthCamera:
        """A pyrealsense2 software device fed with ``camera``'s frames at its frame rate, as the
        perception role reads a USB camera (``fed`` False: the caller pushes the frames it
        takes, e.g. a stepped harness that ray-casts only the frames it perceives); ``options``
        go to SoftwareDepthCamera (e.g. ``record_to``)."""
        from climbd.drivers.realsense.software import SoftwareDepthCamera

        cam = self.cameras[camera]
        config = next(c for c in self.profile.cameras if c.name == camera)
        device = SoftwareDepthCamera(
            cam.intrinsics,
            cam.depth_scale,
            cam.extrinsics,
            fps=config.fps,
            model=config.model,
            config=config,
            **options,
        )

        def push(name: str, frame: DepthFrame) -> None:
            if name == camera:
                device.push(frame.depth, frame.timestamp)

        if fed:
            self.on_depth(push)
        return device

    def imu_sample(self) -> ImuSample:
        """Gyro (rad/s) and specific force (m/s², gravity included) in the body frame: the
        base's acceleration over the last ``IMU_WINDOW`` physics steps less gravity."""
        with self.lock:
            d = self.data
            acceleration = np.zeros(3)
            if len(self._velocities) > 1:
                (t0, v0), (t1, v1) = self._velocities[0], self._velocities[-1]
                acceleration = (v1 - v0) / (t1 - t0)
            base = d.xmat[self.robot.base_body].reshape(3, 3)
            return ImuSample(
                d.time,
                d.sensordata[self._gyro : self._gyro + 3].copy(),
                (acceleration - self.model.opt.gravity) @ base,
            )

    # --- faults -----------------------------------------------------------------------------

    def _servo(self, joint: str):
        if joint not in self.ids:
            raise ValueError(f"twin of {self.profile.name}: no joint {joint!r}")
        if self.chain is None:
            raise ValueError(
                f"twin of {self.profile.name}: no emulated Dynamixel servo behind {joint!r}"
            )
        return self.chain.servo(self.ids[joint])

    def overheat(self, joint: str, temperature: float) -> None:
        """Heat one winding to ``temperature`` (°C); it cools by the thermal model."""
        self._servo(joint)
        with self.lock:
            self.thermal.temperature[self.names.index(joint)] = temperature
            self._sync_bus()

    def brownout(self, voltage: float) -> None:
        """Set the supply voltage every servo reports (V), e.g. a sagging battery."""
        with self.lock:
            self.voltage = voltage
            self._sync_bus()

    def overload(self, joint: str, on: bool = True) -> None:
        """Raise (or clear) one servo's overload condition."""
        self._servo(joint).inject_overload(on)

    def silence(self, joint: str, on: bool = True) -> None:
        """One servo or motor stops (or resumes) answering, as with a loose cable."""
        if self.can_chain is not None and joint in self.ids:
            self.can_chain.silence(self.ids[joint], on)
            return
        self._servo(joint)
        self.chain.silence(self.ids[joint], on)

    def corrupt(self, joint: str, count: int | None = 1) -> None:
        """Replies of one servo carry a bad checksum (the next ``count``), or one motor's
        replies come truncated (until ``count`` is 0)."""
        if self.can_chain is not None and joint in self.ids:
            self.can_chain.corrupt(self.ids[joint], count != 0)
            return
        self._servo(joint)
        self.chain.corrupt(self.ids[joint], count)

    def unplug(self) -> None:
        """The bus adapter goes: the pty closes under the driver, or the CAN bus goes bus-off."""
        if self.emulator is not None:
            self.emulator.vanish()
        if self.can_chain is not None:
            self.can_chain.bus_off()

    # --- measures ---------------------------------------------------------------------------

    def fallen(self, stand_height: float, tolerance: float = 0.5) -> bool:
        """Whether the body is below ``tolerance`` × its stand height or tilted past 45°."""
        pos, quat = self.body_pose()
        up = 1.0 - 2.0 * (quat[1] ** 2 + quat[2] ** 2)
        return bool(pos[2] < tolerance * stand_height or up < math.cos(math.radians(45)))


def serve_cameras(
    conn: Connection, profile: Profile, world: World, timestep: float, options: dict
) -> None:
    """A camera process's loop (drivers/sim/camera_process.py): its own twin of the world
    renders each requested (camera, qpos, time) and answers with the uint16 image."""
    twin = Twin(profile, world, stepped=True, timestep=timestep, bus=False, **options)
    conn.send(True)
    try:
        while True:
            try:
                request = conn.recv()
            except EOFError:
                return
            if request is None:
                return
            camera, qpos, t = request
            twin.data.qpos[:] = qpos
            twin.data.time = t
            frame = twin.depth_frame(camera)
            conn.send_bytes(frame.depth.tobytes())
    finally:
        twin.stop()
