"""``climbd run --sim WORLD``: the physics twin in the control role's process.

The twin replaces the world, never our code paths: the control role opens the profile's own
driver on the twin's port (the Dynamixel pty, or the virtual CAN channel of torque legs), and
the twin's ray-cast depth goes over Zenoh (``sim/depth``) to the perception role, which feeds
it into a pyrealsense2 software device as it would a camera. ``--stepped`` runs the loop on
simulated time in lock-step with the physics and, while a perception role answers, waits for
its features of each frame before simulating on (PerceptionGate), so perception sees the world
at the pace it would in real time. The twin also publishes its world's ground truth
(``sim/truth``, drivers/sim/truth.py) about once a second (TruthPublisher), for viewers to draw
beside perception's maps.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import numpy as np

from climbd.daemon.algorithms.estimation import EstimatorConfig
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import DepthFrame, Imu, ImuSample, mount_extrinsics
from climbd.daemon.contract.messages import DepthImage, Feature, Joists, Message, SimTruth
from climbd.daemon.contract.profile import CameraConfig, Profile
from climbd.daemon.runtime.loop import MonotonicClock, SteppedClock
from climbd.drivers.realsense.models import model
from climbd.drivers.sim.joist_outcomes import describe, joist_outcomes
from climbd.drivers.sim.topview import render_top_view
from climbd.drivers.sim.truth import truth_message
from climbd.drivers.torque.bus import waiting_for_replies

if TYPE_CHECKING:  # the twin (MuJoCo) loads only when a --sim run starts one
    from climbd.drivers.sim.twin import Twin

log = logging.getLogger("climbd.sim")

PERCEPTION_WAIT = 5.0
"""Wall seconds a stepped run waits for the features of a frame before going on without."""

FRAME_STAMP_TOLERANCE = 1e-6
"""Seconds an answer's ``frame_stamp`` may fall short of its frame's stamp and still answer it.

The stamp reaches the features through pyrealsense2's software device, which keeps time in
milliseconds: s -> ms -> s is not exact and comes back an ulp short for some stamps (in
``make demo`` one frame in 32, and one in 8 past 2^18 ms = 262.144 s, where the product in ms
loses a bit)."""

STEPPED_TIMEOUT_MARGIN_MS = 100.0
"""Dynamixel packet-timeout margin in stepped mode: replies wait for the physics step."""

STEPPED_REPLY_TIMEOUT = 0.05
"""MIT-mode reply timeout (s) in stepped mode, for the same reason."""
THREAD_REPLY_TIMEOUT = 0.0005
"""MIT-mode reply timeout (s) in real time: the twin's motors answer from a thread of this
interpreter, which runs only while the tick waits (a tick that never waits starves them until
they are taken for lost)."""


class PerceptionGate:
    """Lock-step of the twin's depth frames with perception: physics waits for the answer to
    the last frame rendered, from perception's first answer on (start-up is not waited for).

    A frame not answered within ``wait`` s is given up and said so; lock-step then pauses until
    perception answers again, so a stalled role costs one wait, not one per frame, and the
    control role's feature-age check holds the gait on the stale features.
    """

    def __init__(self, wait: float = PERCEPTION_WAIT) -> None:
        self.wait = wait
        self.given_up = 0
        self._pending = -math.inf
        self._answered = -math.inf
        self._waiting = False
        self._cond = threading.Condition()

    def rendered(self, stamp: float) -> None:
        """A frame taken at ``stamp`` (s, simulated) went to perception."""
        with self._cond:
            self._pending = stamp

    def answered(self, frame_stamp: float) -> None:
        """Perception published features of the frame taken at ``frame_stamp``."""
        with self._cond:
            if not self._waiting and self.given_up:
                log.warning(
                    "perception answers again (frame at %.2f s): lock-step resumes", frame_stamp
                )
            self._answered = max(self._answered, frame_stamp)
            self._waiting = True
            self._cond.notify_all()

    def _open(self) -> bool:
        return self._answered >= self._pending - FRAME_STAMP_TOLERANCE

    def pass_frame(self) -> bool:
        """Block until the last frame is answered (or lock-step is paused); False if given up."""
        with self._cond:
            if not self._waiting or self._open():
                return True
            end = time.monotonic() + self.wait
            while not self._open() and time.monotonic() < end:
                self._cond.wait(end - time.monotonic())
            if self._open():
                return True
            self.given_up += 1
            self._waiting = False
            log.warning(
                "perception did not answer the frame at %.2f s within %.0f s: simulating on "
                "without waiting for it until it answers again (the gait holds on stale features)",
                self._pending,
                self.wait,
            )
            return False


TRUTH_PERIOD = 1.0
"""Seconds between the twin's ``sim/truth`` messages (simulated seconds in a stepped run)."""


class TruthPublisher:
    """The world's ground truth (``sim/truth``), published at most once per ``period`` of
    whatever clock ``due`` is given (the first call publishes); nothing for a world without
    joists, stairs, holds or truss. The message is built once; each copy gets its stamp."""

    def __init__(
        self, message: SimTruth, publish: Callable[[Message], None], period: float = TRUTH_PERIOD
    ) -> None:
        self.message = message
        self.publish = publish
        self.period = period
        self.sent = 0
        self.empty = all(
            m is None for m in (message.joists, message.stairs, message.holds, message.truss)
        )
        self._next = -math.inf

    def due(self, t: float) -> None:
        """Publish the truth stamped ``t`` if ``period`` has passed since the last one."""
        if t >= self._next:
            self._next = t + self.period
            self.send(t)

    def send(self, t: float) -> None:
        """Publish the truth stamped ``t`` (unless the world has none)."""
        if not self.empty:
            self.publish(msgspec.structs.replace(self.message, stamp=t))
            self.sent += 1


class TwinImu:
    """The twin's IMU behind the hardware ``Imu`` interface."""

    def __init__(self, twin: Twin) -> None:
        self.twin = twin

    def read(self) -> ImuSample:
        return self.twin.imu_sample()


class SimHost:
    """The twin, its clock, its driver port, and the depth bridge of one control role."""

    def __init__(
        self,
        profile: Profile,
        world: str,
        stepped: bool,
        publish: Callable[[Message], None],
        depth_backend: str = "auto",
    ) -> None:
        from climbd.drivers.sim.twin import Twin

        self.profile = profile
        self.stepped = stepped
        self.publish = publish
        self.twin = Twin(profile, world, stepped=stepped, depth_backend=depth_backend)
        self.path: list[np.ndarray] = []
        self.times: list[float] = []
        """Simulated time (s) of each ``path`` sample."""
        self.detected: list[tuple[list[float], list[float]]] = []
        self.gate = PerceptionGate()
        self.truth = TruthPublisher(truth_message(self.twin.world), publish)
        self._truth_thread: threading.Thread | None = None
        self._truth_stop = threading.Event()
        self._next_sample = 0.0

    def start(self) -> None:
        self.twin.start()
        self.twin.on_depth(self._on_depth)
        self._sample()
        if not self.stepped and not self.truth.empty and self._truth_thread is None:
            self._truth_stop.clear()
            self._truth_thread = threading.Thread(
                target=self._publish_truth, name="twin-truth", daemon=True
            )
            self._truth_thread.start()

    def stop(self) -> None:
        self._truth_stop.set()
        if self._truth_thread is not None:
            self._truth_thread.join(timeout=2.0)
            self._truth_thread = None
        self.twin.stop()

    def _publish_truth(self) -> None:
        """Real time: the truth every TRUTH_PERIOD, stamped with the monotonic clock (the
        loop's clock in real time); a stepped run publishes it from ``_advance`` instead."""
        while not self._truth_stop.is_set():
            self.truth.send(time.monotonic())
            self._truth_stop.wait(self.truth.period)

    def driver(self) -> tuple[Profile, dict]:
        """The profile and options the control role opens its driver with, on the twin's port."""
        options: dict = {"port": self.twin.port}
        if self.profile.bus.kind == "torque":
            options["interface"] = "virtual"

            wait = STEPPED_REPLY_TIMEOUT if self.stepped else THREAD_REPLY_TIMEOUT
            return waiting_for_replies(self.profile, wait), options
        if self.stepped:
            options["timeout_margin_ms"] = STEPPED_TIMEOUT_MARGIN_MS
        return self.profile, options

    def attach(self, joint_bus) -> None:
        """Stepped mode: physics waits until the emulated bus handled all this driver sent."""
        self.twin.driver_sent = lambda: joint_bus.sent

    def clock(self):
        """The loop's clock: simulated time in lock-step, or the monotonic clock."""

        return SteppedClock(on_advance=self._advance) if self.stepped else MonotonicClock()

    def _advance(self, t0: float, t1: float) -> None:
        """Stepped mode: wait for perception's answer to the last frame, then simulate to t1."""
        self.gate.pass_frame()
        self.twin.advance_to(t1)
        self._sample_path(t1)
        self.truth.due(t1)

    def _sample_path(self, t: float) -> None:
        if t >= self._next_sample:
            self._next_sample = t + 0.1
            self._sample()

    def _sample(self) -> None:
        """Keep the body's position now in the path, with the simulated time."""
        self.path.append(self.twin.body_pose()[0].copy())
        self.times.append(self.twin.time)

    def _on_depth(self, camera: str, frame) -> None:
        """Publish a rendered frame for the perception role (``sim/depth``)."""
        depth = np.ascontiguousarray(frame.depth, dtype="<u2")
        self.gate.rendered(frame.timestamp)
        self.publish(
            DepthImage(
                stamp=frame.timestamp,
                camera=camera,
                width=depth.shape[1],
                height=depth.shape[0],
                depth_scale=frame.depth_scale,
                depth=depth.tobytes(),
            )
        )

    def on_feature(self, message: Feature) -> None:
        """A perception feature arrived: the frame it answers is done (lock-step)."""
        if self.stepped:
            self.gate.answered(message.frame_stamp)
        if isinstance(message, Joists) and message.joists:
            self._remember_joists(message.joists)

    def imu(self) -> Imu:
        """The twin's IMU behind the hardware ``Imu`` interface."""
        return TwinImu(self.twin)

    def estimator_start(self) -> tuple[EstimatorConfig, np.ndarray, np.ndarray]:
        """Paper 004's estimator calibrated from the twin's build (link masses, foot radius),
        and the body's start pose."""
        model = self.twin.model
        masses = [
            float(model.body_mass[model.body(j.name).id]) for j in self.profile.legs[0].joints
        ]
        config = EstimatorConfig(foot_radius=self.twin.robot.foot_radius, link_masses=masses)
        pos, quat = self.twin.body_pose()
        return config, pos, quat

    def _remember_joists(self, joists) -> None:
        """Detected joists in the world frame (for the top view), from the true body pose."""
        pos, quat = self.twin.body_pose()
        rot = rotation(quat)
        self.detected = [
            tuple((pos[:2] + (rot @ np.asarray(p[:3], float))[:2]).tolist() for p in j.endpoints)
            for j in joists
            if len(j.endpoints) == 2
        ]

    def end_of_run(self) -> None:
        """Note the robot's state when the run ends, before the safe stop lowers it."""
        self.final_height = float(self.twin.body_pose()[0][2])
        self.final_fallen = self.twin.fallen(self.profile.stand.body_height)
        self._sample()

    def summary(self, png: Path) -> str:
        """A one-screen account of the run and the top-view PNG it names."""

        path = np.array(self.path)
        start, end = path[0], path[-1]
        travelled = float(np.linalg.norm((end - start)[:2]))
        height = self.final_height
        at_joists = describe(joist_outcomes(self.twin.world, np.array(self.times), path))
        fallen = "yes" if self.final_fallen else "no"
        render_top_view(
            self.twin.world, path, png, self.detected, title=f"{self.profile.name} in the twin"
        )
        return (
            f"sim: {self.twin.world.name}, "
            f"{self.twin.time:.1f} s simulated; body moved {travelled:.2f} m "
            f"(x {end[0] - start[0]:+.2f} m, y {end[1] - start[1]:+.2f} m), body height "
            f"{height:.3f} m, fallen: {fallen}; "
            f"{len(self.detected)} joist(s) in the last detection; "
            + (f"perception frames given up: {self.gate.given_up}; " if self.stepped else "")
            + f"top view: {png}"
            + (f"\n{at_joists}" if at_joists else "")
        )


def sim_camera(profile: Profile, config: CameraConfig):
    """The perception role's camera in a sim run: a software device fed from ``sim/depth``."""
    from climbd.drivers.realsense.software import SoftwareDepthCamera

    spec = model(config.model)
    return SoftwareDepthCamera(
        spec.intrinsics(config.width, config.height),
        config.depth_units or spec.depth_unit,
        mount_extrinsics(config),
        fps=config.fps,
        model=config.model,
        config=config,
    )


def frame_of(image: DepthImage, config: CameraConfig) -> DepthFrame:
    """The DepthFrame the perception role's software camera makes of a ``sim/depth`` image of
    ``config``'s camera: the same intrinsics, depth units, mount and stamp (librealsense keeps
    it in ms: s → ms → s), so a recording's frames replay as they were perceived live."""
    spec = model(config.model)
    depth = np.frombuffer(image.depth, dtype="<u2").reshape(image.height, image.width)
    return DepthFrame(
        depth=depth,
        depth_scale=config.depth_units or spec.depth_unit,
        intrinsics=spec.intrinsics(config.width, config.height),
        extrinsics=mount_extrinsics(config),
        timestamp=(image.stamp * 1000.0) / 1000.0,
    )


def feed(camera, config: CameraConfig) -> Callable[[DepthImage], None]:
    """The ``sim/depth`` subscriber that pushes frames of ``config``'s camera into ``camera``."""

    def push(image: DepthImage) -> None:
        if image.camera != config.name:
            return
        if (image.width, image.height) != (config.width, config.height):
            log.error(
                "sim/depth %s is %dx%d, the profile's camera is %dx%d: frame dropped",
                image.camera,
                image.width,
                image.height,
                config.width,
                config.height,
            )
            return
        depth = np.frombuffer(image.depth, dtype="<u2").reshape(image.height, image.width)
        camera.push(depth, image.stamp)

    return push
