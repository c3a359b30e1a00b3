"""The wire contract: every topic's msgspec Struct and key expression.

Payloads are msgpack-encoded Structs; each carries ``schema`` (the schema version) so a
peer on an older or newer climbd is detected instead of misread. Units are SI, frames as in
docs/architecture.md (body frame: x forward, y left, z up). ``docs/topics.md`` lists every topic.
"""

from __future__ import annotations

import enum
from typing import Annotated, ClassVar

import msgspec

SCHEMA_VERSION = 1

# --- bounds -----------------------------------------------------------------------------
# Every string, list, map and bytes field has a maximum size, enforced at decode: a payload
# over it is refused (msgspec.ValidationError, a decode error to the bus) before a role keeps
# or repeats it. The limits fit the largest real use with margin.

MAX_NAME = 256
"""Characters of a name, session id, client, source, behaviour, map key or e-stop reason."""

MAX_TEXT = 1024
"""Characters of a text the robot composes from names and errors: a mode's reason, a message."""

MAX_ENTRIES = 64
"""Entries of a per-joint list or another short list of names, and keys of a map."""

MAX_LEGS = 8
"""Entries of a per-leg list (feet, stance, grip, tripod legs): legs of one robot."""

MAX_VECTOR = 8
"""Entries of a small vector (position, quaternion, axis) or list of them (an edge's ends)."""

MAX_FEATURES = 16384
"""Items of a feature or plan list: graspable points, holds, joists, members, steps, lengths."""

MAX_GRID_BYTES = 8 * 1024 * 1024
"""Bytes of an ElevationGrid's heights or one (compressed) TerrainMap layer."""

MAX_DEPTH_BYTES = 2 * 1280 * 960
"""Bytes of a DepthImage's uint16 depth: a 1280 × 960 frame."""

MAX_PREVIEW_PIXELS = 320 * 240
"""Pixels of a DepthPreview: a 640 × 480 frame at every second pixel, 16 times the default
preview (``[world] preview_points``)."""

MAX_PREVIEW_BYTES = 2 * MAX_PREVIEW_PIXELS
"""Bytes of a DepthPreview's uint16 depth."""

Name = Annotated[str, msgspec.Meta(max_length=MAX_NAME)]
Text = Annotated[str, msgspec.Meta(max_length=MAX_TEXT)]
Names = Annotated[list[Name], msgspec.Meta(max_length=MAX_ENTRIES)]
JointValues = Annotated[list[float], msgspec.Meta(max_length=MAX_ENTRIES)]
LegFlags = Annotated[list[bool], msgspec.Meta(max_length=MAX_LEGS)]
Vector = Annotated[list[float], msgspec.Meta(max_length=MAX_VECTOR)]
Vectors = Annotated[list[Vector], msgspec.Meta(max_length=MAX_VECTOR)]


def _clipped(text: str, limit: int = MAX_TEXT) -> str:
    """``text`` cut to ``limit`` characters, an ellipsis saying so."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


class Message(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Base of every wire message: schema version and a timestamp (s, sender's clock).

    Unknown fields are refused, so a payload of another topic or schema never decodes as an
    empty message of this one.
    """

    TOPIC: ClassVar[str] = ""
    RATE: ClassVar[str] = ""
    schema: int = SCHEMA_VERSION
    stamp: float = 0.0


class Mode(str, enum.Enum):
    """Robot modes (docs/architecture.md, Safety), in the order a normal run passes through them."""

    OFF = "OFF"
    STAND = "STAND"
    ACTIVE = "ACTIVE"
    HOLD = "HOLD"
    ESTOP = "ESTOP"
    FAULT = "FAULT"


class EstopPolicy(str, enum.Enum):
    """What e-stop does to the joints: torque off, hold the commanded pose, or hold with grip."""

    TORQUE_OFF = "torque_off"
    HOLD = "hold"
    HOLD_GRIP = "hold_grip"


# --- joints -----------------------------------------------------------------------------


class JointState(Message):
    """Measured joint state, one entry per joint in profile order (rad, rad/s, N·m).

    ``age`` (s, per joint) says how old each joint's reading is when the tick gets it, for a
    bus that cannot read every joint every tick (Dynamixel Protocol 1.0 behind a USB adapter);
    NaN for a joint the bus has lost (not read; its health says so); empty when every joint
    was read this tick. ``holding``, per leg, says which feet's grippers hold something, for
    a bus that drives grippers (None: it drives none). The control role stamps it with its
    tick's time, as the body state, whatever the driver stamped: the perception role pairs a
    frame with the joints nearest its stamp (the self filter)."""

    TOPIC: ClassVar[str] = "state/joints"
    RATE: ClassVar[str] = "control rate (100 Hz WidowX/HubRobo, 1 kHz Qingzhui)"
    names: Names = []
    position: JointValues = []
    velocity: JointValues = []
    effort: JointValues = []
    age: JointValues = []
    holding: LegFlags | None = None


class JointCommand(Message):
    """Joint command in profile order; torque legs add velocity, feed-forward torque, kp, kd.
    Compliant position servos' positions include their sag offset (profile bus.stiffness).
    ``grip``, per leg, closes (True) or opens the feet's grippers; None leaves them as they are."""

    TOPIC: ClassVar[str] = "state/command"
    RATE: ClassVar[str] = "control rate"
    position: JointValues = []
    velocity: JointValues | None = None
    effort: JointValues | None = None
    kp: JointValues | None = None
    kd: JointValues | None = None
    grip: LegFlags | None = None


class JointHealth(msgspec.Struct, kw_only=True):
    """Health of one joint's actuator: temperature (°C), voltage (V), device error bits."""

    name: Name
    temperature: float = float("nan")
    voltage: float = float("nan")
    error: int = 0
    errors: Names = []
    lost: bool = False
    derated: bool = False


class LoopStats(msgspec.Struct, kw_only=True):
    """Control-loop timing over the last window: lateness of wake-ups and per-tick compute (s)."""

    rate_hz: float = 0.0
    ticks: int = 0
    overruns: int = 0
    lateness_p50: float = 0.0
    lateness_p99: float = 0.0
    lateness_max: float = 0.0
    compute_p50: float = 0.0
    compute_p99: float = 0.0


class BusSchedule(msgspec.Struct, kw_only=True):
    """How a joint bus that reads between ticks keeps up, over the last window: reads per tick
    and per second, goal writes per second, the age (s) of the oldest joint state each tick
    took (p50, p99, max) against the profile's bound, replies missed (by joint), and what the
    driver says of its plan (the adapter's latency, a lowered read rate)."""

    reads_per_tick: float = 0.0
    reads_per_s: float = 0.0
    writes_per_s: float = 0.0
    oldest_age_p50: float = 0.0
    oldest_age_p99: float = 0.0
    oldest_age_max: float = 0.0
    age_bound: float = 0.0
    missed: int = 0
    missed_by: Annotated[dict[Name, int], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    plan: Text = ""


class MotionStats(msgspec.Struct, kw_only=True):
    """What the motion pipeline did since the current mode was entered."""

    unreachable_legs: Annotated[list[Name], msgspec.Meta(max_length=MAX_LEGS)] = []
    unreachable_ticks: int = 0
    clamps: int = 0
    smoothing_fallbacks: int = 0


class Health(Message):
    """Whole-robot health: mode, joints, loop timing, plugins, bus decode errors, refusals.

    ``refused_commands`` counts claims, mode and motion commands refused for their session, and
    a reset or override sent in ``ModeRequest.reset``/``SessionClaim.override`` over the wire
    (they ride on ``cmd/reset``/``cmd/override``; a stray heartbeat is not a command);
    ``refused_heartbeats`` counts heartbeats of the holding session whose ``seq`` or ``stamp``
    did not advance (replayed or stale); ``unauthorised_commands`` counts puts on the read-only
    telemetry endpoint (``network.auth.telemetry_listen``) on command, feature and sim keys,
    from any peer; ``features`` gives the age (s) of each feature topic the role last received;
    ``bus`` is the joint bus's read schedule, for a bus that reads between ticks (else None);
    ``session`` names the client holding the control
    session ("" when none); ``plugin_slowest`` gives each plugin's slowest call so far (s), with
    ``plugin_slowest_call`` naming the plugin and method of the slowest of all; ``plugin_errors``
    counts each plugin's calls that raised (their results dropped; ``plugins`` says whether it
    is failing, restarting or failed); ``refused_frames`` counts depth frames perception gave
    no body pose, by reason (no_pose, too_old, too_new, out_of_order, not_finite), and frames
    its world model did not fuse (no_depth, malformed_depth, ground_not_level: the ground near
    the body is not level in the body frame, the camera's mount in the profile is likely wrong).
    ``decode_errors_by`` breaks ``decode_errors`` down by topic ("cmd/motion"), or topic and
    peer ("cmd/motion from <zid>") when the sample names its source; ``refused_by`` breaks
    ``refused_commands`` down by topic. Both hold at most 64 keys, later ones summed under
    "other".
    """

    TOPIC: ClassVar[str] = "state/health"
    RATE: ClassVar[str] = "2 Hz"
    role: Name = "control"
    mode: Mode = Mode.OFF
    joints: Annotated[list[JointHealth], msgspec.Meta(max_length=MAX_ENTRIES)] = []
    loop: LoopStats = msgspec.field(default_factory=LoopStats)
    bus: BusSchedule | None = None
    motion: MotionStats = msgspec.field(default_factory=MotionStats)
    plugins: Annotated[dict[Name, Text], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    plugin_slowest: Annotated[dict[Name, float], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    plugin_slowest_call: Name = ""
    plugin_errors: Annotated[dict[Name, int], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    decode_errors: int = 0
    decode_errors_by: Annotated[dict[Name, int], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    refused_commands: int = 0
    refused_by: Annotated[dict[Name, int], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    refused_heartbeats: int = 0
    unauthorised_commands: int = 0
    dropped_frames: int = 0
    refused_frames: Annotated[dict[Name, int], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    features: Annotated[dict[Name, float], msgspec.Meta(max_length=MAX_ENTRIES)] = {}
    session: Name = ""
    messages: Annotated[list[Text], msgspec.Meta(max_length=MAX_ENTRIES)] = []

    def __post_init__(self) -> None:
        """Clip what the robot composes from errors (plugin statuses, messages) to what a peer
        decodes: a long exception text must not make the whole Health unreadable."""
        self.plugins = {k: _clipped(v) for k, v in self.plugins.items()}
        self.messages = [_clipped(m) for m in self.messages[-MAX_ENTRIES:]]


# --- body and motion --------------------------------------------------------------------


class BodyState(Message):
    """Estimated body pose in the odometry frame: position (m), quaternion (w, x, y, z), rates."""

    TOPIC: ClassVar[str] = "state/body"
    RATE: ClassVar[str] = "control rate"
    position: Vector = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    orientation: Vector = msgspec.field(default_factory=lambda: [1.0, 0.0, 0.0, 0.0])
    linear_velocity: Vector = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    angular_velocity: Vector = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    stance: LegFlags = []
    pose_variance: Vector = msgspec.field(default_factory=lambda: [0.0] * 6)
    """The diagonal of the pose's covariance: x, y, z (m²), roll, pitch, yaw (rad²); all zero
    when the pose comes with none (a twin's truth, a test)."""
    holding: LegFlags | None = None
    """Which feet's grippers hold, as the joint bus reports them; None when it drives none."""


class FootTargets(Message):
    """Foot positions in the body frame, one (x, y, z) per leg in profile order; stance flags;
    ``unload`` marks stance feet about to lift, whose weight passes to the others first."""

    TOPIC: ClassVar[str] = "state/feet"
    RATE: ClassVar[str] = "control rate"
    positions: Annotated[list[Vector], msgspec.Meta(max_length=MAX_LEGS)] = []
    stance: LegFlags = []
    grip: LegFlags | None = None
    unload: LegFlags | None = None


class MotionCommand(Message):
    """Teleop/autonomy velocity and body-pose command (m/s, rad/s, m, rad)."""

    TOPIC: ClassVar[str] = "cmd/motion"
    RATE: ClassVar[str] = "operator rate, typically 10-50 Hz"
    session: Name = ""
    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0
    body_height: float | None = None
    roll: float = 0.0
    pitch: float = 0.0
    behaviour: Name | None = None


class ModeState(Message):
    """The current mode and why it was entered. ``estop_by`` names the sources whose e-stop
    holds the current ESTOP latch, ``reset_by`` the session that last reset an ESTOP or FAULT:
    an operator tool confirms its own e-stop or reset by them (``climbd estop``)."""

    TOPIC: ClassVar[str] = "state/mode"
    RATE: ClassVar[str] = "on change and 2 Hz"
    mode: Mode = Mode.OFF
    reason: Text = ""
    estop_by: Names = []
    reset_by: Name = ""

    def __post_init__(self) -> None:
        """Clip a reason the robot composed (it may quote an error) to what a peer decodes."""
        self.reason = _clipped(self.reason)


class ModeRequest(Message):
    """A request to change mode (e.g. STAND, ACTIVE, HOLD, OFF, or reset from ESTOP/FAULT)."""

    TOPIC: ClassVar[str] = "cmd/mode"
    RATE: ClassVar[str] = "on demand"
    session: Name = ""
    mode: Mode = Mode.HOLD
    reset: bool = False


class EStop(Message):
    """Engage (or, with ``engage=False``, release) the emergency stop; repeated by the sender."""

    TOPIC: ClassVar[str] = "cmd/estop"
    RATE: ClassVar[str] = "on demand, repeated 10 Hz until the robot's ModeState confirms it"
    engage: bool = True
    source: Name = ""
    reason: Name = ""

    def __post_init__(self) -> None:
        """Clip an operator's long reason, so the robot never refuses an e-stop for its words."""
        self.reason = _clipped(self.reason, MAX_NAME)


class SessionClaim(Message):
    """Claim (or release) the controlling teleop session; ``override`` preempts autonomy. A
    release puts the robot in HOLD unless ``handoff`` hands it to autonomy (logged, and named
    in the mode's reason)."""

    TOPIC: ClassVar[str] = "cmd/session"
    RATE: ClassVar[str] = "on demand"
    session: Name = ""
    client: Name = ""
    release: bool = False
    override: bool = False
    handoff: bool = False


class Heartbeat(Message):
    """Keep-alive of the session holder; its absence past the profile's window means HOLD.

    ``seq`` rises by one per heartbeat and ``stamp`` is the sender's monotonic clock: the robot
    accepts one only if both advanced past the last it accepted for the session, so a captured
    heartbeat sent again is refused (counted in ``Health.refused_heartbeats``)."""

    TOPIC: ClassVar[str] = "cmd/heartbeat"
    RATE: ClassVar[str] = "10 Hz or more"
    session: Name = ""
    seq: int = 0


class ResetRequest(Message):
    """Reset a latched e-stop or fault, by the session holder: on its own key so Zenoh's ACL
    admits it only from identities with the ``reset`` right (docs/access.md)."""

    TOPIC: ClassVar[str] = "cmd/reset"
    RATE: ClassVar[str] = "on demand"
    session: Name = ""


class OverrideClaim(Message):
    """Claim the controlling session even when another holds it: on its own key so Zenoh's ACL
    admits it only from identities with the ``override`` right (docs/access.md)."""

    TOPIC: ClassVar[str] = "cmd/override"
    RATE: ClassVar[str] = "on demand"
    session: Name = ""
    client: Name = ""


# --- perception features ----------------------------------------------------------------


class Feature(Message):
    """Base of what perception plugins publish: ``frame_stamp`` is the stamp of the depth frame
    the feature was computed from (the control role's clock), ``stamp`` when it was published;
    ``frame_position`` and ``frame_orientation`` (w, x, y, z) are the body pose in the odometry
    frame at ``frame_stamp`` that perception computed it in, so a reader can place a
    body-frame feature in the odometry frame."""

    frame_stamp: float = 0.0
    frame_position: Vector = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    frame_orientation: Vector = msgspec.field(default_factory=lambda: [1.0, 0.0, 0.0, 0.0])


class GridFeature(Feature):
    """A feature on a grid of ``rows`` × ``cols`` square cells: cell (row, col) covers
    x = origin_x + row · resolution, y = origin_y + col · resolution (m)."""

    origin_x: float = 0.0
    origin_y: float = 0.0
    resolution: float = 0.01
    rows: int = 0
    cols: int = 0


class ElevationGrid(GridFeature):
    """Height map in the body frame: ``heights`` is row-major float32 little-endian, NaN unknown."""

    TOPIC: ClassVar[str] = "features/grid"
    RATE: ClassVar[str] = "camera rate, up to 30 Hz"
    heights: Annotated[bytes, msgspec.Meta(max_length=MAX_GRID_BYTES)] = b""


TERRAIN_LAYERS = (
    "height",
    "variance",
    "normal_x",
    "normal_y",
    "slope",
    "roughness",
    "step",
    "traversability",
    "age",
)
"""The layers of a TerrainMap, in order: m, m², unit normal's x and y (z = √(1 − x² − y²)),
rad, m, m, [0, 1], s since a frame last saw the cell."""


class TerrainMap(GridFeature):
    """The world model's elevation map in the odometry frame (grid_map style): a rolling window
    around the robot fused from every frame, with its terrain layers (TERRAIN_LAYERS).

    ``layers`` holds each layer as row-major float16 little-endian, zlib-compressed, NaN
    unknown, over the window's observed part. Heights are stored less ``origin_z`` (the body's
    height when published) to keep float16's millimetres; ages count back from ``frame_stamp``.
    """

    TOPIC: ClassVar[str] = "features/terrain"
    RATE: ClassVar[str] = "2 Hz"
    origin_z: float = 0.0
    layers: Annotated[
        dict[Name, Annotated[bytes, msgspec.Meta(max_length=MAX_GRID_BYTES)]],
        msgspec.Meta(max_length=MAX_ENTRIES),
    ] = {}


class Joist(msgspec.Struct, kw_only=True):
    """A joist (paper 000): distance along the direction of motion, yaw ψ (eq. 2), height (m).

    ``yaw`` is signed: the yaw of the joist's normal pointing away from the robot, positive
    counter-clockwise (eq. 2 gives its absolute value); turning by it squares the robot to the
    joist. ``height`` is the top above the floor beside it; ``endpoints`` are two (x, y, z)
    body-frame points on its near top edge; ``confidence`` in [0, 1].
    """

    distance: float
    yaw: float
    height: float
    endpoints: Vectors
    confidence: float = 1.0


class Joists(Feature):
    """Joists seen in one frame, nearest first."""

    TOPIC: ClassVar[str] = "features/joists"
    RATE: ClassVar[str] = "camera rate"
    joists: Annotated[list[Joist], msgspec.Meta(max_length=MAX_FEATURES)] = []


class GraspablePoints(Feature):
    """Graspable points (paper 001) in the body frame, metres, one (x, y, z) each."""

    TOPIC: ClassVar[str] = "features/graspable"
    RATE: ClassVar[str] = "camera rate"
    points: Annotated[list[Vector], msgspec.Meta(max_length=MAX_FEATURES)] = []


class Tracked(msgspec.Struct, kw_only=True):
    """What the world model keeps of a feature tracked across frames: its identity, how sure
    (1 − Π(1 − cᵢ) over its sightings), how many frames saw it, seconds since the last."""

    id: int
    confidence: float
    seen: int
    age: float


class MappedHold(Tracked, kw_only=True):
    """A graspable point of the hold map: its odometry-frame position (m, its height kept)."""

    position: Vector


class HoldMap(Feature):
    """The world model's graspable points (paper 001) tracked across frames, odometry frame."""

    TOPIC: ClassVar[str] = "features/hold_map"
    RATE: ClassVar[str] = "2 Hz"
    holds: Annotated[list[MappedHold], msgspec.Meta(max_length=MAX_FEATURES)] = []


class MappedJoist(Tracked, kw_only=True):
    """A joist of the joist map, odometry frame: its near top edge's line n·p = ``offset`` with
    n = (cos ``heading``, sin ``heading``) pointing away from where it was first seen, its
    ``height``, the ``endpoints`` (x, y, z) of the edge seen so far."""

    heading: float
    offset: float
    height: float
    endpoints: Vectors


class JoistMap(Feature):
    """The world model's joists (paper 000) tracked across frames, odometry frame."""

    TOPIC: ClassVar[str] = "features/joist_map"
    RATE: ClassVar[str] = "2 Hz"
    joists: Annotated[list[MappedJoist], msgspec.Meta(max_length=MAX_FEATURES)] = []


class Stability(Message):
    """Tumble Stability Margin (m, Yoneda & Hirose, with grip forces) of a climbing gait's tick:
    ``support`` marks the limbs it counts, ``grip`` the closed grippers, ``swing`` the swinging
    limb (-1 when none); ``plan_late`` while the robot holds its stance because the next swing's
    plan is not ready."""

    TOPIC: ClassVar[str] = "state/stability"
    RATE: ClassVar[str] = "control rate"
    tsm: float = 0.0
    support: LegFlags = []
    grip: LegFlags = []
    swing: int = -1
    plan_late: bool = False


class TrussMember(msgspec.Struct, kw_only=True):
    """A cylindrical truss member (paper 003): the tube extent p0, p1 (m, where the tube's
    surface ends), radius (m), unit axis p0 -> p1; confidence: 1 - the product over the
    updates it was seen in of (1 - the fraction of its length covered by points); ``id`` stays
    the member's across model updates (0: not tracked).
    ``node0``/``node1``: its node-to-node ends, the nodes (where member axes meet, inside the
    connectors) its p0/p1 ends meet; empty when that end is free (then the tube end)."""

    p0: Vector
    p1: Vector
    radius: float
    axis: Vector
    confidence: float = 1.0
    id: int = 0
    node0: Vector = []
    node1: Vector = []


class TrussNode(msgspec.Struct, kw_only=True):
    """A connector of the truss: where the ends of two or more members meet (m, odometry
    frame), and the ids of those members; ``reach`` (m): how far from it the farthest of
    their tube ends lies (the connector's extent along the members; 0: not measured)."""

    position: Vector
    members: Annotated[list[int], msgspec.Meta(max_length=MAX_ENTRIES)]
    reach: float = 0.0


class TrussMembers(Feature):
    """The truss model, odometry frame (frames accumulated with BodyState): its members and the
    connectors their ends meet at."""

    TOPIC: ClassVar[str] = "features/truss"
    RATE: ClassVar[str] = "on model update"
    members: Annotated[list[TrussMember], msgspec.Meta(max_length=MAX_FEATURES)] = []
    nodes: Annotated[list[TrussNode], msgspec.Meta(max_length=MAX_FEATURES)] = []


class TrussGrasp(msgspec.Struct, kw_only=True):
    """Where a gripper may close on a truss member (odometry frame, m): ``position`` on the
    member's axis, ``approach`` the unit direction the gripper moves in to close (perpendicular
    to the axis), ``clearance`` the free space between the closed gripper (a ball of half its
    width, or the member's radius if larger, about ``position``) and the nearest node or other
    member (inf: the truss has no other), ``span`` the ends (x, y, z) of the clear stretch of
    axis it lies on, ``limbs`` the legs (profile order) whose IK reaches ``position`` within
    joint limits from the frame's pose."""

    member: int
    position: Vector
    approach: Vector
    clearance: float
    span: Vectors
    limbs: Annotated[list[int], msgspec.Meta(max_length=MAX_LEGS)] = []


class TrussGrasps(Feature):
    """Grasp targets on the truss model's members (paper 003) for the profile's gripper
    (``width`` along the axis and ``clearance``, m), odometry frame; reachability is from the
    body pose ``frame_position``, ``frame_orientation``."""

    TOPIC: ClassVar[str] = "features/truss_grasps"
    RATE: ClassVar[str] = "on model update, with features/truss"
    width: float = 0.0
    clearance: float = 0.0
    grasps: Annotated[list[TrussGrasp], msgspec.Meta(max_length=MAX_FEATURES)] = []


class Stair(msgspec.Struct, kw_only=True):
    """One step (paper 004): rise above the previous tread, tread depth, tread height, edge line."""

    height: float
    rise: float
    depth: float
    edge: Vectors


class AlignedFeature(Feature):
    """A feature whose frame's cloud was registered onto the role's map. ``alignment``: the
    translation (m, odometry frame) that moved the cloud onto the map, solved only along
    ``constrained``, the unit directions the structure in view pins; the estimator's drift
    measurement (paper 004 filter 2). Both empty when the cloud was not aligned."""

    alignment: Vector = []
    constrained: Vectors = []


class Stairs(AlignedFeature):
    """Stairs in the odometry frame, bottom step first; their treads pin z, their risers the
    ascent (``constrained``)."""

    TOPIC: ClassVar[str] = "features/stairs"
    RATE: ClassVar[str] = "camera rate"
    steps: Annotated[list[Stair], msgspec.Meta(max_length=MAX_FEATURES)] = []


class MappedStair(Tracked, kw_only=True):
    """A step of the stair map, odometry frame: as a Stair (tread top ``height``, ``rise``,
    tread ``depth``, ``edge`` ends left then right facing up the flight), tracked."""

    height: float
    rise: float
    depth: float
    edge: Vectors


class StairMap(Feature):
    """The world model's stair steps (paper 004) tracked across frames, odometry frame, bottom
    step first."""

    TOPIC: ClassVar[str] = "features/stair_map"
    RATE: ClassVar[str] = "2 Hz"
    steps: Annotated[list[MappedStair], msgspec.Meta(max_length=MAX_FEATURES)] = []


FEATURES: tuple[type[Feature], ...] = (
    ElevationGrid,
    TerrainMap,
    Joists,
    JoistMap,
    GraspablePoints,
    HoldMap,
    TrussMembers,
    TrussGrasps,
    Stairs,
    StairMap,
)
"""The features of the contract's own perception plugins and of the world model."""


class StairStep(Message):
    """The stair gait's plan at a half cycle's start (paper 004 section 3.3): tripod ``legs``
    (profile order) steps ``length`` (m along the heading) with swing ``height`` (m, apex over
    the highest tread under a foot's path), then the other tripod ``next_length``; ``feasible``:
    the step lengths (m) all three feet allow; ``limit``: the longest the command asks for;
    ``body``: the body's progress (m) along the flight. A zero ``length`` under a nonzero
    ``limit`` means the robot waits: no longer step is feasible (``blocked``: not even this)."""

    TOPIC: ClassVar[str] = "state/stair_step"
    RATE: ClassVar[str] = "every half cycle of the stair gait"
    body: float = 0.0
    legs: Annotated[list[int], msgspec.Meta(max_length=MAX_LEGS)] = []
    length: float = 0.0
    height: float = 0.0
    next_length: float = 0.0
    limit: float = 0.0
    feasible: Annotated[list[float], msgspec.Meta(max_length=MAX_FEATURES)] = []
    blocked: bool = False


class DepthImage(Message):
    """A simulated depth frame (``climbd run --sim``): the twin's camera, on its way to the
    perception role's software device. uint16 little-endian, row-major; ``stamp`` is sim time."""

    TOPIC: ClassVar[str] = "sim/depth"
    RATE: ClassVar[str] = "the simulated camera's frame rate"
    camera: Name = ""
    width: int = 0
    height: int = 0
    depth_scale: float = 0.001
    depth: Annotated[bytes, msgspec.Meta(max_length=MAX_DEPTH_BYTES)] = b""


class DepthPreview(Message):
    """A perception role's depth frame, decimated for viewers (``climbd view`` draws it as a
    point cloud in the camera's optical frame): every ``stride``-th pixel of every
    ``stride``-th row of the frame, so that ``width`` × ``height`` ≤ ``[world]
    preview_points``; uint16 little-endian, row-major, × ``depth_scale`` = m, 0 no return.
    ``fx``, ``fy``, ``cx``, ``cy`` (pixels) are the decimated image's own pinhole intrinsics
    (the frame's divided by ``stride``): a point is ((u − cx)·z/fx, (v − cy)·z/fy, z) at
    pixel (u, v), optical frame x right, y down, z forward. ``frame_stamp`` is the depth
    frame's stamp (the control role's clock, as BodyState's); ``stamp`` when it was sent."""

    TOPIC: ClassVar[str] = "state/depth"
    RATE: ClassVar[str] = "every [world] preview_period (0.5 s), from the perception role"
    camera: Name = ""
    frame_stamp: float = 0.0
    width: int = 0
    height: int = 0
    stride: int = 1
    depth_scale: float = 0.001
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    depth: Annotated[bytes, msgspec.Meta(max_length=MAX_PREVIEW_BYTES)] = b""


class SimTruth(Message):
    """The twin world's ground truth (``climbd run --sim``): its joists, stair steps, holds and
    truss as the world model's maps would hold them if perception were perfect (every item of
    confidence 1, ``seen`` 0, age 0), from drivers/sim/truth.py. Positions are in the world
    frame, which is the run's odometry frame (the estimator starts at the twin's body pose).
    A map the world has none of is None. For viewers (``climbd view``, ``climbd record
    --scene``), never for behaviours: they read perception's maps."""

    TOPIC: ClassVar[str] = "sim/truth"
    RATE: ClassVar[str] = "1 Hz, simulated time in a stepped run"
    world: Name = ""
    joists: JoistMap | None = None
    stairs: StairMap | None = None
    holds: HoldMap | None = None
    truss: TrussMembers | None = None


ALL_MESSAGES: tuple[type[Message], ...] = (
    JointState,
    JointCommand,
    Health,
    BodyState,
    FootTargets,
    MotionCommand,
    ModeState,
    ModeRequest,
    EStop,
    SessionClaim,
    Heartbeat,
    ResetRequest,
    OverrideClaim,
    ElevationGrid,
    TerrainMap,
    Joists,
    JoistMap,
    GraspablePoints,
    HoldMap,
    Stability,
    StairStep,
    DepthImage,
    DepthPreview,
    TrussMembers,
    TrussGrasps,
    Stairs,
    StairMap,
    SimTruth,
)


def key(robot: str, message: type[Message] | str) -> str:
    """Key expression ``climbd/<robot>/<topic>`` for a message type or a topic string."""
    topic = message if isinstance(message, str) else message.TOPIC
    return f"climbd/{robot}/{topic}"


_encoder = msgspec.msgpack.Encoder()


def encode(message: Message) -> bytes:
    """Encode a message to its msgpack payload."""
    return _encoder.encode(message)


class SchemaMismatch(ValueError):
    """A payload decoded but carries another schema version than ours."""


_decoders: dict[type, msgspec.msgpack.Decoder] = {}


def decode(payload: bytes, message: type[Message]) -> Message:
    """Decode ``message``; raises msgspec.DecodeError/ValidationError or SchemaMismatch.

    msgspec raises UnicodeDecodeError for a map key that is not UTF-8, and RecursionError for
    a value under an unknown key nested past the recursion limit (skipping it recurses); both
    become a DecodeError here so every garbage payload is refused the same way (found by
    tests/test_fuzz.py and bench/soak.py's fuzz).
    """
    decoder = _decoders.get(message)
    if decoder is None:
        decoder = _decoders[message] = msgspec.msgpack.Decoder(message)
    try:
        value = decoder.decode(payload)
    except UnicodeDecodeError as e:
        raise msgspec.DecodeError(f"{message.__name__}: invalid UTF-8 in a string: {e}") from None
    except RecursionError:
        raise msgspec.DecodeError(f"{message.__name__}: nested too deeply") from None
    if value.schema != SCHEMA_VERSION:
        raise SchemaMismatch(
            f"{message.__name__}: schema {value.schema}, this climbd speaks {SCHEMA_VERSION}"
        )
    return value


def json_schemas() -> dict:
    """JSON Schema of every message, keyed by topic, for third-party clients."""
    _, components = msgspec.json.schema_components(ALL_MESSAGES, ref_template="#/$defs/{name}")
    return {
        "schema_version": SCHEMA_VERSION,
        "topics": {
            m.TOPIC: {"type": m.__name__, "rate": m.RATE, "$ref": f"#/$defs/{m.__name__}"}
            for m in ALL_MESSAGES
        },
        "$defs": components,
    }
