"""Free-climbing gaits of paper 001 (§3) over discrete graspable points, as pure planners.

Frames: the wall frame has x up the slope (towards the goal), y left, z out of the wall; the
body keeps the wall's orientation, so body-frame feet are wall-frame feet minus the base.
One limb swings at a time (quasi-static, no four-limb phase): its gripper opens only while the
three others hold, it swings along a cubic spline (0.02 m high, 4 s), and closes before the
limb takes load. During the swing the base moves so that the CoM's projection along gravity
lands on the intersection of the support diagonals (§3.3).

Both gaits choose among the same options: the graspable points each limb reaches from the
current base (IK within joint limits), no farther than ``max_stride`` from its foot and clear
of the other grippers, and both take a step only if it is feasible: every foot reachable
along the base's path and the predicted Tumble Stability Margin ≥ 0 throughout (§3.2, [9]).
The periodic baseline swings limbs in a fixed crawl order and, as [9] in ClimbLab, takes its
limb's feasible option with the longest stride towards the goal even when that is a step
back, or holds still for the period when its limb has no feasible option.

The non-periodic gait chooses the swing limb freely (§3.1). The paper counts each limb's
options ahead, a stand-in (its two stated assumptions) for the stride and the lag that move
the whole robot; on maps tiled from the real cloud (about one hold per palm) that count
walks the robot into postures with no step ahead (``limb_rule = "paper"``, measured below).
So it selects by what the count stands for:
the base's progress towards the goal, looking ``horizon`` swings ahead over feasible steps (a
beam of ``beam`` postures per swing), and takes the first swing of the best sequence; among
equals, the longer stride. It never returns to one of its recent stances (nor does a sequence
it weighs return to its own), so it cannot undo a step and redo it; a step back is taken only
when it leads further. It keeps the rest of the sequence it chose and follows it unless the
next plan finds a better one. Told how long the climb is (``duration``), it looks no further
than the swings left: a search that looks past the run's end sets up swings that never
happen, and in 45 s runs that cost it a few centimetres on most maps (bench/free_climb.py,
the open-ended column).

Its base does not sit on the diagonals' crossing (§3.3): with grippers the TSM stays far above
zero there (least 0.25 m in the twin), and what bounds the climb is the legs' reach (on the
crossing, the stance legs left the base 5.6 cm of room up the slope per swing where it
advanced 1.1 cm; BENCHMARKS.md, bench/free_climb.py). So each
swing takes the base up to ``max_lead`` beyond the crossing, the furthest lead that keeps
every foot in reach and the holding grips' TSM ≥ ``lead_margin`` along the swing, which lets
the front legs reach holds further up.

``limb_rule = "paper"`` selects the paper's own rule instead (``ClimbPlanner._plan_paper``):
the limb with the most graspable options ahead in its reachable region (§3.1) steps to its
feasible option with the longest stride towards the goal (§3.2, [9]), so that rule can be
measured beside the search (bench/free_climb.py, its "paper rule" column).

Planning takes up to a few hundred milliseconds, so it runs off the control tick: a worker
thread (PlanAhead) plans the next swing from the posture the current swing ends in while it
executes. A swing that ends before its successor's plan is ready leaves the robot holding its
stance (all four grippers) and the tick says so (``late``); in simulated time (tests, twin,
bench) the runner waits for the plan where it needs it, so runs stay deterministic.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal, NamedTuple

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.planning import PlanWorker
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import (
    BodyState,
    FootTargets,
    HoldMap,
    Message,
    MotionCommand,
    Stability,
)
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.contract.profile import Profile
from climbd.plugins.gaits.tsm import stance_margins, tumble_stability_margin

NORMAL = np.array([0.0, 0.0, 1.0])
GOAL = np.array([1.0, 0.0, 0.0])
"""Direction of the goal in the wall frame: straight up the slope."""
PERIODIC_ORDER = (1, 0, 2, 3)  # rr, rf, lr, lf: the crawl order of [9]
SWING_SAMPLES = (0.25, 0.5, 0.75, 1.0)
"""Swing phases at which a step's reach and TSM are checked before it is taken."""
RECENT = 32
"""Stances the non-periodic gait remembers and does not return to."""
REACH_CHUNK = 4096
"""Points per leg that one vectorised reach call solves at most (bounds its memory)."""
SLOPE_NOTICE = 2.0
"""Degrees between the measured and the configured slope beyond which the gait says so."""
KNOWN_POSTURES = 4096
"""Postures whose feasible steps the non-periodic gait keeps between plans."""

log = logging.getLogger("climbd.gait.free_climb")


class ClimbConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Paper 001 §4.1 conditions (swing height/period, base height, grip force, slope, gravity,
    mass) and the foothold rule's limits: ``max_stride`` is ClimbLab's allowable maximum stride
    for discrete footholds, ``min_stride`` its same-point distance, ``hold_spacing`` the least
    distance (m) between two grippers' holds (one palm's width). ``horizon`` (swings) and
    ``beam`` (postures kept per swing) bound the non-periodic gait's look-ahead (a beam of 120
    is the narrowest that came within 10 % of the bound on each of 16 maps, where 12 to 100
    left one map at 0.87: its best route steps back first; bench/free_climb_maps.py); ``limb_rule``
    is how the non-periodic gait chooses its swing: ``"search"`` by that look-ahead, ``"paper"``
    by §3.1's count of options ahead (the periodic gait ignores it). The search may put the base
    up to ``max_lead`` (m) up the slope beyond the diagonals' crossing: the furthest of
    ``lead_steps`` evenly spaced leads whose swing keeps every foot in reach and the TSM of
    the holding grips ≥ ``lead_margin`` (m); the periodic gait and the paper's rule keep it on
    the crossing (§3.3). ``duration`` (s) is the time the climb is given from the gait's start
    (paper 001 §4: 45 s), if it has one: the search then looks no further than the swings left
    in it, so its last swings take the base as far as they can rather than set up swings that
    will not happen; 0 is open-ended (every plan looks ``horizon`` swings ahead), as is the
    climb after it.
    Where the grippers report whether they hold, a closed gripper that does not hold within
    ``grip_wait`` (s) fails its hold (see ``ClimbRunner.tick``). The holds are
    the world model's hold map: those at least ``min_confidence`` sure, each a foot target
    ``foot_radius`` (m, the gripper's contact sphere; unset: the profile's) above the top
    perception saw, placed from the body as its estimate sees it; a swing's hold counts as
    still there while the map has a hold within ``hold_tolerance`` (m) of it, and the swing
    follows it by its id where the map moves it further."""

    swing_height: float = 0.02
    swing_period: float = 4.0
    base_height: float = 0.06
    grip_force: float = 9.0
    mass: float = 2.3
    gravity: float = 9.80665 / 6
    slope_deg: float = 30.0
    max_stride: float = 0.1
    min_stride: float = 0.005
    hold_spacing: float = 0.03
    hold_tolerance: Annotated[float, msgspec.Meta(gt=0.0)] = 0.01
    foot_radius: Annotated[float, msgspec.Meta(ge=0.0)] | None = None
    min_confidence: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.0
    horizon: Annotated[int, msgspec.Meta(ge=1)] = 11
    beam: Annotated[int, msgspec.Meta(ge=1)] = 120
    limb_rule: Literal["search", "paper"] = "search"
    max_lead: Annotated[float, msgspec.Meta(ge=0.0, le=0.2)] = 0.08
    lead_steps: Annotated[int, msgspec.Meta(ge=2)] = 4
    lead_margin: Annotated[float, msgspec.Meta(ge=0.0)] = 0.05
    duration: Annotated[float, msgspec.Meta(ge=0.0)] = 0.0
    grip_wait: Annotated[float, msgspec.Meta(gt=0.0)] = 1.0


@dataclass(frozen=True)
class Step:
    """One planned swing: limb, foot start/target and base start/end (wall frame, m);
    ``regrip`` when the swing does not advance its foot (a step back or aside); ``wait``
    when the periodic gait's limb had no feasible option and holds still for its period."""

    limb: int
    start: np.ndarray
    target: np.ndarray
    base_start: np.ndarray
    base_end: np.ndarray
    regrip: bool = False
    wait: bool = False

    @property
    def stride(self) -> float:
        """Foot displacement towards the goal (m)."""
        return float((self.target - self.start) @ GOAL)


def smooth(s: float) -> float:
    """Cubic ease 3s² − 2s³: zero velocity at both ends."""
    return s * s * (3.0 - 2.0 * s)


def swing_lift(s: float, height: float) -> float:
    """Cubic-spline height of the swing foot over the wall: 0 → ``height`` at s = ½ → 0."""
    return height * (smooth(2 * s) if s < 0.5 else 1.0 - smooth(2 * s - 1.0))


def stance_key(feet: np.ndarray) -> tuple[float, ...]:
    """A stance as a hashable key: the feet's wall-plane positions rounded to 0.1 mm."""
    return stance_keys(np.asarray(feet)[None])[0]


def stance_keys(feet: np.ndarray) -> list[tuple[float, ...]]:
    """``stance_key`` of stances (n, 4, ≥2) in one pass."""
    flat = np.round(feet[:, :, :2], 4).reshape(len(feet), 2 * feet.shape[1])
    return list(map(tuple, flat.tolist()))


def diagonal_crossings(feet: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersections (n, 2) of the diagonals rf–lr and rr–lf of stances (n, 4, ≥2), and
    whether they cross (both within their segments); where they do not, the point is NaN."""
    a, b = feet[:, 0, :2], feet[:, 2, :2]
    c, d = feet[:, 1, :2], feet[:, 3, :2]
    e, f, g = b - a, c - d, c - a
    det = e[:, 0] * f[:, 1] - f[:, 0] * e[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (g[:, 0] * f[:, 1] - f[:, 0] * g[:, 1]) / det
        v = (e[:, 0] * g[:, 1] - g[:, 0] * e[:, 1]) / det
    crosses = (np.abs(det) >= 1e-12) & (u > 0.0) & (u < 1.0) & (v > 0.0) & (v < 1.0)
    point = a + u[:, None] * e
    point[~crosses] = np.nan
    return point, crosses


def diagonal_crossing(feet: np.ndarray) -> np.ndarray | None:
    """Intersection (x, y) of the diagonals rf–lr and rr–lf, or None if they do not cross."""
    point, crosses = diagonal_crossings(np.asarray(feet, float)[None])
    return point[0] if crosses[0] else None


class Move(NamedTuple):
    """A feasible step from a posture, the feet after it, their stance (``stance_key``) and
    the base's progress."""

    step: Step
    after: np.ndarray
    key: tuple[float, ...]
    ahead: float
    """How far the step's base ends towards the goal (m)."""


def sequence_value(path: tuple[Step, ...]) -> tuple[int, float, float]:
    """How the search ranks a sequence of swings: by its length (one that ends sooner ranks
    lower), then how far its base ends towards the goal, then its first swing's stride."""
    return len(path), float(path[-1].base_end @ GOAL), path[0].stride


class LegReach:
    """Reachability (IK within joint limits) of many points per leg in one vectorised call.

    The daemon's Kinematics solves one point per leg; a Kinematics over each leg repeated
    ``batch`` times solves ``batch`` candidate points of every leg at once.
    """

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.n_legs = len(profile.legs)
        self._kinematics: dict[int, Kinematics] = {}

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(n_legs, m) reachable flags of body-frame points shaped (n_legs, m, 3)."""
        m = points.shape[1]
        if m > REACH_CHUNK:
            return np.concatenate(
                [self(points[:, i : i + REACH_CHUNK]) for i in range(0, m, REACH_CHUNK)], axis=1
            )
        if m == 0:
            return np.zeros((self.n_legs, 0), dtype=bool)
        batch = 1 << (m - 1).bit_length()
        kin = self._kinematics.get(batch)
        if kin is None:
            kin = self._kinematics[batch] = Kinematics(self.profile, repeat=batch)
        padded = np.zeros((self.n_legs, batch, 3))
        padded[:, :m] = points
        padded[:, m:] = points[:, :1]
        return kin.ik(padded.reshape(-1, 3))[1].reshape(self.n_legs, batch)[:, :m]


class ClimbPlanner:
    """Plans swings over a hold map; ``periodic`` picks limbs in a fixed order instead (§3.1).
    Gravity acts along ``down`` (wall frame, unit), measured where the robot has a body
    orientation; without one, along the configured ``slope_deg``."""

    def __init__(
        self,
        kinematics: Kinematics,
        config: ClimbConfig,
        periodic: bool,
        down: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.reach = LegReach(kinematics.profile)
        self.config = config
        self.periodic = periodic
        self.turn = 0
        self.passed = 0
        """Turns the periodic gait waited out because its limb had no feasible step at all."""
        self.left: dict[int, np.ndarray] = {}
        """Holds the periodic gait stepped back from, barred to their limb until a stride ahead."""
        self.recent: deque[tuple] = deque(maxlen=RECENT)
        """The non-periodic gait's latest stances, which it does not return to."""
        self.known: dict[tuple, list[Move]] = {}
        """Feasible steps of the postures searched, for the hold map of ``holds_token``."""
        self.holds_token: int | None = None
        self.committed: tuple[Step, ...] = ()
        """The rest of the non-periodic gait's chosen sequence, after the swing it planned."""
        if down is None:
            slope = math.radians(config.slope_deg)
            down = np.array([-math.sin(slope), 0.0, -math.cos(slope)])
        self.down = np.asarray(down, float) / np.linalg.norm(down)
        self.force = config.mass * config.gravity * self.down

    def base_for(self, feet: np.ndarray) -> np.ndarray | None:
        """Base whose CoM projects along gravity onto the diagonals' crossing (§3.3)."""
        base, crosses = self.bases_for(np.asarray(feet, float)[None])
        return base[0] if crosses[0] else None

    def bases_for(self, feet: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``base_for`` of stances (n, 4, 3): bases (n, 3), NaN where the diagonals do not
        cross, and whether they do."""
        crossing, crosses = diagonal_crossings(feet)
        h = self.config.base_height
        shift = -h * self.down[:2] / -self.down[2]
        base = np.column_stack((crossing + shift, np.full(len(feet), h)))
        return base, crosses

    def tsm(self, com: np.ndarray, stance: np.ndarray) -> float:
        """Tumble Stability Margin (m) of the gripping ``stance`` feet with the CoM at ``com``."""
        return tumble_stability_margin(com, stance, self.force, self.config.grip_force, NORMAL)

    def pose(self, step: Step, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Swing foot and base at phase s ∈ [0, 1] of ``step``."""
        k = smooth(s)
        foot = step.start + k * (step.target - step.start)
        foot = foot + NORMAL * swing_lift(s, self.config.swing_height)
        return foot, step.base_start + k * (step.base_end - step.base_start)

    def leads(self) -> np.ndarray:
        """Leads (m) of the base up the slope beyond the diagonals' crossing that a step tries,
        furthest first: only the search leads; the periodic gait and the paper's rule keep the
        base on the crossing (§3.3)."""
        cfg = self.config
        if self.periodic or cfg.limb_rule != "search" or cfg.max_lead == 0.0:
            return np.zeros(1)
        return np.linspace(cfg.max_lead, 0.0, cfg.lead_steps)

    def feasible(
        self, feet: np.ndarray, base: np.ndarray, limb: int, target: np.ndarray
    ) -> Step | None:
        """The step of ``limb`` to ``target`` with the base at its furthest feasible lead, or
        None (see ``feasible_steps``)."""
        steps = self.feasible_steps(feet, base, np.array([limb]), np.asarray(target, float)[None])
        return steps[0]

    def feasible_steps(
        self, feet: np.ndarray, base: np.ndarray, limbs: np.ndarray, targets: np.ndarray
    ) -> list[Step | None]:
        """For each candidate swing of ``limbs[i]`` to ``targets[i]`` from posture (``feet``
        (4, 3) or per candidate (n, 4, 3), ``base`` (3,) or (n, 3)), the step with the base at
        its furthest feasible lead beyond the new diagonals' crossing, or None if those
        diagonals do not cross or, at every lead, a foot leaves its reach at a swing sample
        (``SWING_SAMPLES``) or the TSM of the three holding limbs falls below its margin (0 on
        the crossing, ``lead_margin`` ahead of it). Leads are tried furthest first, each over
        the candidates no further lead suits, in one vectorised reach call and one TSM call."""
        n = len(limbs)
        if n == 0:
            return []
        feet = np.broadcast_to(feet, (n, *np.shape(feet)[-2:]))
        base = np.array(np.broadcast_to(base, (n, 3)))
        targets = np.array(targets, float)
        legs, rows = len(feet[0]), np.arange(n)
        new = feet.copy()
        new[rows, limbs] = targets
        crossing, crosses = self.bases_for(new)
        k = np.array([smooth(s) for s in SWING_SAMPLES])
        lift = np.array([swing_lift(s, self.config.swing_height) for s in SWING_SAMPLES])
        start = feet[rows, limbs]
        swung = start[:, None, :] + k[None, :, None] * (targets - start)[:, None, :]
        swung = swung + lift[None, :, None] * NORMAL  # (n, S, 3)
        holding = np.ones((n, legs), bool)
        holding[rows, limbs] = False
        stances = new[holding].reshape(n, legs - 1, 3)  # the limbs that keep their grip
        end = np.full((n, 3), np.nan)
        pending = np.flatnonzero(crosses)
        for lead in self.leads():
            if not len(pending):
                break
            ends = crossing[pending] + lead * GOAL
            gone = ends - base[pending]
            bases = base[pending, None, :] + k[None, :, None] * gone[:, None, :]  # (m, S, 3)
            trial = feet[pending].transpose(1, 0, 2)[:, :, None, :].repeat(len(k), axis=2)
            trial[limbs[pending], np.arange(len(pending))] = swung[pending]
            reach = self.reach((trial - bases[None]).reshape(legs, -1, 3))
            reached = reach.reshape(legs, len(pending), len(k)).all(axis=(0, 2))
            margins = stance_margins(
                bases, stances[pending], self.force, self.config.grip_force, NORMAL
            ).min(axis=1)
            ok = reached & (margins >= (self.config.lead_margin if lead > 0.0 else 0.0))
            end[pending[ok]] = ends[ok]
            pending = pending[~ok]
        feasible = ~np.isnan(end[:, 0])
        return [
            Step(int(limbs[i]), start[i], targets[i], base[i], end[i]) if feasible[i] else None
            for i in range(n)
        ]

    def options(self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray) -> list[np.ndarray]:
        """Per limb, the holds it may grip next: reachable from the current base, within
        ``max_stride`` of its foot (and not its own hold), clear of the other grippers."""
        _, limbs, index = self.option_index(feet[None], base[None], holds)
        return [holds[index[limbs == limb]] for limb in range(len(feet))]

    def option_index(
        self, feet: np.ndarray, bases: np.ndarray, holds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``options`` of postures (``feet`` (P, 4, 3), ``bases`` (P, 3)) in one pass, as
        index arrays (posture, limb, hold) ordered by posture, limb, then hold."""
        cfg = self.config
        gap = np.linalg.norm(holds[None, None, :, :2] - feet[:, :, None, :2], axis=3)
        near = (gap > cfg.min_stride) & (gap <= cfg.max_stride)  # (P, 4, H)
        crowded = (gap <= cfg.hold_spacing).astype(np.int8)
        clear = crowded.sum(axis=1, keepdims=True) - crowded == 0  # no other gripper's
        posture, limb, index = np.nonzero(near & clear)
        legs = feet.shape[1]
        counts = np.bincount(limb, minlength=legs)
        points = np.zeros((legs, max(int(counts.max(initial=0)), 1), 3))
        slot = np.zeros(len(limb), int)
        for leg in range(legs):
            mine = limb == leg
            slot[mine] = np.arange(int(counts[leg]))
        points[limb, slot] = holds[index] - bases[posture]
        reach = self.reach(points)[limb, slot]
        return posture[reach], limb[reach], index[reach]

    def plan(
        self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray, swings_left: int = 0
    ) -> Step | None:
        """The next swing (§3.1-3.2), or None when no limb has any feasible step;
        ``swings_left`` is how many swings the climb's ``duration`` leaves, this one included
        (0: open-ended).

        A periodic limb that stepped back may not return to the hold it left before some limb
        has taken a stride ahead, so a stuck posture is worked free instead of cycling."""
        if not self.periodic:
            if self.config.limb_rule == "paper":
                return self._plan_paper(feet, base, holds)
            return self._plan_free(feet, base, holds, swings_left)
        options = self.options(feet, base, holds)
        for limb, hold in self.left.items():
            gap = np.linalg.norm(options[limb][:, :2] - hold[:2], axis=1)
            options[limb] = options[limb][gap > self.config.min_stride]
        step = self._plan_periodic(feet, base, options)
        if step.regrip:
            self.left[step.limb] = step.start
        elif not step.wait:
            self.left.clear()
        return step

    def successors(
        self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray, barred: set
    ) -> list[tuple[Step, np.ndarray]]:
        """Every feasible step from this posture, with the feet after it, whose stance is not
        in ``barred`` (see ``expand``)."""
        return [
            (m.step, m.after) for m in self.expand([(feet, base)], holds)[0] if m.key not in barred
        ]

    def expand(
        self, postures: Sequence[tuple[np.ndarray, np.ndarray]], holds: np.ndarray
    ) -> list[list[Move]]:
        """Every feasible step from each posture (feet, base). A posture's steps are worked out
        once per hold map (the next plans' look-ahead covers mostly the same postures), and
        the postures not yet known in one vectorised pass (a search level at a time)."""
        if not postures:
            return []
        every = np.array([feet for feet, _ in postures], float)
        places = np.array([base for _, base in postures], float)
        rounded = np.round(places, 4).tolist()
        keys = [s + tuple(b) for s, b in zip(stance_keys(every), rounded, strict=True)]
        out = {key: self.known[key] for key in keys if key in self.known}
        todo = {key: i for i, key in enumerate(keys) if key not in out}
        if todo:
            feet, bases = every[list(todo.values())], places[list(todo.values())]
            posture, limbs, index = self.option_index(feet, bases, holds)
            steps = self.feasible_steps(feet[posture], bases[posture], limbs, holds[index])
            afters = feet[posture]
            afters[np.arange(len(posture)), limbs] = holds[index]
            found: list[list[Move]] = [[] for _ in todo]
            moves = zip(posture, steps, afters, stance_keys(afters), strict=True)
            for p, step, after, stance in moves:
                if step is not None:
                    found[p].append(Move._make((step, after, stance, step.base_end @ GOAL)))
            if len(self.known) + len(todo) > KNOWN_POSTURES:
                self.known.clear()
            self.known.update(zip(todo, found, strict=True))
            out.update(zip(todo, found, strict=True))
        return [out[key] for key in keys]

    def _plan_free(
        self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray, swings_left: int
    ) -> Step | None:
        """§3.1 by its aim: the first swing of the feasible sequence (≤ ``horizon`` swings and
        ≤ ``swings_left`` if the climb counts them; the ``beam`` postures with the base
        furthest ahead kept per swing) that takes the base furthest towards the goal; a
        sequence that ends sooner ranks lower (``sequence_value``). The rest of the
        sequence chosen is kept: the next plan follows it unless it finds a better one, so a
        route found once is not lost to a narrower beam from the next posture; while the
        horizon is longer than what is kept, it is weighed with its best next swing added."""
        first, barred = self._first_steps(feet, base, holds)
        if not first:
            self.committed = ()
            return None
        # A node: the sequence so far, the feet after it, and its own stances: it may not
        # return to them nor to the recent ones (``barred``), as the gait may not.
        level = [((move.step,), move.after, (move.key,), move.ahead) for move in first]
        best = max((node[0] for node in level), key=sequence_value)
        horizon = self.config.horizon
        if swings_left > 0:
            horizon = min(horizon, swings_left)
        for _ in range(1, horizon):
            reached: dict[tuple, tuple[tuple[Step, ...], np.ndarray, tuple, float]] = {}
            moves = self.expand([(node[1], node[0][-1].base_end) for node in level], holds)
            for (path, _, keys, _), options in zip(level, moves, strict=True):
                for step, after, key, ahead in options:
                    if key in barred or key in keys:
                        continue
                    if key not in reached or reached[key][3] < ahead:
                        reached[key] = (path + (step,), after, (*keys, key), ahead)
            if not reached:
                break
            level = sorted(reached.values(), key=lambda node: -node[3])[: self.config.beam]
            best = max([best, *(node[0] for node in level)], key=sequence_value)
        kept = self.committed
        followed = self._follows(kept, feet, base, barred)
        if followed is not None:
            end, passed = followed
            if len(kept) < horizon:
                more = self.successors(end, kept[-1].base_end, holds, passed)
                if more:
                    kept += (max(more, key=lambda n: (n[0].base_end @ GOAL, n[0].stride))[0],)
            best = max(best, kept, key=sequence_value)
        self.committed = best[1:]
        step = best[0]
        return dataclasses.replace(step, regrip=step.stride <= self.config.min_stride)

    def _follows(
        self, path: tuple[Step, ...], feet: np.ndarray, base: np.ndarray, barred: set
    ) -> tuple[np.ndarray, set] | None:
        """If the committed ``path`` starts from this posture and returns to no barred stance
        (over the same hold map): the feet at its end and the stances it may not enter after
        it (``barred`` and its own); else None."""
        if not path or not np.allclose(path[0].base_start, base):
            return None
        feet = feet.copy()
        passed = set(barred)
        for step in path:
            if not np.allclose(feet[step.limb], step.start):
                return None
            feet[step.limb] = step.target
            key = stance_key(feet)
            if key in passed:
                return None
            passed.add(key)
        return feet, passed

    def _first_steps(
        self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray
    ) -> tuple[list[Move], set]:
        """The non-periodic gaits' feasible steps from this posture that do not return to a
        recent stance, and the stances barred. In a pocket, where every feasible step returns
        to a recent stance, only the current one is barred, so the gait backs out at once
        rather than holding still until the pocket's stances fall out of its memory."""
        barred = self._remember(feet, holds)
        moves = self.expand([(feet, base)], holds)[0]
        steps = [move for move in moves if move.key not in barred]
        if not steps:
            barred = {stance_key(feet)}
            steps = [move for move in moves if move.key not in barred]
        return steps, barred

    def _remember(self, feet: np.ndarray, holds: np.ndarray) -> set:
        """The non-periodic gaits' bookkeeping before a plan: forget the known steps if the
        hold map changed, and the committed sequence if a hold it steps to is gone; remember the
        stance ``feet`` (once, however often it is planned from); returns the recent stances
        (barred)."""
        token = hash(holds.tobytes())
        if token != self.holds_token:
            self.known.clear()
            if not all((holds == step.target).all(axis=1).any() for step in self.committed):
                self.committed = ()
            self.holds_token = token
        key = stance_key(feet)
        if not self.recent or self.recent[-1] != key:
            self.recent.append(key)
        return set(self.recent)

    def ahead_counts(self, feet: np.ndarray, options: list[np.ndarray]) -> np.ndarray:
        """§3.1's count per limb: "first for every limb, in its reachable region, the number of
        graspable options in the side of moving direction, is counted". The reachable region is
        the limb's ``options`` (IK from the current base, within ``max_stride``, clear of the
        other grippers: the region both gaits choose footholds in); the side of the moving
        direction is the half-plane ahead of the limb's foot along ``GOAL`` (stride > 0)."""
        return np.array([int(((o - feet[k]) @ GOAL > 0.0).sum()) for k, o in enumerate(options)])

    def _plan_paper(self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray) -> Step | None:
        """§3.1-3.3 as written: "the limb which has the most graspable targets is selected to be
        swung next" and "the next gripping point is selected so that the robot can get the
        longest stride to move forward within the kinematic constraint" (§3.2, [9]): the limb
        with the most options ahead (``ahead_counts``) takes its feasible option ahead with the
        longest stride towards the goal; feasibility, the cubic swing and the base over the
        diagonals' crossing (§3.3) are ``feasible``'s. Where the paper is silent: a limb with no
        feasible option ahead yields to the next count, ties go to the longer stride; with no
        feasible step ahead at all it re-grips, ranking all feasible steps the same way (count,
        then stride: that limb's shortest step back or aside); and, like the search, it never
        returns to a recent stance, so a re-grip is not undone at once (this can bar the
        paper's pick only after a step back: steps ahead never repeat a stance)."""
        steps = [move.step for move in self._first_steps(feet, base, holds)[0]]
        if not steps:
            return None
        count = self.ahead_counts(feet, self.options(feet, base, holds))
        ahead = [step for step in steps if step.stride > 0.0] or steps
        step = max(ahead, key=lambda s: (count[s.limb], s.stride))
        return dataclasses.replace(step, regrip=step.stride <= self.config.min_stride)

    def _plan_periodic(self, feet, base, options) -> Step | None:
        """[9] as ClimbLab runs it: the limb whose turn it is takes, of all its options, the
        feasible one furthest towards the goal (a step back if nothing ahead is feasible); with
        no feasible option it holds still for its swing period (a wait) and the turn moves on."""
        limb = PERIODIC_ORDER[self.turn]
        self.turn = (self.turn + 1) % len(PERIODIC_ORDER)
        opts = options[limb]
        stride = (opts - feet[limb]) @ GOAL
        for i in np.argsort(-stride, kind="stable"):
            step = self.feasible(feet, base, limb, opts[i])
            if step is not None:
                return dataclasses.replace(step, regrip=bool(stride[i] <= self.config.min_stride))
        self.passed += 1
        return Step(limb, feet[limb].copy(), feet[limb].copy(), base.copy(), base.copy(), wait=True)


class PlanAhead:
    """The planner on a ``PlanWorker`` (climbd.daemon.algorithms.planning), so planning never
    runs in the control tick; in ``wait`` mode (simulated time) ``take`` waits for the plan,
    keeping runs deterministic."""

    def __init__(self, planner: ClimbPlanner, wait: bool = False) -> None:
        self.planner = planner
        self.worker: PlanWorker[Step | None] = PlanWorker("climb-plan", wait)

    @property
    def requested(self) -> bool:
        """A plan has been requested and not yet taken."""
        return self.worker.pending

    def request(
        self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray, swings_left: int
    ) -> None:
        """Start planning the swing from posture (``feet``, ``base``) over ``holds``, with
        ``swings_left`` in the climb (0: open-ended), on the worker; the inputs are copied and
        frozen, so the plan depends on nothing else."""
        frozen = []
        for a in (feet, base, holds):
            a = np.array(a, float)
            a.flags.writeable = False
            frozen.append(a)
        self.worker.request(self.planner.plan, *frozen, swings_left)

    def take(self) -> tuple[bool, Step | None]:
        """(True, step) once the requested plan is done, else (False, None) without waiting
        (``wait`` mode: waits for it); a planner error is raised here, in the caller."""
        outcome = self.worker.take()
        if outcome is None:
            return False, None
        if outcome.error is not None:
            raise outcome.error
        return True, outcome.plan

    def close(self) -> None:
        """Stop the worker: a queued plan is dropped, one under way ends on its own."""
        self.worker.close()


@dataclass
class Tick:
    """Wall-frame state of one control tick: feet, base, swinging limb, grips, TSM (m);
    ``late`` when the robot holds its stance because the next swing's plan is not ready;
    ``reason`` why the gait holds still or backs off, while it does."""

    feet: np.ndarray
    base: np.ndarray
    swing: int | None
    grip: list[bool]
    tsm: float
    late: bool = False
    reason: str = ""


class ClimbRunner:
    """Executes planned swings tick by tick: release, swing, grip. The next swing is planned
    by ``ahead`` from the posture the current swing ends in, while the swing executes."""

    def __init__(
        self, planner: ClimbPlanner, feet: np.ndarray, base: np.ndarray, ahead: PlanAhead
    ) -> None:
        self.planner = planner
        self.ahead = ahead
        self.feet = np.array(feet, float)
        self.base = np.array(base, float)
        self.step: Step | None = None
        self.phase = 0.0
        self.steps: list[Step] = []
        self.reason = ""
        """Why the runner backs off, while it does."""
        self._backing: Step | None = None
        self.failed: list[np.ndarray] = []
        """Holds a gripper closed on without holding: never planned on again."""
        self.missed = 0
        """Swings whose gripper did not hold at the end (each backed off)."""
        self._unheld = 0.0
        self._asked: int | None = None
        """The hold map (its hash) of the plan asked for last."""
        self._stuck: int | None = None
        """The hold map (its hash) on which no step was feasible from here: not planned on
        again until the map changes."""

    def tick(self, dt: float, holds: np.ndarray, holding: Sequence[bool] | None = None) -> Tick:
        """Advance by ``dt`` (s); a swing starts only when the grippers hold and its plan is
        ready; until then the four grippers hold (a ``late`` tick). A plan whose hold the map
        no longer has where it was planned (a newer map moved or dropped it) is not started but
        made again over the map of now. A swing whose hold has left
        the map backs off to the hold it left; with no feasible step at all the four grippers
        hold, and the tick says why. ``holding`` is what the grippers report (None: they are
        taken to hold as commanded): between swings, no limb is released while any gripper
        does not hold; a swing's gripper that does not hold within ``grip_wait`` has failed its
        hold, and the limb swings back to the hold it left (never planned on again)."""
        holds = self._usable(holds)
        step = self.step
        lost = step is not None and not step.wait and not self._mapped(step.target, holds)
        if lost and step is not self._backing:
            self._back_off(holds, "left the hold map mid-swing")
        if self.step is None and holding is not None and not all(holding):
            return self._unheld_grips(dt, holds, holding)
        self._unheld = 0.0
        if self.step is None:
            if self._stuck == hash(holds.tobytes()):
                return self._no_step(holds)
            if not self.ahead.requested:
                self._request(self.feet, self.base, holds)
            ready, step = self.ahead.take()
            if not ready:
                return self._still(late=True)
            if step is not None and not step.wait and not self._mapped(step.target, holds):
                self._request(self.feet, self.base, holds)  # planned on a map now moved on
                return self._still(late=True)
            self.step, self.phase = step, 0.0
            self.reason, self._backing = "", None
            if step is None:
                self._stuck = self._asked
                return self._no_step(holds)
            self._stuck = None
            self.steps.append(step)
            self._request(*self._after(step), holds)
        step = self.step
        self.phase = min(1.0, self.phase + dt / self.planner.config.swing_period)
        if step.wait:
            if self.phase >= 1.0:
                self.step = None
            return self._still()
        foot, base = self.planner.pose(step, self.phase)
        feet = self.feet.copy()
        feet[step.limb] = foot
        grip = [True] * 4
        grip[step.limb] = self.phase >= 1.0
        margin = self.planner.tsm(base, np.delete(self.feet, step.limb, axis=0))
        if self.phase >= 1.0:
            self.feet = feet
            self.base = base
            self.step = None
        return Tick(feet, base, step.limb, grip, margin, reason=self.reason)

    def _unheld_grips(self, dt: float, holds: np.ndarray, holding: Sequence[bool]) -> Tick:
        """Between swings, a gripper reports it does not hold: the four stay closed; the one
        the last swing closed gets ``grip_wait`` to hold, then its hold fails and the limb
        backs off to the hold it left; a stance gripper that lets go holds everything still."""
        self._unheld += dt
        open_limbs = [leg for leg, held in enumerate(holding) if not held]
        last = self.steps[-1] if self.steps else None
        swung = last is not None and not last.wait and open_limbs == [last.limb]
        if (
            not swung
            or last is self._backing
            or self._unheld < self.planner.config.grip_wait - 1e-9
        ):
            names = ", ".join(str(leg) for leg in open_limbs)
            return self._still(reason=f"gripper of limb {names} does not hold: no limb released")
        self.missed += 1
        self.failed.append(last.target.copy())
        self.step, self.phase = last, 1.0
        self._back_off(self._usable(holds), "did not hold when its gripper closed")
        self._unheld = 0.0
        return self._still(reason=self.reason)

    def retarget(self, target: np.ndarray) -> None:
        """The swing's hold is seen elsewhere now (the body's estimate moved, not the hold):
        aim there. A back-off keeps its aim: the hold it left is where its foot gripped."""
        step = self.step
        if step is None or step.wait or step is self._backing:
            return
        self.step = dataclasses.replace(step, target=np.asarray(target, float).copy())
        if self.steps and self.steps[-1] is step:
            self.steps[-1] = self.step

    def _usable(self, holds: np.ndarray) -> np.ndarray:
        """The mapped holds less those within a palm's width (``hold_spacing``) of where a
        gripper failed: the rock there did not hold, and a hold mapped that near is the same
        feature seen a little elsewhere (maps put one rock feature in several places)."""
        holds = np.asarray(holds, float).reshape(-1, 3)
        if not self.failed or not len(holds):
            return holds
        gap = np.linalg.norm(holds[:, None, :] - np.array(self.failed)[None], axis=2)
        return holds[gap.min(axis=1) > self.planner.config.hold_spacing]

    def _mapped(self, target: np.ndarray, holds: np.ndarray) -> bool:
        """Whether the hold map still has a hold at ``target`` (within ``hold_tolerance``)."""
        gap = np.linalg.norm(np.asarray(holds).reshape(-1, 3) - target, axis=1)
        return bool(gap.size) and float(gap.min()) <= self.planner.config.hold_tolerance

    def _back_off(self, holds: np.ndarray, why: str) -> None:
        """The swinging limb's hold is lost (``why``: it left the map, occluded or gone from the
        wall, or the gripper closed on it without holding): swing back from where the foot is
        to the hold it left, which it gripped a moment ago, the base back along its path to
        where the swing began; the three others keep their grips, and the plan made for after
        the lost swing is replaced by one from after the back-off."""
        step = self.step
        foot, base = self.planner.pose(step, self.phase)
        back = Step(step.limb, foot, step.start.copy(), base, step.base_start.copy(), regrip=True)
        x, y = step.target[:2]
        self.reason = (
            f"limb {step.limb}'s hold at ({x:.3f}, {y:.3f}) m {why}: back to the hold it left"
        )
        self.step, self.phase, self._backing = back, 0.0, back
        self.steps.append(back)
        self._request(*self._after(back), holds)

    def _request(self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray) -> None:
        """Ask for the plan of the next swing from (``feet``, ``base``) over ``holds``."""
        self._asked = hash(holds.tobytes())
        self.ahead.request(feet, base, holds, self._swings_left())

    def _swings_left(self) -> int:
        """Swings the climb's ``duration`` leaves for the next one planned, that one included
        (0: open-ended, or the duration is spent)."""
        cfg = self.planner.config
        if cfg.duration <= 0.0:
            return 0
        return max(0, int(cfg.duration // cfg.swing_period) - len(self.steps))

    def _after(self, step: Step) -> tuple[np.ndarray, np.ndarray]:
        """Feet and base once ``step`` is done: exactly what ``tick`` reaches at phase 1."""
        if step.wait:
            return self.feet, self.base
        foot, base = self.planner.pose(step, 1.0)
        feet = self.feet.copy()
        feet[step.limb] = foot
        return feet, base

    def _still(self, late: bool = False, reason: str = "") -> Tick:
        """A tick holding the current stance with all four grippers."""
        margin = self.planner.tsm(self.base, self.feet)
        return Tick(self.feet.copy(), self.base.copy(), None, [True] * 4, margin, late, reason)

    def _no_step(self, holds: np.ndarray) -> Tick:
        """Four grips held still: no step is feasible over ``holds``, and the tick says so."""
        return self._still(reason=f"no feasible step over the {len(holds)} holds mapped")

    def close(self) -> None:
        """Stop the planning worker."""
        self.ahead.close()


class FreeClimb(GaitPlugin):
    """Non-periodic free-climbing gait (paper 001) as a gait plugin over the hold map. The
    runner acts on the grippers' holds as the joint bus reports them (``BodyState.holding``);
    a bus that drives no grippers reports none, and they are taken to hold as commanded."""

    name: ClassVar[str] = "free_climb"
    Config: ClassVar[type[msgspec.Struct]] = ClimbConfig
    needs: ClassVar[tuple[str, ...]] = (HoldMap.TOPIC,)
    periodic: ClassVar[bool] = False

    def __init__(self, config: ClimbConfig | None = None, profile: object = None) -> None:
        super().__init__(config, profile)
        self.kinematics = Kinematics(profile)
        radius = self.config.foot_radius
        self.foot_radius = (profile.foot_radius or 0.0) if radius is None else radius
        """m: how far above a hold's top the foot's centre grips it."""
        self.planner: ClimbPlanner | None = None
        self.runner: ClimbRunner | None = None
        self._forget_map()
        self.last: Tick | None = None
        self.stamp = 0.0

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        """Take the measured feet (body frame) as gripping; the wall frame starts under the
        base, its axes the body's at start (the body keeps the wall's orientation), and gravity
        acts along the odometry frame's down as the body measures it: a wall steeper than
        ``slope_deg`` gets the TSM of its true slope (a step that would tumble there is not
        feasible), and the difference is logged. Starts the planning worker (a fresh planner:
        a stopped one may still be finishing)."""
        self.stop()
        base = np.array([0.0, 0.0, self.config.base_height])
        wall_feet = np.asarray(feet, float) + base
        wall_feet[:, 2] = 0.0
        down = rotation(body.orientation).T @ np.array([0.0, 0.0, -1.0])
        self._forget_map()
        slope = math.degrees(math.acos(float(np.clip(-down @ NORMAL, -1.0, 1.0))))
        if abs(slope - self.config.slope_deg) > SLOPE_NOTICE:
            log.info(
                "measured slope %.1f deg, configured %.1f deg: planning on the measured gravity",
                slope,
                self.config.slope_deg,
            )
        self.planner = ClimbPlanner(self.kinematics, self.config, self.periodic, down)
        ahead = PlanAhead(self.planner, wait=self.stepped)
        self.runner = ClimbRunner(self.planner, wall_feet, base, ahead)

    def stop(self) -> None:
        """Stop the planning worker (the robot left ACTIVE or the daemon stops)."""
        if self.runner is not None:
            self.runner.close()

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        """Foot targets (body frame) of this tick, planned over the latest hold map."""
        seen = world.get(HoldMap.TOPIC)
        if isinstance(seen, HoldMap) and seen.stamp != self.mapped:
            self.take_map(seen, body)
        tick = self.runner.tick(dt, self.holds, body.holding)
        if tick.reason and (self.last is None or tick.reason != self.last.reason):
            log.info("%.2f s %s", t, tick.reason)
        self.last = tick
        self.stamp = t
        return FootTargets(
            stamp=t,
            positions=(tick.feet - tick.base).tolist(),
            stance=list(tick.grip),
            grip=tick.grip,
        )

    def _forget_map(self) -> None:
        """No holds until the next map (a new start has a new wall frame)."""
        self.holds = np.zeros((0, 3))
        self.hold_ids = np.zeros(0, np.int64)
        """The world model's ids of ``holds``, row by row."""
        self.mapped = -math.inf
        """The stamp of the hold map ``holds`` came from."""

    def take_map(self, seen: HoldMap, body: BodyState) -> None:
        """Take a new hold map (``wall_holds``). While the holds it shares with the last moved
        less than ``hold_tolerance / 2`` (the estimate's jitter, the body lagging its plan) they
        stay where they were, beside the holds it adds, so the plan's route stands where its
        holds stay (``_remember``); else the new positions replace them all, and a swing aims
        where its hold, by its id, is now (or backs off if it is gone)."""
        holds, ids = self.wall_holds(seen, body)
        self.mapped = seen.stamp
        calm = 0.5 * self.config.hold_tolerance
        _, now, was = np.intersect1d(ids, self.hold_ids, return_indices=True)
        if len(now) and np.abs(holds[now] - self.holds[was]).max() < calm:
            holds[now] = self.holds[was]
        if np.array_equal(ids, self.hold_ids) and np.array_equal(holds, self.holds):
            return
        step = self.runner.step
        if step is not None and len(self.holds):
            gap = np.linalg.norm(self.holds - step.target, axis=1)
            k = int(np.argmin(gap))
            again = np.flatnonzero(ids == self.hold_ids[k])
            if gap[k] <= self.config.hold_tolerance and again.size:
                self.runner.retarget(holds[again[0]])
        self.holds, self.hold_ids = holds, ids

    def wall_holds(self, holds: HoldMap, body: BodyState) -> tuple[np.ndarray, np.ndarray]:
        """The map's holds sure enough to grip, as wall-frame foot targets (heights kept), and
        their ids: each where the body's estimate now puts it from the body, from the plan's
        base. A shift of the odometry frame (drift, a re-registered stance) moves the map and
        the body alike, so the holds stay where the feet that grip them are, and the body's
        tilt and lag behind its plan turn the aim."""
        sure = [h for h in holds.holds if h.confidence >= self.config.min_confidence]
        tops = np.reshape([h.position for h in sure], (-1, 3))
        seen = (tops - body.position) @ rotation(body.orientation)
        base = self.runner.base if self.last is None else self.last.base
        ids = np.array([h.id for h in sure], np.int64)
        return base + seen + self.foot_radius * NORMAL, ids

    def telemetry(self) -> list[Message]:
        """This tick's Stability (TSM, holding limbs, grips) for the control role to publish."""
        tick = self.last
        if tick is None:
            return []
        return [
            Stability(
                stamp=self.stamp,
                tsm=tick.tsm,
                support=[leg != tick.swing for leg in range(len(tick.grip))],
                grip=list(tick.grip),
                swing=-1 if tick.swing is None else tick.swing,
                plan_late=tick.late,
            )
        ]


class PeriodicClimb(FreeClimb):
    """The periodic baseline of paper 001 ([9]): fixed limb order, same foothold rule."""

    name: ClassVar[str] = "periodic_climb"
    periodic: ClassVar[bool] = True
