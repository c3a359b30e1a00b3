"""What a run in the twin did at each joist, scored by the world's truth against paper 000.

The paper's robot climbs every joist under 14 cm and goes round higher ones (§IV, Fig. 8).
A run's body path (world frame) passing a joist's near top edge between its ends climbed
over it; passing the edge's line beyond an end went round it; not passing it, did not reach
it. Ground truth scores the run here; it never drives one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from climbd.drivers.sim.truth import joists
from climbd.drivers.sim.worlds import World

PAPER_CLIMB_BELOW = 0.14
"""m: paper 000's robot climbs joists lower than this and goes round the others."""


@dataclass(frozen=True)
class JoistOutcome:
    """One joist: its height (m), the paper's action, what the run did and when (s)."""

    height: float
    paper: str
    did: str
    at: float | None

    @property
    def as_paper(self) -> bool:
        """Whether the run did what the paper's robot does at this joist."""
        return (self.paper, self.did) in {
            ("climb", "climbed over"),
            ("go round", "went round its end"),
        }


def joist_outcomes(world: World, times: np.ndarray, path: np.ndarray) -> list[JoistOutcome]:
    """Each joist of ``world``, in the world's order, with what the body path ``path`` (n×2
    or n×3, m) sampled at ``times`` (s) did at it: the first time it passed the joist's edge."""
    times = np.asarray(times, float)
    xy = np.asarray(path, float)[:, :2]
    out = []
    for joist in joists(world).joists:
        a, b = (np.array(p[:2]) for p in joist.endpoints)
        along = (b - a) / np.linalg.norm(b - a)
        normal = np.array([-along[1], along[0]])
        side = (xy - a) @ normal
        passed = np.flatnonzero(np.sign(side[:-1]) * np.sign(side[1:]) < 0)
        paper = "climb" if joist.height < PAPER_CLIMB_BELOW else "go round"
        if len(passed) == 0:
            out.append(JoistOutcome(joist.height, paper, "not reached", None))
            continue
        i = int(passed[0])
        w = side[i] / (side[i] - side[i + 1])
        point = xy[i] + w * (xy[i + 1] - xy[i])
        s = float((point - a) @ along)
        between = 0.0 <= s <= float(np.linalg.norm(b - a))
        did = "climbed over" if between else "went round its end"
        at = float(times[i] + w * (times[i + 1] - times[i]))
        out.append(JoistOutcome(joist.height, paper, did, at))
    return out


def describe(outcomes: list[JoistOutcome]) -> str:
    """One line per joist: height, the paper's action, what the run did and when."""
    lines = []
    for k, o in enumerate(outcomes, 1):
        when = f" at {o.at:.1f} s" if o.at is not None else ""
        mark = "as the paper" if o.as_paper else "NOT as the paper"
        lines.append(
            f"joist {k}: {o.height * 100:.0f} cm, the paper's robot would {o.paper}; "
            f"this run {o.did}{when} ({mark})"
        )
    return "\n".join(lines)
