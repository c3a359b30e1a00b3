"""The control role of one robot: joint bus, control loop, safety and Zenoh, wired for a run.

The asyncio main thread owns the Zenoh network, signals and reporting; the ControlLoop runs in
its own thread so I/O on the asyncio side never delays a tick. SIGTERM/SIGINT bring the
robot to a safe pose under the profile's e-stop policy, then the process exits 0. The driver
is found through its entry point; a ``--sim`` run's twin comes from the CLI as a ``TwinHost``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import logging
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from climbd.daemon.algorithms.estimation import EstimatorConfig, StateEstimator
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.hardware import (
    CountsSent,
    DriverError,
    Imu,
    JointBus,
)
from climbd.daemon.contract.plugins import GaitPlugin, PluginError
from climbd.daemon.contract.profile import Profile, ProfileError
from climbd.daemon.runtime import sdnotify
from climbd.daemon.runtime.access import AccessError, TelemetryGate
from climbd.daemon.runtime.loader import instantiate, load_class
from climbd.daemon.runtime.loop import Clock, MonotonicClock
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config
from climbd.daemon.runtime.stack import control_stack

log = logging.getLogger("climbd.run")

SHUTDOWN_TIMEOUT = 5.0
"""Seconds the safe-pose motion may take at shutdown before the policy is applied anyway."""


class StartupError(RuntimeError):
    """The role cannot start (device, plugin or network problem); the message says which."""


def role_network(
    profile: Profile, role: str, args: argparse.Namespace, aio: asyncio.AbstractEventLoop
) -> Network:
    """The role's Zenoh session: the profile's endpoints for ``role``, or ``--listen`` and
    ``--connect``; a bad endpoint or a port in use is a StartupError."""
    endpoints = None
    if args.listen or args.connect:
        endpoints = Endpoints(args.listen or [], args.connect or [])
    try:
        return Network(profile.name, zenoh_config(profile, role, endpoints), aio)
    except AccessError as e:
        raise StartupError(str(e)) from None
    except Exception as e:  # zenoh raises ZError for a bad endpoint or a port in use
        raise StartupError(f"zenoh: {e}") from None


def make_joint_bus(profile: Profile, driver: str | None, options: dict) -> JointBus:
    """Open the joint bus named ``driver`` (an entry point in climbd.drivers) for ``profile``."""
    name = driver or profile.bus.kind
    try:
        cls = load_class("climbd.drivers", name)
    except PluginError as e:
        raise StartupError(str(e)) from None
    try:
        bus = cls.from_profile(profile, **options)
        bus.open()
    except (DriverError, ProfileError) as e:
        raise StartupError(f"joint bus {name!r}: {e}") from None
    return bus


def make_gait(profile: Profile, name: str | None) -> GaitPlugin | None:
    """The gait plugin ACTIVE runs; None when the profile configures none."""
    specs = {spec.name: spec for spec in profile.plugins.gaits}
    name = name or profile.plugins.default_gait or next(iter(specs), None)
    if name is None:
        return None
    overrides = specs[name].config if name in specs else {}
    try:
        plugin = instantiate(
            "climbd.gaits", name, overrides, profile, f"{profile.source}: gait {name}"
        )
    except PluginError as e:
        raise StartupError(str(e)) from None
    return plugin


class TwinHost(Protocol):
    """What the control role asks of the physics twin of a ``--sim`` run (the CLI builds it)."""

    stepped: bool

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def driver(self) -> tuple[Profile, dict]: ...

    def attach(self, joint_bus: CountsSent) -> None: ...

    def clock(self) -> Clock: ...

    def imu(self) -> Imu: ...

    def estimator_start(self) -> tuple[EstimatorConfig, np.ndarray, np.ndarray]: ...

    def on_feature(self, message: m.Message) -> None: ...

    def end_of_run(self) -> None: ...

    def summary(self, png: Path) -> str: ...


def feature_types(profile: Profile) -> tuple[type[m.Feature], ...]:
    """The features the control role takes: the contract's own, and those the profile's
    perception plugins declare they publish (a third-party plugin may bring its own type)."""
    types: list[type[m.Feature]] = list(m.FEATURES)
    for spec in profile.plugins.perception:
        try:
            cls = load_class("climbd.perception", spec.name)
        except PluginError as e:
            raise StartupError(str(e)) from None
        types += [t for t in cls.publishes if t not in types]
    return tuple(types)


class ControlRole:
    """Wires profile, joint bus, safety, controller, loop and Zenoh together for one run."""

    def __init__(
        self,
        profile: Profile,
        args: argparse.Namespace,
        twin: Callable[[Callable[[m.Message], None]], TwinHost] | None = None,
    ) -> None:
        """``twin``, for a ``--sim`` run, makes the started twin host given the publisher."""
        self.profile = profile
        self.args = args
        self.twin = twin

    async def run(self) -> int:
        profile, args = self.profile, self.args
        aio = asyncio.get_running_loop()
        clock: Clock = MonotonicClock()
        net = role_network(profile, "control", args, aio)
        net.declare(m.JointState, m.JointCommand, m.BodyState, m.FootTargets, m.Health, m.ModeState)
        gate = None
        if profile.network.auth is not None and profile.network.auth.telemetry_listen:
            gate = TelemetryGate(profile.name, list(profile.network.auth.telemetry_listen))

        def publish(message: m.Message) -> None:
            net.put(message)
            if gate is not None:
                gate.put(message)

        sim, driver_profile = None, profile
        options = {"port": args.port} if args.port else {}
        try:
            if self.twin is not None:
                sim = self.twin(publish)
                driver_profile, options = sim.driver()
                clock = sim.clock()
            joint_bus = make_joint_bus(driver_profile, args.driver, options)
            if sim is not None and sim.stepped:
                if not isinstance(joint_bus, CountsSent):
                    raise StartupError(
                        f"--sim --stepped: driver {args.driver!r} does not talk to the twin's "
                        "emulated bus; leave --driver out to use the profile's own"
                    )
                sim.attach(joint_bus)
        except StartupError:
            if sim is not None:
                sim.stop()
            net.close()
            raise
        self.clock = clock
        estimator, imu = self._estimator(sim)
        stack = control_stack(
            profile,
            joint_bus,
            clock,
            make_gait(profile, args.gait),
            publish=publish,
            estimator=estimator,
            imu=imu,
            feed_forward=estimator is not None,
        )
        safety, controller, loop = stack.safety, stack.controller, stack.loop
        controller.undecodable = net.undecodable
        if gate is not None:
            controller.unauthorised = lambda: gate.attempts
        net.subscribe(m.MotionCommand, controller.on_motion, latest_only=True)
        net.subscribe(m.ModeRequest, controller.on_mode)
        net.subscribe(m.EStop, controller.on_estop)
        net.subscribe(m.SessionClaim, controller.on_claim)
        net.subscribe(m.Heartbeat, controller.on_heartbeat)
        net.subscribe(m.ResetRequest, controller.on_reset)
        net.subscribe(m.OverrideClaim, controller.on_override)
        for feature in feature_types(profile):
            net.subscribe(feature, controller.on_feature, latest_only=True)
            if sim is not None:
                net.subscribe(feature, sim.on_feature)
        net.alive("control")

        stop = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            aio.add_signal_handler(sig, stop.set)
        gc.collect()
        gc.freeze()  # start-up objects leave the collector's scans: shorter pauses in the loop
        thread = threading.Thread(target=loop.run, name="control-loop", daemon=True)
        thread.start()
        print(
            f"climbd: {profile.name} control role, {profile.rate_hz:g} Hz, "
            f"{len(profile.joints)} joints, e-stop policy {safety.policy.value}",
            flush=True,
        )
        if not args.no_stand:
            safety.request(m.Mode.STAND, clock.now(), reason="start-up")
        sdnotify.notify("READY=1")
        await self._supervise(stop, loop, safety, controller, sdnotify.watchdog_period())
        if sim is not None:
            sim.end_of_run()
        await self._safe_stop(controller, safety, loop, clock)
        loop.stop()
        await aio.run_in_executor(None, thread.join, 2.0)
        gc.unfreeze()  # frozen objects are never freed: ruckig's would be reported as leaks
        sdnotify.notify("STOPPING=1")
        joint_bus.close()
        if sim is not None:
            sim.stop()  # before the net closes: the twin's cameras publish on it
        net.close()
        if gate is not None:
            gate.close()
        self._report(loop, safety, controller)
        if sim is not None:
            print(sim.summary(Path(args.snapshot)), flush=True)
        return 0

    def _estimator(self, sim: TwinHost | None) -> tuple[StateEstimator | None, Imu | None]:
        """Profiles with joint torque sensing (torque legs) get paper 004's state estimator, and
        the gravity feed-forward; in the twin, calibrated from its build and fed its IMU. Other
        profiles get leg odometry, fused with the twin's IMU in the twin."""
        profile = self.profile
        if profile.bus.kind != "torque":
            return None, (sim.imu() if sim is not None else None)
        if sim is None:
            config = EstimatorConfig(foot_radius=profile.foot_radius or 0.0)
            return StateEstimator(profile, config), None
        config, pos, quat = sim.estimator_start()
        return StateEstimator(profile, config, pos, quat), sim.imu()

    async def _supervise(
        self, stop: asyncio.Event, loop, safety, controller, watchdog: float | None
    ) -> None:
        """Print statistics, ping the watchdog while ticks advance, await stop; modes are logged.
        ``--activate`` activates once the stand is complete and the gait's features are fresh
        (perception may start after the stand: activated before, the gait would hold at once)."""
        aio = asyncio.get_running_loop()
        clock = self.clock
        end = clock.now() + self.args.duration if self.args.duration else None
        activate, waiting = self.args.activate, False
        last_ticks, last_stats, last_ping = -1, aio.time(), aio.time()
        while not stop.is_set():
            now = aio.time()
            if watchdog is not None and now - last_ping >= watchdog and loop.ticks != last_ticks:
                sdnotify.notify("WATCHDOG=1")
                last_ticks, last_ping = loop.ticks, now
            if not self.args.quiet and now - last_stats >= 1.0:
                last_stats = now
                s = loop.stats()
                print(
                    f"loop {s.ticks} ticks, lateness p50 {s.lateness_p50 * 1e6:.0f} µs "
                    f"p99 {s.lateness_p99 * 1e6:.0f} µs, compute p50 {s.compute_p50 * 1e6:.0f} µs, "
                    f"overruns {s.overruns}, mode {safety.mode.value}",
                    flush=True,
                )
            if activate and safety.mode == m.Mode.HOLD and safety.reason == "stand complete":
                awaited = controller.awaiting(clock.now())
                if not awaited:
                    activate = False
                    safety.request(m.Mode.ACTIVE, clock.now(), reason="autonomy (--activate)")
                elif not waiting:
                    waiting = True
                    log.info("--activate: standing until %s arrive", ", ".join(awaited))
            if end is not None and clock.now() >= end:
                break
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.05)

    async def _safe_stop(self, controller, safety, loop, clock) -> None:
        """Bring the robot to its safe pose under the profile's policy before exiting."""
        controller.begin_shutdown(clock.now())
        deadline = clock.now() + SHUTDOWN_TIMEOUT
        while not controller.shutdown_done and clock.now() < deadline and not loop.stopped:
            await asyncio.sleep(controller.dt * 5)
        if not controller.shutdown_done:
            log.warning(
                "safe pose not reached in %.1f s; applying the e-stop policy", SHUTDOWN_TIMEOUT
            )
            controller.finish_shutdown()
            give_up = asyncio.get_running_loop().time() + 1.0
            while not controller.shutdown_done and asyncio.get_running_loop().time() < give_up:
                await asyncio.sleep(controller.dt * 5)

    def _report(self, loop, safety, controller) -> None:
        s = loop.stats()
        pose = "torque on, holding the commanded pose" if safety.torque_on else "torque off"
        if controller.sat_down:
            pose = "sat down, then torque off"
        print(
            f"climbd: stopped in {safety.mode.value} ({safety.reason}), {pose}; {s.ticks} ticks at "
            f"{s.rate_hz:g} Hz, lateness p50 {s.lateness_p50 * 1e6:.0f} µs p99 "
            f"{s.lateness_p99 * 1e6:.0f} µs max {s.lateness_max * 1e6:.0f} µs, "
            f"overruns {s.overruns}, refused commands {safety.refused}",
            flush=True,
        )
