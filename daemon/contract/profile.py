"""Robot profiles: the robots/*.toml schema as msgspec Structs, includes, and validation.

A profile is data, not code. Errors name the file, the field path, what was expected and
what was found, so a user fixes a profile without reading our source.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any, Literal, TypeVar

import msgspec

from climbd.daemon.contract.messages import MAX_LEGS, MAX_NAME, EstopPolicy

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


class ProfileError(ValueError):
    """A profile that cannot be used; the message names file, field path, expected and found."""


# Physical bounds (inclusive) of the values a typo makes dangerous: a dead-man that never
# fires, a loop the machine cannot run, a stand that never completes.

RATE_HZ = (1.0, 5000.0)
"""Control rate (Hz): from a slow position-servo bus to a fast torque bus with margin."""

HEARTBEAT_WINDOW = (0.05, 5.0)
"""Seconds without a heartbeat before HOLD: longer leaves the robot unwatched."""

COMMAND_TIMEOUT = (0.05, 5.0)
"""Seconds a motion command is obeyed without a newer one."""

FEATURE_MAX_AGE = (0.05, 10.0)
"""Seconds a perception feature is used after its frame."""

STAND_TIME = (0.1, 60.0)
"""Seconds the stand takes."""

STAND_TOLERANCE = (0.001, 0.5)
"""Radians the joints may sit off the stand command when it counts as complete."""

STATE_AGE = (0.001, 1.0)
"""Seconds a joint's state may age before it is a fault: beyond a second a leg moves blind."""

FOOT_RADIUS = (0.001, 0.1)
"""m: a foot's rounded tip, from a 1 mm point to a 10 cm ball."""

GRIPPER_WIDTH = (0.005, 0.3)
"""m: a gripper's footprint along a member's axis, from a 5 mm pinch to a 30 cm clamp."""

GRIPPER_CLEARANCE = (0.0, 0.2)
"""m: free space the gripper keeps from nodes and other members around its footprint."""

CAMERA_FPS = (1, 300)
"""Frames per second of a depth camera's stream."""

CAMERA_WIDTH = (16, 1280)
"""Pixels across a depth frame; with CAMERA_HEIGHT, a frame fits a DepthImage."""

CAMERA_HEIGHT = (16, 960)
"""Pixels down a depth frame."""


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


class GripperServo(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The servo that closes a foot's gripper, on the joint bus: its device ``id``, its horn
    angle (rad about the centre) fully ``open`` and fully ``closed`` with nothing between the
    fingers, and its speed (rad/s). Closed on a hold, the fingers stop short of ``closed``:
    that is how the bus tells a grip that holds from one that closed on nothing."""

    id: int
    open: float
    closed: float
    velocity: float = 4.0


class Leg(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A 3-DOF leg: mount in the body frame (m), mount yaw (rad), link lengths (m), joints.

    ``kind`` names the chain: coxa–femur–tibia (WidowX, HubRobo) or abduction–thigh–shank
    (Qingzhui, paper 004 eqs. 1–3); ``knee`` is Qingzhui's knee type "a" or "b";
    ``gripper_servo`` the servo of the foot's gripper, when one drives it.
    """

    name: str
    mount: list[float]
    yaw: float
    links: list[float]
    joints: list[Joint]
    kind: Literal["coxa_femur_tibia", "abduction_thigh_shank"] = "coxa_femur_tibia"
    knee: Literal["a", "b"] = "a"
    gripper_servo: GripperServo | None = None


class JointBusConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The joint bus: driver kind, what the runtime needs of any bus, and the driver's own keys.

    ``kind`` names the driver (an entry point in ``climbd.drivers``). A motor is lost after
    ``lost_after`` ticks in a row whose reads it did not answer; health (voltage, temperature)
    is read at ``health_rate_hz``. Position servos (Dynamixel) sag under load by torque /
    ``stiffness`` (N·m/rad, the firmware gain's); above 0, each stance leg's goal is offset by
    its share of the weight's torque over it, so loaded legs hold their height (0: no sag
    compensation).
    A joint whose state is older than ``max_state_age`` (s) when a tick takes it (a bus that
    reads joints in turn, not all every tick) is a fault: the e-stop policy applies. The
    default, 0.2 s, is over 4× the oldest state WidowX's schedule gives behind a 16 ms
    adapter (~45 ms): a loaded host's hiccup is not a fault, a stalled schedule is.
    ``options`` holds every other key of the profile's flat ``[bus]`` table: the driver's own
    settings, which its ``Config`` (a ``DriverConfig``) decodes and checks.
    """

    kind: str = "fake"
    health_rate_hz: float = 10.0
    lost_after: int = 5
    stiffness: float = 0.0
    max_state_age: float = 0.2
    options: dict[str, Any] = {}


C = TypeVar("C", bound="DriverConfig")


class DriverConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Base of a joint-bus driver's ``Config``: its keys of the profile's ``[bus]`` table.

    A driver subclasses it with its fields and defaults and sets it as its class attribute
    ``Config``; ``from_profile`` decodes ``profile.bus.options`` with errors at ``$.bus.<field>``,
    ``validate`` adds the checks across fields (and the rest of the profile) the schema cannot.
    """

    @classmethod
    def from_profile(cls: type[C], profile: Profile) -> C:
        """This driver's settings in ``profile``; a ProfileError names ``$.bus.<field>``."""
        try:
            return msgspec.convert(profile.bus.options, cls, strict=True)
        except msgspec.ValidationError as e:
            what, _, at = str(e).partition(" - at `")
            at = at.rstrip("`") or "$"
            where = "$.bus" + at[1:]
            raise ProfileError(f"{profile.source or profile.name}: {where}: {what}") from None

    def validate(self, profile: Profile) -> None:
        """Checks across fields; raises ProfileError naming the field. None by default."""

    @classmethod
    def check(cls: type[C], profile: Profile) -> C:
        """Decode and validate this driver's settings in ``profile``."""
        config = cls.from_profile(profile)
        config.validate(profile)
        return config


def with_bus_options(profile: Profile, **options: Any) -> Profile:
    """``profile`` with some of its driver's ``[bus]`` keys replaced (tests, the twin)."""
    bus = msgspec.structs.replace(profile.bus, options={**profile.bus.options, **options})
    return msgspec.structs.replace(profile, bus=bus)


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

    ``stand_time`` (s): how long standing up (and sitting down) takes, every joint arriving
    together: at its joints' limits the WidowX stood in 0.38 s and HubRobo, under G/6, in 0.3 s,
    each leaving the ground (5 and 34 ticks of 10 ms) as the legs stopped under a rising body
    (tests/test_stand_twin.py).
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


Right = Literal["telemetry", "teleop", "override", "estop", "reset", "features"]
"""What an identity may do on a role's authenticated session (docs/access.md): ``telemetry``
observe; ``teleop`` claim, release, heartbeats, motion and mode requests; ``override`` claim a
session another holds; ``estop`` engage the e-stop; ``reset`` reset a latched e-stop or fault;
``features`` publish ``features/**`` (perception roles)."""


class AuthConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Who may command: TLS files or a user/password file, and the authorised peers.

    Paths are relative to the profile file; ``{role}`` in a path or in ``user`` becomes the
    role's name. ``rights`` gives each certificate CN or user name its rights; ``commanders``
    (the older form) gives each of its names every right but ``features``; the two add up.
    ``telemetry_listen`` endpoints serve peers without credentials read-only (docs/access.md).
    """

    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""
    user: str = ""
    password: str = ""
    credentials_file: str = ""
    commanders: list[str] = []
    rights: dict[str, list[Right]] = {}
    telemetry_listen: list[str] = []
    create_certificates: bool = False
    """With TLS: a role that listens creates the CA and every named identity's certificate
    that is missing, on its first run (as an SSH server creates its host keys)."""


class NetworkConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Zenoh setup: mode, multicast scouting (off by default), per-role endpoints, auth."""

    mode: Literal["peer", "router", "client"] = "peer"
    multicast_scouting: bool = False
    roles: dict[str, RoleEndpoints] = {}
    auth: AuthConfig | None = None


class GripperConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A gripper that closes around a truss member: its ``width`` along the member's axis and
    the ``clearance`` it needs from nodes and other members beyond it (m)."""

    width: float
    clearance: float


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
    foot_radius: float | None = None
    """m: radius of the feet's rounded tips. A stance foot rolls on it and its centre, which FK
    gives, travels with the body; the torque robots' estimator and the leg odometry follow the
    roll (not of grippers, which do not roll). Unset: a point foot to both; the twin then makes
    the feet 4 % of a leg's span."""
    gripper: GripperConfig | None = None
    """The feet's grippers, for grasping truss members (``[gripper]``); unset: no grasp
    targets are published."""
    bus: JointBusConfig = msgspec.field(default_factory=JointBusConfig)
    cameras: list[CameraConfig] = []
    safety: SafetyConfig = msgspec.field(default_factory=SafetyConfig)
    plugins: PluginsConfig = msgspec.field(default_factory=PluginsConfig)
    network: NetworkConfig = msgspec.field(default_factory=NetworkConfig)
    world: dict[str, Any] = {}
    """The perception role's world model (``[world]``: map extent and cells, terrain filter
    chain, feature tracking, publish period); validated by the role at start against
    ``climbd.daemon.algorithms.world.WorldConfig``, the error naming ``$.world.<field>``."""
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


def gripper_servos(profile: Profile) -> list[tuple[int, str, GripperServo]]:
    """The legs whose gripper a servo drives: (leg index, servo name ``<leg>_gripper``, servo)."""
    return [
        (i, f"{leg.name}_gripper", leg.gripper_servo)
        for i, leg in enumerate(profile.legs)
        if leg.gripper_servo is not None
    ]


def has_grippers(profile: Profile) -> bool:
    """Whether the robot's feet are grippers: a ``hold_grip`` e-stop policy implies them."""
    return profile.safety.estop_policy == EstopPolicy.HOLD_GRIP


def merge_tables(base: dict, override: dict) -> dict:
    """Deep-merge ``override`` into ``base``: tables merge key by key, anything else replaces."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge_tables(out[k], v)
        else:
            out[k] = v
    return out


def _read_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    """Read a profile TOML, resolving ``include`` (relative to the including file) recursively."""
    path = path.resolve()
    if path in chain:
        raise ProfileError(f"{chain[0]}: include cycle through {path}")
    where = f"{chain[-1]}: include: " if chain else ""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ProfileError(f"{where}profile file not found: {path}") from None
    except IsADirectoryError:
        raise ProfileError(f"{where}{path}: a directory, not a profile file") from None
    except OSError as e:
        raise ProfileError(f"{where}{path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise ProfileError(f"{where}{path}: not UTF-8 text: byte {e.start}: {e.reason}") from None
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{where}{path}: not valid TOML: {e}") from None
    include = data.get("include")
    if include is None:
        return data
    if not isinstance(include, str):
        raise ProfileError(
            f"{path}: $.include: expected a file path string, found {type(include).__name__}"
        )
    base = _read_toml(path.parent / include, (*chain, path))
    return merge_tables(base, data)


def _check(cond: bool, source: str, field: str, message: str) -> None:
    if not cond:
        raise ProfileError(f"{source}: {field}: {message}")


def _check_range(
    value: float, bounds: tuple[float, float], source: str, field: str, unit: str
) -> None:
    """``value`` lies within ``bounds`` (inclusive; NaN does not), else a ProfileError."""
    lo, hi = bounds
    _check(lo <= value <= hi, source, field, f"expected {lo:g}..{hi:g} {unit}, found {value}")


def validate(profile: Profile) -> Profile:
    """Check what the schema cannot: physical bounds, limit order, unique ids/names, three
    joints per leg, legs and names that fit the wire contract's messages."""
    src = profile.source or profile.name
    _check_range(profile.rate_hz, RATE_HZ, src, "$.rate_hz", "Hz")
    _check(
        profile.mass > 0 and math.isfinite(profile.mass),
        src,
        "$.mass",
        f"expected a finite value > 0, found {profile.mass}",
    )
    k = profile.bus.stiffness
    _check(
        k >= 0 and math.isfinite(k),
        src,
        "$.bus.stiffness",
        f"expected a finite value >= 0, found {k}",
    )
    _check(
        2 <= len(profile.legs) <= MAX_LEGS,
        src,
        "$.legs",
        f"expected 2..{MAX_LEGS} legs, found {len(profile.legs)}",
    )
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
            _check(
                len(joint.name) <= MAX_NAME,
                src,
                f"{jat}.name",
                f"expected at most {MAX_NAME} characters, found {len(joint.name)}",
            )
            lim = joint.limits
            _check(
                math.isfinite(lim.lower) and math.isfinite(lim.upper) and lim.lower < lim.upper,
                src,
                f"{jat}.limits",
                f"expected finite lower < upper, found lower={lim.lower} upper={lim.upper}",
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
        grip = leg.gripper_servo
        if grip is not None:
            gat = f"{at}.gripper_servo"
            _check(
                grip.id not in ids,
                src,
                f"{gat}.id",
                f"duplicate id {grip.id} (already used by {ids.get(grip.id)!r})",
            )
            ids[grip.id] = f"{leg.name}_gripper"
            _check(
                math.isfinite(grip.open - grip.closed) and grip.open != grip.closed,
                src,
                gat,
                f"expected finite open != closed, found open={grip.open} closed={grip.closed}",
            )
            _check(
                grip.velocity > 0 and math.isfinite(grip.velocity),
                src,
                f"{gat}.velocity",
                f"expected a finite value > 0, found {grip.velocity}",
            )
    for i, cam in enumerate(profile.cameras):
        cat = f"$.cameras[{i}]"
        _check_range(cam.fps, CAMERA_FPS, src, f"{cat}.fps", "frames/s")
        _check_range(cam.width, CAMERA_WIDTH, src, f"{cat}.width", "pixels")
        _check_range(cam.height, CAMERA_HEIGHT, src, f"{cat}.height", "pixels")
        _check(
            0 <= cam.min_range < cam.max_range and math.isfinite(cam.max_range),
            src,
            f"{cat}.max_range",
            f"expected finite 0 <= min_range < max_range, found {cam.min_range}..{cam.max_range}",
        )
        tilt = cam.mount.tilt_deg
        _check(
            0 <= tilt <= 90,
            src,
            f"$.cameras[{i}].mount.tilt_deg",
            f"expected 0..90 degrees, found {tilt}",
        )
    _check_range(profile.bus.max_state_age, STATE_AGE, src, "$.bus.max_state_age", "s")
    if profile.foot_radius is not None:
        _check_range(profile.foot_radius, FOOT_RADIUS, src, "$.foot_radius", "m")
    if profile.gripper is not None:
        g = profile.gripper
        _check_range(g.width, GRIPPER_WIDTH, src, "$.gripper.width", "m")
        _check_range(g.clearance, GRIPPER_CLEARANCE, src, "$.gripper.clearance", "m")
    _check(
        profile.bus.health_rate_hz > 0,
        src,
        "$.bus.health_rate_hz",
        f"expected > 0, found {profile.bus.health_rate_hz}",
    )
    s = profile.safety
    _check_range(s.heartbeat_window, HEARTBEAT_WINDOW, src, "$.safety.heartbeat_window", "s")
    _check_range(s.command_timeout, COMMAND_TIMEOUT, src, "$.safety.command_timeout", "s")
    _check_range(s.feature_max_age, FEATURE_MAX_AGE, src, "$.safety.feature_max_age", "s")
    _check_range(s.stand_time, STAND_TIME, src, "$.safety.stand_time", "s")
    _check_range(s.stand_tolerance, STAND_TOLERANCE, src, "$.safety.stand_tolerance", "rad")
    _check(
        s.derate_temperature <= s.max_temperature,
        src,
        "$.safety.derate_temperature",
        f"expected <= max_temperature {s.max_temperature}, found {s.derate_temperature}",
    )
    return profile


BUS_FIELDS = frozenset(JointBusConfig.__struct_fields__) - {"options"}
"""Keys of the ``[bus]`` table the contract decodes; the others are the driver's options."""


def _split_bus(data: dict) -> dict:
    """``data`` with the driver's keys of its flat ``[bus]`` table moved into ``bus.options``.

    A dict-valued ``options`` key (a decoded profile turned back into builtins) is merged."""
    bus = data.get("bus")
    if not isinstance(bus, dict):
        return data
    options = bus.get("options")
    common = {k: v for k, v in bus.items() if k in BUS_FIELDS}
    own = {k: v for k, v in bus.items() if k not in BUS_FIELDS}
    if isinstance(options, dict):
        del own["options"]
        own = {**options, **own}
    return {**data, "bus": {**common, "options": own}}


def from_dict(data: dict, source: str = "<profile>") -> Profile:
    """Decode and validate a profile from a plain dict (as read from TOML).

    The driver's keys of ``[bus]`` are kept, undecoded, in ``bus.options``: the driver's
    ``Config`` checks them (``climbd profile check``, ``climbd run``, the driver itself)."""
    try:
        profile = msgspec.convert({**_split_bus(data), "source": source}, Profile, strict=True)
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
