"""``climbd run --role all``: each role as its own OS process, restarted with back-off when it dies.

Perception never shares an interpreter with the control loop: the supervisor starts
``climbd run --role control`` and ``--role perception`` as children linked by Zenoh (perception
dials the control role's listen endpoints on loopback). A child that crashes is restarted after
a delay that doubles up to a ceiling and resets once the child has run stably. A child that
exits with 2 (a bad profile or argument) stops everything: restarting cannot fix it; one that
exits 0 has finished and is not restarted, and the control role exiting 0 ends the run.
systemd hears READY/WATCHDOG from the supervisor only (children get no NOTIFY_SOCKET), and
WATCHDOG only while the control role runs.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field

from climbd.daemon.runtime import sdnotify
from climbd.daemon.runtime.network import Endpoints, zenoh_config

log = logging.getLogger("climbd.supervisor")

BACKOFF_FIRST = 0.5
BACKOFF_MAX = 8.0
STABLE_AFTER = 10.0
"""A child that ran this long (s) before dying is restarted after BACKOFF_FIRST again."""
STOP_TIMEOUT = 10.0
"""Seconds children get to stop after SIGTERM (the control role's safe stop) before SIGKILL."""
CONFIG_ERROR = 2


@dataclass
class Child:
    """One role's process and its restart bookkeeping (times on the supervisor's loop clock)."""

    role: str
    argv: list[str]
    proc: subprocess.Popen | None = None
    started: float = 0.0
    restart_at: float | None = None
    delay: float = BACKOFF_FIRST
    restarts: int = 0
    exits: list[int] = field(default_factory=list)


def loopback(endpoint: str) -> str:
    """A listen endpoint as a peer on the same machine dials it (wildcard → loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def role_argv(args: argparse.Namespace, role: str, listen: list[str], connect: list[str]):
    """The ``climbd run`` command line of one role, carrying the options that apply to it."""
    argv = [
        sys.executable,
        "-m",
        "climbd.daemon.cli",
        "run",
        "--profile",
        args.profile,
        "--role",
        role,
    ]
    for e in listen:
        argv += ["--listen", e]
    for e in connect:
        argv += ["--connect", e]
    if role == "control":
        for opt in ("driver", "port", "gait"):
            if getattr(args, opt):
                argv += [f"--{opt}", getattr(args, opt)]
        argv += ["--no-stand"] if args.no_stand else []
        argv += ["--quiet"] if args.quiet else []
        argv += ["--activate"] if args.activate else []
        if args.sim:  # the control role hosts the twin and ends the run after --duration
            argv += ["--sim", args.sim, "--snapshot", args.snapshot]
            argv += ["--stepped"] if args.stepped else []
            argv += ["--duration", str(args.duration)] if args.duration else []
    else:
        argv += ["--source", "sim" if args.sim else args.source]
        for opt in ("camera", "playback"):
            if getattr(args, opt):
                argv += [f"--{opt}", getattr(args, opt)]
        for name in args.plugin or []:
            argv += ["--plugin", name]
    return argv


def plan(profile, args: argparse.Namespace) -> list[Child]:
    """Control listens where --listen or the profile says; perception dials it on loopback.
    A network setup the control role would refuse (auth, exposure) is a ValueError here."""
    control = profile.network.roles.get("control")
    listen = list(args.listen or (control.listen if control else []))
    if not listen:
        raise ValueError(
            f"{profile.source}: network.roles.control.listen: --role all links the roles "
            "through the control role's listen endpoints; give one (or --listen)"
        )
    connect = list(args.connect or [])
    zenoh_config(profile, "control", Endpoints(listen, connect))  # AccessError before any start
    return [
        Child("control", role_argv(args, "control", listen, connect)),
        Child("perception", role_argv(args, "perception", [], [loopback(e) for e in listen])),
    ]


async def supervise(profile, args: argparse.Namespace) -> int:
    """Run every role of ``profile`` as a supervised child until SIGTERM/SIGINT."""

    try:
        children = plan(profile, args)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return CONFIG_ERROR
    aio = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        aio.add_signal_handler(sig, stop.set)
    print(f"climbd: {profile.name} supervisor, roles control and perception", flush=True)
    duration = None if args.sim else args.duration  # a sim run ends when its control role does
    return await Supervisor(children).run(stop, sdnotify.watchdog_period(), duration)


class Supervisor:
    """Starts the children, restarts the ones that die, stops them all on request."""

    def __init__(self, children: list[Child], control: str = "control") -> None:
        self.children = children
        self.control = control

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
            env.pop(k, None)
        return env

    def _start(self, child: Child, now: float) -> None:
        child.proc = subprocess.Popen(child.argv, env=self._env())
        child.started, child.restart_at = now, None
        log.info("started %s role (pid %d)", child.role, child.proc.pid)

    def _reap(self, child: Child, now: float) -> int | None:
        """Exit code of a child that just ended (and schedule its restart), else None."""
        if child.proc is None or child.proc.poll() is None:
            return None
        code = child.proc.returncode
        child.exits.append(code)
        child.proc = None
        if now - child.started >= STABLE_AFTER:
            child.delay = BACKOFF_FIRST
        how = f"signal {-code}" if code < 0 else f"code {code}"
        print(f"climbd: {child.role} role exited with {how}", flush=True)
        if code == 0:
            return code
        log.warning("%s role exited with %s; restart in %.1f s", child.role, how, child.delay)
        child.restart_at = now + child.delay
        child.delay = min(child.delay * 2, BACKOFF_MAX)
        return code

    async def run(
        self, stop: asyncio.Event, watchdog: float | None = None, duration: float | None = None
    ) -> int:
        """Supervise until ``stop``, ``duration``, a config error, or control's clean exit."""

        aio = asyncio.get_running_loop()
        end = aio.time() + duration if duration else None
        for child in self.children:
            self._start(child, aio.time())
        sdnotify.notify("READY=1")
        last_ping = aio.time()
        try:
            while not stop.is_set() and (end is None or aio.time() < end):
                now = aio.time()
                for child in self.children:
                    code = self._reap(child, now)
                    if code == CONFIG_ERROR:
                        return CONFIG_ERROR
                    if code == 0 and child.role == self.control:
                        return 0
                    due = child.restart_at is not None and now >= child.restart_at
                    if child.proc is None and due:
                        child.restarts += 1
                        self._start(child, now)
                control = next(c for c in self.children if c.role == self.control)
                if watchdog and control.proc is not None and now - last_ping >= watchdog:
                    sdnotify.notify("WATCHDOG=1")
                    last_ping = now
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(stop.wait(), 0.1)
            return 0
        finally:
            sdnotify.notify("STOPPING=1")
            await aio.run_in_executor(None, self.stop_all)

    def stop_all(self) -> None:
        """SIGTERM every child, wait for the safe stop, SIGKILL what is left."""
        running = [c.proc for c in self.children if c.proc is not None and c.proc.poll() is None]
        for proc in running:
            proc.send_signal(signal.SIGTERM)
        for proc in running:
            try:
                proc.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                log.error("pid %d ignored SIGTERM for %.0f s; killing it", proc.pid, STOP_TIMEOUT)
                proc.kill()
                proc.wait()
