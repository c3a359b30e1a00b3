"""The Zenoh network of a climbd process: typed publish/subscribe of wire messages, handed over
to asyncio safely ("bus" is the joint bus; this is the network).

Zenoh callbacks run on Zenoh's own threads. There we only decode (cheap, and it lets garbage
be dropped at once) and queue the message for the asyncio loop, waking it with
``call_soon_threadsafe`` once per batch; we never block and never call Zenoh from a callback.
An undecodable or wrong-schema payload is dropped, counted by topic (and by peer where the
sample names its source), and logged once per sender.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec
import zenoh

from climbd.daemon.contract.messages import (
    EStop,
    Heartbeat,
    JointCommand,
    JointState,
    Message,
    ModeRequest,
    MotionCommand,
    OverrideClaim,
    ResetRequest,
    SchemaMismatch,
    SessionClaim,
    decode,
    encode,
    key,
)
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.access import apply_auth, check_exposure, plain_loopback
from climbd.daemon.runtime.counting import Tally

log = logging.getLogger("climbd.bus")

CONTROL_STREAMS: tuple[type[Message], ...] = (JointState, JointCommand, MotionCommand, Heartbeat)
"""Streams sent REAL_TIME, express, congestion DROP: a stale sample is worth nothing."""

ONE_SHOT_COMMANDS: tuple[type[Message], ...] = (
    EStop,
    SessionClaim,
    ModeRequest,
    ResetRequest,
    OverrideClaim,
)
"""Sent REAL_TIME, reliable, congestion BLOCK: each must arrive, and none waits behind
lower-priority traffic."""


@dataclass
class Endpoints:
    """Where this process listens and whom it connects to (Zenoh locators)."""

    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)


def zenoh_config(
    profile: Profile | None,
    role: str,
    endpoints: Endpoints | None = None,
    mode: str | None = None,
) -> zenoh.Config:
    """Zenoh config from the profile's network section: peer mode, explicit endpoints, no multicast.

    ``endpoints`` overrides the profile's for this role (tests pick free loopback ports).
    With ``network.auth`` the session admits only authenticated peers, each to its rights
    (daemon/runtime/access.py); raises access.AccessError naming the field when that cannot work,
    or when the role would listen beyond this computer without auth. Plain loopback endpoints
    given instead of a TLS profile's run without TLS (only this computer reaches them).
    """
    net = profile.network if profile is not None else None
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode or (net.mode if net else "peer")))
    multicast = net.multicast_scouting if net else False
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(multicast))
    given = endpoints is not None
    if endpoints is None:
        role_ep = net.roles.get(role) if net else None
        endpoints = Endpoints(
            list(role_ep.listen) if role_ep else [], list(role_ep.connect) if role_ep else []
        )
    cfg.insert_json5("listen/endpoints", json.dumps(endpoints.listen))
    cfg.insert_json5("connect/endpoints", json.dumps(endpoints.connect))
    if profile is None:
        return cfg
    check_exposure(
        profile, "--listen" if given else f"network.roles.{role}.listen", endpoints.listen
    )
    auth = profile.network.auth
    if auth is None:
        return cfg
    if given and not auth.user and plain_loopback(endpoints.listen, endpoints.connect):
        log.warning(
            "%s: network.auth (TLS) not applied: the endpoints given (%s) are plain loopback, "
            "reachable from this computer only",
            profile.source,
            ", ".join(endpoints.listen + endpoints.connect),
        )
        return cfg
    apply_auth(cfg, profile, role, endpoints.listen, endpoints.connect)
    return cfg


class Publisher:
    """A declared Zenoh publisher for one message type on one robot."""

    def __init__(self, publisher: zenoh.Publisher) -> None:
        self._publisher = publisher

    def put(self, message: Message) -> None:
        self._publisher.put(encode(message))

    def undeclare(self) -> None:
        self._publisher.undeclare()


class _Handler:
    """A subscriber's callback, dropped when the bus closes: Zenoh may keep the sample handler
    alive past undeclare, and with it whatever the callback holds (a controller, its ruckig)."""

    def __init__(self, callback: Callable[[Message], None]) -> None:
        self._callback: Callable[[Message], None] | None = callback

    def __call__(self, msg: Message) -> None:
        callback = self._callback  # read once: release() may run on another thread
        if callback is not None:
            callback(msg)

    def release(self) -> None:
        self._callback = None


class Network:
    """One Zenoh session of a climbd process, for robot ``robot``.

    ``loop`` is the asyncio loop subscriber callbacks are delivered on; without one they run
    on Zenoh's thread and must not block.
    """

    def __init__(
        self,
        robot: str,
        config: zenoh.Config,
        loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        self.robot = robot
        self.loop = loop
        self.session = zenoh.open(config)
        self.undecodable = Tally()
        """Dropped payloads by ``drop_key``: topic, and peer where the sample names one."""
        self._warned: set[str] = set()
        self._lock = threading.Lock()
        self._declared: list = []
        self._handlers: list[_Handler] = []
        self._publishers: dict[type[Message], Publisher] = {}
        self._declare_lock = threading.Lock()

    def publisher(self, message: type[Message], robot: str | None = None) -> Publisher:
        """Declare a publisher with the QoS docs/topics.md gives the topic."""
        k = key(robot or self.robot, message)
        if message in ONE_SHOT_COMMANDS:
            qos = dict(
                priority=zenoh.Priority.REAL_TIME,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
            )
        elif message in CONTROL_STREAMS:
            qos = dict(
                priority=zenoh.Priority.REAL_TIME,
                congestion_control=zenoh.CongestionControl.DROP,
                express=True,
            )
        else:
            qos = dict(congestion_control=zenoh.CongestionControl.DROP)
        pub = Publisher(self.session.declare_publisher(k, **qos))
        self._declared.append(pub)
        return pub

    def put(self, message: Message) -> None:
        """Publish ``message`` on this robot's key; its publisher is declared on first use.

        Thread-safe: the control loop, a perception worker and asyncio may all publish."""
        kind = type(message)
        pub = self._publishers.get(kind) or self.declare(kind)[0]
        pub.put(message)

    def declare(self, *kinds: type[Message]) -> list[Publisher]:
        """Declare the publishers ``put`` uses ahead of time (off a loop's first tick)."""
        with self._declare_lock:
            for kind in kinds:
                if kind not in self._publishers:
                    self._publishers[kind] = self.publisher(kind)
            return [self._publishers[kind] for kind in kinds]

    @property
    def decode_errors(self) -> int:
        """Payloads dropped as undecodable or of another schema, on every subscription."""
        return self.undecodable.total

    def drop_key(self, sample: zenoh.Sample) -> str:
        """Where a dropped payload is counted: its topic (``climbd/<this robot>/`` left out,
        ``robot/topic`` for another robot's), with `` from <zid>`` when the sample carries its
        source. Zenoh fills ``source_info`` only when the sender sets it, so most samples,
        garbage from plain zenoh included, are counted by topic alone."""
        topic = str(sample.key_expr)
        own = f"climbd/{self.robot}/"
        topic = topic.removeprefix(own) if topic.startswith(own) else topic.removeprefix("climbd/")
        info = sample.source_info
        return topic if info is None else f"{topic} from {info.source_id.zid()}"

    def _drop(self, sample: zenoh.Sample, error: Exception) -> None:
        self.undecodable.add(self.drop_key(sample))
        with self._lock:
            info = sample.source_info
            sender = str(info.source_id.zid()) if info is not None else str(sample.key_expr)
            first = sender not in self._warned
            self._warned.add(sender)
        if first:
            log.warning(
                "dropped undecodable payload on %s from %s: %s (further ones only counted)",
                sample.key_expr,
                sender,
                error,
            )

    def subscribe(
        self,
        message: type[Message],
        callback: Callable[[Message], None],
        robot: str | None = None,
        latest_only: bool = False,
    ):
        """Subscribe to ``message`` of ``robot`` (``*`` for all robots).

        Samples wait in a per-subscription queue that one asyncio wake-up drains whole, so a
        burst costs one ``call_soon_threadsafe``, not one per sample. ``latest_only`` keeps a
        queue of one: a newer message replaces one asyncio has not yet taken.
        """
        k = key(robot or self.robot, message)
        handler = _Handler(callback)
        self._handlers.append(handler)
        pending: list[Message] = []

        def deliver() -> None:
            with self._lock:
                batch = pending.copy()
                pending.clear()
            for msg in batch:
                handler(msg)

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), message)
            except (msgspec.DecodeError, msgspec.ValidationError, SchemaMismatch) as e:
                self._drop(sample, e)
                return
            if self.loop is None:
                handler(msg)
                return
            with self._lock:
                schedule = not pending
                if latest_only:
                    pending[:] = [msg]
                else:
                    pending.append(msg)
            if schedule:
                self._call_soon(deliver)

        sub = self.session.declare_subscriber(k, on_sample)
        self._declared.append(sub)
        return sub

    def _call_soon(self, fn: Callable, *args) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closing: the daemon is stopping
            self.loop.call_soon_threadsafe(fn, *args)

    def alive(self, role: str):
        """Declare this role's liveliness token ``climbd/<robot>/alive/<role>``."""
        token = self.session.liveliness().declare_token(key(self.robot, f"alive/{role}"))
        self._declared.append(token)
        return token

    def alive_roles(self, robot: str = "*", timeout: float = 1.0) -> list[tuple[str, str]]:
        """(robot, role) of every live climbd role matching ``robot``."""
        found = []
        for reply in self.session.liveliness().get(key(robot, "alive/*"), timeout=timeout):
            if reply.ok is not None:
                parts = str(reply.ok.key_expr).split("/")
                found.append((parts[1], parts[3]))
        return sorted(set(found))

    def close(self) -> None:
        for d in reversed(self._declared):
            try:
                d.undeclare()
            except Exception as e:  # already gone with the session: nothing left to release
                log.debug("undeclare failed: %s", e)
        self._declared.clear()
        for handler in self._handlers:
            handler.release()
        self._handlers.clear()
        self.session.close()
