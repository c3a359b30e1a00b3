"""Accuracy of a truss model against known members, with the paper's metrics (Figs. 9-11):
relative length error, midpoint distance and axis angle per ground-truth member, and (ours,
issue 37) the farther of the two end point errors. Run it on tube extents against true tubes,
or on node-to-node ends against true nodes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MemberError:
    """Errors of the detected member matched to one ground-truth member (None if not found)."""

    truth: int
    detected: int | None
    length_error: float = float("nan")
    relative_length_error: float = float("nan")
    midpoint_error: float = float("nan")
    angle_error_deg: float = float("nan")
    end_error: float = float("nan")


@dataclass(frozen=True)
class Accuracy:
    """Per-member errors, their means over found members, and the unmatched detections."""

    members: list[MemberError]
    false_members: int

    @property
    def found(self) -> int:
        return sum(m.detected is not None for m in self.members)

    @property
    def all_found(self) -> bool:
        return self.found == len(self.members)

    def mean(self, field: str) -> float:
        values = [getattr(m, field) for m in self.members if m.detected is not None]
        return float(np.mean(values)) if values else float("nan")

    def max(self, field: str) -> float:
        """The worst found member's ``field`` (nan if none was found)."""
        values = [getattr(m, field) for m in self.members if m.detected is not None]
        return float(np.max(values)) if values else float("nan")


def end_error(d0: np.ndarray, d1: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> float:
    """The farther of the two end point errors (m), the ends paired either way round."""
    same = max(np.linalg.norm(d0 - t0), np.linalg.norm(d1 - t1))
    flipped = max(np.linalg.norm(d0 - t1), np.linalg.norm(d1 - t0))
    return float(min(same, flipped))


def _line_distance(point: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> float:
    w = point - origin
    return float(np.linalg.norm(w - (w @ axis) * axis))


def evaluate(
    detected: list[tuple[np.ndarray, np.ndarray]],
    truth: list[tuple[np.ndarray, np.ndarray, float]],
    max_angle_deg: float = 10.0,
) -> Accuracy:
    """Match detections (p0, p1) to ground truth (p0, p1, radius) and measure the errors.

    A detection matches a member when their axes are within ``max_angle_deg`` and the
    detection's axis passes within two radii of the member's axis over their overlap; each
    member takes the match with the longest overlap, each detection serves one member.
    """
    candidates = []
    for i, (t0, t1, radius) in enumerate(truth):
        t_axis = (t1 - t0) / np.linalg.norm(t1 - t0)
        for j, (d0, d1) in enumerate(detected):
            d_axis = (d1 - d0) / np.linalg.norm(d1 - d0)
            angle = np.degrees(np.arccos(min(1.0, abs(t_axis @ d_axis))))
            if angle > max_angle_deg:
                continue
            s = sorted([(d0 - t0) @ t_axis, (d1 - t0) @ t_axis])
            lo, hi = max(s[0], 0.0), min(s[1], np.linalg.norm(t1 - t0))
            if hi <= lo:
                continue
            mid = t0 + 0.5 * (lo + hi) * t_axis
            if _line_distance(mid, d0, d_axis) > 2 * radius:
                continue
            candidates.append((hi - lo, i, j, angle))
    matched: dict[int, tuple[int, float]] = {}
    used: set[int] = set()
    for _, i, j, angle in sorted(candidates, reverse=True):
        if i not in matched and j not in used:
            matched[i] = (j, angle)
            used.add(j)
    errors = []
    for i, (t0, t1, _) in enumerate(truth):
        if i not in matched:
            errors.append(MemberError(i, None))
            continue
        j, angle = matched[i]
        d0, d1 = detected[j]
        true_length = float(np.linalg.norm(t1 - t0))
        length = float(np.linalg.norm(d1 - d0))
        errors.append(
            MemberError(
                truth=i,
                detected=j,
                length_error=abs(length - true_length),
                relative_length_error=abs(length - true_length) / true_length,
                midpoint_error=float(np.linalg.norm(0.5 * (d0 + d1) - 0.5 * (t0 + t1))),
                angle_error_deg=float(angle),
                end_error=end_error(d0, d1, t0, t1),
            )
        )
    return Accuracy(errors, len(detected) - len(used))
