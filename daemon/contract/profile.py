"""Robot profiles: the robots/*.toml schema as msgspec Structs, includes, and validation.

A profile is data, not code. Errors name the file, the field path, what was expected and
what was found, so a user fixes a profile without reading our source.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any, Literal

import msgspec

from climbd.daemon.contract.messages import EstopPolicy

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


class ProfileError(ValueError):
    """A profile that cannot be used; the message names file, field path, expected and found."""


class Limits(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Per-joint limits in SI units: position (rad), velocity, acceleration, jerk, effort (N·m)."""

    lower: float
    upper: float
    velocity: float
    acceleration: float
    jerk: float
    effort: float


class Joint(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """One joint: name, device id on the bus, zero offset (rad), direction (±1), limits.

    A joint's position ``q`` is its actuator's output angle about the actuator's centre (rad),
    as drivers report it; the kinematic angle is ``direction · (q − zero_offset)``
    (daemon/algorithms/kinematics.py). Limits apply to ``q``.
    """

    name: str
    id: int
    zero_offset: float = 0.0
    direction: Literal[1, -1] = 1
    limits: Limits


class Leg(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A 3-DOF leg: mount in the body frame (m), mount yaw (rad), link lengths (m), joints.

    ``kind`` names the chain: coxa–femur–tibia (WidowX, HubRobo) or abduction–thigh–shank
    (Qingzhui, paper 004 eqs. 1–3); ``knee`` is Qingzhui's knee type "a" or "b".
    """

    name: str
    mount: list[float]
    yaw: float
    links: list[float]
    joints: list[Joint]
    kind: Literal["coxa_femur_tibia", "abduction_thigh_shank"] = "coxa_femur_tibia"
    knee: Literal["a", "b"] = "a"


class ActuatorRanges(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Ranges of an MIT-mode actuator's packed fields (SI, at the output shaft).

    The firmware maps each range onto 16 bits (position) or 12 bits (the others); they must
    match the actuator's firmware. Defaults are the common mini-cheetah/AK-series values.
    """

    position: float = 12.5
    velocity: float = 45.0
    kp: float = 500.0
    kd: float = 5.0
    torque: float = 18.0


class JointBusConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The joint bus: driver kind and its transport settings.

    Torque legs (``kind = "torque"``) use the CAN fields, the actuator ranges, and the
    default position gains ``kp`` (N·m/rad) and ``kd`` (N·m·s/rad) for commands without gains;
    ``can_channels`` spreads the legs over several CAN buses (leg i on channel i mod n), each
    of which must carry its motors' command and reply every tick at ``baud`` (the serial or CAN
    bit rate, bit/s). ``reply_timeout`` (s) is how long a read waits for motors yet to answer
    the last write: 0 takes the replies that have arrived and leaves those still on the wire
    to the next read, so a tick never waits out a channel's bus time (three motors hold a
    1 Mbit/s channel 0.75 ms after each write); a motor is lost after ``lost_after`` reads
    without any reply.
    Position servos (Dynamixel) sag under load by torque / ``stiffness`` (N·m/rad, the firmware
    gain's); above 0, each stance leg's goal is offset by its share of the weight's torque over
    it, so loaded legs hold their height (0: no sag compensation).
    """

    kind: str = "fake"
    port: str = "/dev/ttyUSB0"
    baud: int = 1_000_000
    protocol: Literal[1, 2] = 1
    model: str = "AX-18A"
    return_delay_us: int = 0
    latency_timer_ms: int = 1
    health_rate_hz: float = 10.0
    lost_after: int = 5
    can_interface: str = "socketcan"
    can_channel: str = "can0"
    can_channels: list[str] = []
    master_id: int = 0
    reply_timeout: float = 0.0
    actuator: ActuatorRanges = msgspec.field(default_factory=ActuatorRanges)
    kp: float = 60.0
    kd: float = 1.5
    stiffness: float = 0.0


class CameraMount(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Camera mount in the body frame: position (m), tilt down (deg, 0–90 in 15° steps), yaw."""

    position: list[float] = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.2])
    tilt_deg: float = 0.0
    yaw_deg: float = 0.0
    roll_deg: float = 0.0


class CameraConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A depth camera: model, serial, stream profile, mount, and optional post-processing."""

    name: str = "depth"
    kind: str = "realsense"
    model: Literal["L515", "D435"] = "D435"
    serial: str = ""
    width: int = 640
    height: int = 480
    fps: int = 30
    depth_units: float | None = None
    visual_preset: str | None = None
    emitter: bool = True
    filters: list[str] = []
    min_range: float = 0.1
    max_range: float = 4.0
    mount: CameraMount = msgspec.field(default_factory=CameraMount)


class SafetyConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Safety policy: e-stop behaviour, heartbeat window, servo health thresholds.

    ``stand_tolerance`` (rad): how close the joints must follow the stand command before the
    stand counts as complete; compliant servos under the robot's weight sit a little off it.
    """

    estop_policy: EstopPolicy = EstopPolicy.TORQUE_OFF
    heartbeat_window: float = 0.3
    command_timeout: float = 0.5
    feature_max_age: float = 1.0
    derate_temperature: float = 65.0
    max_temperature: float = 75.0
    min_voltage: float = 9.0
    max_voltage: float = 16.0
    stand_time: float = 2.0
    stand_tolerance: float = 0.05


class PluginSpec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A plugin to run: entry-point name and its config overrides (validated by the plugin)."""

    name: str
    config: dict[str, Any] = {}


class PluginsConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Plugins the profile runs: perception plugins and the gaits it may switch between."""

    perception: list[PluginSpec] = []
    gaits: list[PluginSpec] = []
    default_gait: str = ""


class RoleEndpoints(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Zenoh endpoints of one role, e.g. ``tcp/192.168.1.2:7447``."""

    listen: list[str] = []
    connect: list[str] = []


class AuthConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Who may command: TLS files or a user/password file, and the authorised peers.

    Paths are relative to the profile file; ``{role}`` in a path or in ``user`` becomes the
    role's name. ``commanders`` are the certificate CNs or user names allowed on ``cmd/**``;
    ``telemetry_listen`` endpoints serve peers without credentials read-only (docs/access.md).
    """

    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""
    user: str = ""
    password: str = ""
    credentials_file: str = ""
    commanders: list[str] = []
    telemetry_listen: list[str] = []


class NetworkConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Zenoh setup: mode, multicast scouting (off by default), per-role endpoints, auth."""

    mode: Literal["peer", "router", "client"] = "peer"
    multicast_scouting: bool = False
    roles: dict[str, RoleEndpoints] = {}
    auth: AuthConfig | None = None


class StandConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Standing pose: body height (m) and the feet's radial distance from their coxa (m)."""

    body_height: float
    foot_reach: float


class Profile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A whole robot profile as decoded from robots/*.toml."""

    name: str
    model: str
    mass: float
    rate_hz: float
    legs: list[Leg]
    bus: JointBusConfig = msgspec.field(default_factory=JointBusConfig)
    cameras: list[CameraConfig] = []
    safety: SafetyConfig = msgspec.field(default_factory=SafetyConfig)
    plugins: PluginsConfig = msgspec.field(default_factory=PluginsConfig)
    network: NetworkConfig = msgspec.field(default_factory=NetworkConfig)
    stand: StandConfig
    include: str | None = None
    source: str = ""

    @property
    def joints(self) -> list[Joint]:
        """All joints in profile order: leg by leg, three each."""
        return [j for leg in self.legs for j in leg.joints]

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]


def _merge(base: dict, override: dict) -> dict:
    """Deep-merge ``override`` into ``base``: tables merge key by key, anything else replaces."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _read_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    """Read a profile TOML, resolving ``include`` (relative to the including file) recursively."""
    path = path.resolve()
    if path in chain:
        raise ProfileError(f"{chain[0]}: include cycle through {path}")
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        where = f"{chain[-1]}: include: " if chain else ""
        raise ProfileError(f"{where}profile file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{path}: not valid TOML: {e}") from None
    include = data.get("include")
    if include is None:
        return data
    if not isinstance(include, str):
        raise ProfileError(
            f"{path}: $.include: expected a file path string, found {type(include).__name__}"
        )
    base = _read_toml(path.parent / include, (*chain, path))
    return _merge(base, data)


MIT_FRAME_BYTES = (8, 6)
"""Data bytes of an MIT-mode command and of the motor's reply: one of each per motor a tick."""


def can_frame_bits(data_bytes: int) -> int:
    """Bits a classic CAN data frame (11-bit id) holds the bus for: the 34 + 8n bits from start
    of frame to the CRC at worst-case stuffing (a stuff bit after every 4 past the first), then
    CRC delimiter, ACK, end of frame and the 3-bit interframe space (13)."""
    stuffed = 34 + 8 * data_bytes
    return stuffed + (stuffed - 1) // 4 + 13


def can_tick_time(motors: int, baud: int) -> float:
    """Seconds of bus time ``motors`` MIT motors take a tick on one channel at ``baud`` bit/s."""
    return motors * sum(can_frame_bits(n) for n in MIT_FRAME_BYTES) / baud


def _check_can_load(profile: Profile, src: str) -> None:
    """Every CAN channel carries its motors' commands and replies within one control period:
    18 motors on one 1 Mbit/s bus take 4.5 ms a tick, which no 1 kHz loop can run on."""
    bus = profile.bus
    _check(bus.baud > 0, src, "$.bus.baud", f"expected > 0 bit/s, found {bus.baud}")
    channels = bus.can_channels or [bus.can_channel]
    per_leg = [len(leg.joints) for leg in profile.legs]
    motors = {c: sum(per_leg[i :: len(channels)]) for i, c in enumerate(channels)}
    busiest = max(motors, key=motors.get)
    need = can_tick_time(motors[busiest], bus.baud)
    period = 1.0 / profile.rate_hz
    if need <= period:
        return
    fits = [
        n
        for n in range(1, len(per_leg) + 1)
        if can_tick_time(max(sum(per_leg[i::n]) for i in range(n)), bus.baud) <= period
    ]
    advice = (
        f"spread the legs over {fits[0]} channels or more (leg i on channel i mod n)"
        if fits
        else "one leg a channel does not fit either: lower rate_hz or raise baud"
    )
    _check(
        False,
        src,
        "$.bus.can_channels",
        f"{motors[busiest]} motors on {busiest} need {need * 1e3:.2f} ms of bus time a tick "
        f"(an {MIT_FRAME_BYTES[0]}-byte command and a {MIT_FRAME_BYTES[1]}-byte reply each at "
        f"{bus.baud} bit/s), more than the {period * 1e3:g} ms period at {profile.rate_hz:g} Hz: "
        f"{advice}",
    )


def _check(cond: bool, source: str, field: str, message: str) -> None:
    if not cond:
        raise ProfileError(f"{source}: {field}: {message}")


def validate(profile: Profile) -> Profile:
    """Check what the schema cannot: limit order, unique ids/names, three joints per leg."""
    src = profile.source or profile.name
    _check(profile.rate_hz > 0, src, "$.rate_hz", f"expected > 0, found {profile.rate_hz}")
    _check(profile.mass > 0, src, "$.mass", f"expected > 0, found {profile.mass}")
    k = profile.bus.stiffness
    _check(
        k >= 0 and math.isfinite(k),
        src,
        "$.bus.stiffness",
        f"expected a finite value >= 0, found {k}",
    )
    tol = profile.safety.stand_tolerance
    _check(tol > 0, src, "$.safety.stand_tolerance", f"expected > 0, found {tol}")
    _check(len(profile.legs) >= 2, src, "$.legs", f"expected >= 2 legs, found {len(profile.legs)}")
    ids: dict[int, str] = {}
    names: set[str] = set()
    for i, leg in enumerate(profile.legs):
        at = f"$.legs[{i}]"
        _check(
            len(leg.joints) == 3,
            src,
            f"{at}.joints",
            f"expected 3 joints, found {len(leg.joints)} (leg {leg.name!r})",
        )
        _check(len(leg.mount) == 3, src, f"{at}.mount", f"expected [x, y, z], found {leg.mount}")
        _check(
            len(leg.links) == 3 and all(x > 0 for x in leg.links),
            src,
            f"{at}.links",
            f"expected three positive lengths, found {leg.links}",
        )
        for k, joint in enumerate(leg.joints):
            jat = f"{at}.joints[{k}]"
            lim = joint.limits
            _check(
                lim.lower < lim.upper,
                src,
                f"{jat}.limits",
                f"expected lower < upper, found lower={lim.lower} upper={lim.upper}",
            )
            for fname in ("velocity", "acceleration", "jerk", "effort"):
                val = getattr(lim, fname)
                _check(
                    val > 0 and math.isfinite(val),
                    src,
                    f"{jat}.limits.{fname}",
                    f"expected a finite value > 0, found {val}",
                )
            _check(
                joint.id not in ids,
                src,
                f"{jat}.id",
                f"duplicate id {joint.id} (already used by {ids.get(joint.id)!r})",
            )
            ids[joint.id] = joint.name
            _check(joint.name not in names, src, f"{jat}.name", f"duplicate name {joint.name!r}")
            names.add(joint.name)
    for i, cam in enumerate(profile.cameras):
        tilt = cam.mount.tilt_deg
        _check(
            0 <= tilt <= 90,
            src,
            f"$.cameras[{i}].mount.tilt_deg",
            f"expected 0..90 degrees, found {tilt}",
        )
    _check(
        profile.bus.health_rate_hz > 0,
        src,
        "$.bus.health_rate_hz",
        f"expected > 0, found {profile.bus.health_rate_hz}",
    )
    s = profile.safety
    _check(
        s.heartbeat_window > 0,
        src,
        "$.safety.heartbeat_window",
        f"expected > 0 s, found {s.heartbeat_window}",
    )
    _check(
        s.derate_temperature <= s.max_temperature,
        src,
        "$.safety.derate_temperature",
        f"expected <= max_temperature {s.max_temperature}, found {s.derate_temperature}",
    )
    if profile.bus.kind == "torque":
        _check_can_load(profile, src)
    return profile


def from_dict(data: dict, source: str = "<profile>") -> Profile:
    """Decode and validate a profile from a plain dict (as read from TOML)."""
    try:
        profile = msgspec.convert({**data, "source": source}, Profile, strict=True)
    except msgspec.ValidationError as e:
        what, _, at = str(e).partition(" - at `")
        raise ProfileError(f"{source}: {at.rstrip('`') or '$'}: {what}") from None
    return validate(profile)


def load(path: str | Path) -> Profile:
    """Load, merge includes, decode and validate the profile at ``path``."""
    path = Path(path)
    return from_dict(_read_toml(path), str(path))


def stock_profiles() -> dict[str, Path]:
    """The stock profiles shipped in robots/, by robot name."""
    root = Path(__file__).resolve().parents[2] / "robots"
    return {p.stem: p for p in sorted(root.glob("*.toml"))}
