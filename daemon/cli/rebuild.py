"""``climbd rebuild FILE --profile P``: re-run perception on a recording and rebuild its maps.

The recording's body states (``state/body``) go into the perception role's pose history and its
depth frames (``sim/depth``, as a twin run publishes them) through the profile's perception
plugins and the world model, by the role's own ``perceive``, in log-time order. The last terrain
map rebuilt for a frame is compared with the one recorded live for the same frame: cells known
in both, heights within 1 mm; joists and holds by count. ``-o OUT`` writes what was rebuilt
(features and maps) to an MCAP that ``climbd replay`` serves.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from climbd.daemon.algorithms.world import TerrainView
from climbd.daemon.cli.record import McapSink, RecordingError, Sample
from climbd.daemon.cli.replay import read
from climbd.daemon.cli.sim_host import frame_of
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.profile import Profile, ProfileError, load
from climbd.daemon.runtime.perception_role import PerceptionRole, make_plugins

AGREE = 0.001
"""m: heights of a cell closer than this agree."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="MCAP recording holding state/body and sim/depth")
    parser.add_argument("--profile", required=True, help="the robot profile the run used")
    parser.add_argument("-o", "--output", help="write the rebuilt features and maps here")


@dataclass
class Agreement:
    """How a rebuilt terrain map matches the live one of the same frame."""

    frame_stamp: float
    live_cells: int
    rebuilt_cells: int
    both: int
    within: int
    worst: float

    def __str__(self) -> str:
        share = self.within / self.both if self.both else 0.0
        return (
            f"terrain at frame {self.frame_stamp:.3f} s: {self.live_cells} cells live, "
            f"{self.rebuilt_cells} rebuilt, {self.both} in both, {share:.1%} within "
            f"{AGREE * 1e3:g} mm (worst {self.worst * 1e3:.2f} mm)"
        )


def compare(live: m.TerrainMap, rebuilt: m.TerrainMap) -> Agreement:
    """Cell by cell over the two maps' overlap (same odometry frame and resolution)."""
    a, b = TerrainView(live), TerrainView(rebuilt)
    ha = a.layer("height") + live.origin_z
    hb = b.layer("height") + rebuilt.origin_z
    res = live.resolution
    shift_r = round((rebuilt.origin_x - live.origin_x) / res)
    shift_c = round((rebuilt.origin_y - live.origin_y) / res)
    r0, c0 = max(0, shift_r), max(0, shift_c)
    r1 = min(live.rows, shift_r + rebuilt.rows)
    c1 = min(live.cols, shift_c + rebuilt.cols)
    wa = ha[r0:r1, c0:c1]
    wb = hb[r0 - shift_r : r1 - shift_r, c0 - shift_c : c1 - shift_c]
    both = np.isfinite(wa) & np.isfinite(wb)
    diff = np.abs(wa - wb)[both]
    return Agreement(
        frame_stamp=live.frame_stamp,
        live_cells=int(np.isfinite(ha).sum()),
        rebuilt_cells=int(np.isfinite(hb).sum()),
        both=int(both.sum()),
        within=int((diff < AGREE).sum()),
        worst=float(diff.max()) if diff.size else 0.0,
    )


def rebuild(path: str | Path, profile: Profile) -> tuple[list[m.Message], list[m.Message]]:
    """Re-run perception on a recording: (what it publishes now, what was recorded live)."""
    role = PerceptionRole(profile, argparse.Namespace())
    plugins = make_plugins(profile, None, role.plugin_failed)
    cameras = {c.name: c for c in profile.cameras}
    rebuilt: list[m.Message] = []
    live: list[m.Message] = []
    for item in read(path):
        message = item.message
        if isinstance(message, m.BodyState):
            role.on_body(message)
        elif isinstance(message, m.JointState):
            role.on_joints(message)
        elif isinstance(message, m.DepthImage) and message.camera in cameras:
            role.perceive(frame_of(message, cameras[message.camera]), plugins, rebuilt.append)
        elif isinstance(message, m.Feature):
            live.append(message)
    return rebuilt, live


def last_pair(
    rebuilt: list[m.Message], live: list[m.Message]
) -> tuple[m.TerrainMap, m.TerrainMap] | None:
    """The last live terrain map with a rebuilt one of the same frame."""
    ours = {r.frame_stamp: r for r in rebuilt if isinstance(r, m.TerrainMap) and r.rows}
    for recorded in reversed([x for x in live if isinstance(x, m.TerrainMap) and x.rows]):
        match = ours.get(recorded.frame_stamp)
        if match is not None:
            return recorded, match
    return None


def main(args: argparse.Namespace) -> int:
    try:
        profile = load(args.profile)
        rebuilt, live = rebuild(args.file, profile)
    except (RecordingError, ProfileError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    frames = sum(isinstance(r, m.TerrainMap) for r in rebuilt)
    print(
        f"climbd: rebuilt {len(rebuilt)} features and maps ({frames} terrain maps) from {args.file}"
    )
    pair = last_pair(rebuilt, live)
    print(str(compare(*pair)) if pair else "no terrain map recorded live to compare with")
    for line in _feature_maps(rebuilt, live):
        print(line)
    if args.output:
        write(Path(args.output), profile.name, rebuilt)
        print(f"climbd: wrote {len(rebuilt)} messages to {args.output}")
    return 0


def _feature_maps(rebuilt: list[m.Message], live: list[m.Message]) -> list[str]:
    """One line per feature map kind: how many tracks live and rebuilt, last of each."""
    lines = []
    joists = [[x for x in group if isinstance(x, m.JoistMap)] for group in (live, rebuilt)]
    if all(joists):
        lines.append(
            f"{m.JoistMap.TOPIC}: {len(joists[0][-1].joists)} live, "
            f"{len(joists[1][-1].joists)} rebuilt"
        )
    holds = [[x for x in group if isinstance(x, m.HoldMap)] for group in (live, rebuilt)]
    if all(holds):
        lines.append(
            f"{m.HoldMap.TOPIC}: {len(holds[0][-1].holds)} live, {len(holds[1][-1].holds)} rebuilt"
        )
    return lines


def write(path: Path, robot: str, messages: list[m.Message]) -> None:
    """The rebuilt messages as a recording, logged at their publication stamps."""
    sink = McapSink(path, sorted({type(x) for x in messages}, key=lambda t: t.TOPIC), robot)
    for message in messages:
        sink.write(Sample(m.key(robot, type(message)), message, int(message.stamp * 1e9)))
    sink.close()
