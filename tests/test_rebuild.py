"""A recorded twin run rebuilds to the maps perception built live.

Live: the WidowX profile's perception role (its plugins and world model, ``perceive``) on the
twin's ray-cast frames as they travel on the wire (``sim/depth`` images, converted as the role's
software camera converts them), with body states walking toward the attic's joist. Everything
published, and the inputs, go to an MCAP through the recorder's sink. ``climbd rebuild`` then
re-runs perception on the recorded inputs: the terrain map it rebuilds for a frame matches the
live one cell for cell.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from climbd.daemon.cli.rebuild import compare, last_pair, rebuild
from climbd.daemon.cli.record import McapSink, Sample
from climbd.daemon.cli.sim_host import frame_of
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.profile import load
from climbd.daemon.runtime.perception_role import PerceptionRole, make_plugins

ROOT = Path(__file__).resolve().parent.parent
PROFILE = ROOT / "robots" / "widowx-attic-sim.toml"


def _record_live_run(path: Path) -> list[m.Message]:
    """The live run, recorded; returns what the role published."""
    from climbd.drivers.sim.twin import Twin

    profile = load(PROFILE)
    camera = profile.cameras[0]
    twin = Twin(profile, "attic_paper", stepped=True, bus=False)
    role = PerceptionRole(profile, argparse.Namespace())
    plugins = make_plugins(profile, None, role.plugin_failed)
    published: list[m.Message] = []
    sink = McapSink(path, list(m.ALL_MESSAGES), profile.name)

    def record(message: m.Message) -> None:
        sink.write(
            Sample(m.key(profile.name, type(message)), message, int(1e9 * (1 + message.stamp)))
        )

    twin.start()
    try:
        twin.step(300)
        with twin.lock:
            start = twin.data.qpos[:7].copy()
        for k in range(40):
            with twin.lock:
                twin.data.qpos[:7] = start
                twin.data.qpos[0] += 0.01 * k
                twin.data.time = 0.3 + k / camera.fps
            pos, quat = twin.body_pose()
            body = m.BodyState(stamp=twin.time, position=pos.tolist(), orientation=quat.tolist())
            role.on_body(body)
            record(body)
            frame = twin.depth_frame(camera.name)
            depth = np.ascontiguousarray(frame.depth, dtype="<u2")
            image = m.DepthImage(
                stamp=frame.timestamp,
                camera=camera.name,
                width=depth.shape[1],
                height=depth.shape[0],
                depth_scale=frame.depth_scale,
                depth=depth.tobytes(),
            )
            record(image)
            role.perceive(frame_of(image, camera), plugins, published.append)
        for message in published:
            record(message)
    finally:
        twin.stop()
        sink.close()
    return published


def test_maps_rebuilt_from_a_recording_match_the_live_ones(tmp_path: Path):
    recording = tmp_path / "run.mcap"
    published = _record_live_run(recording)
    assert sum(isinstance(x, m.TerrainMap) for x in published) >= 4

    rebuilt, live = rebuild(recording, load(PROFILE))
    pair = last_pair(rebuilt, live)
    assert pair is not None, "a rebuilt map for a frame the live role mapped"
    agreement = compare(*pair)
    assert agreement.both >= 2000, agreement
    assert agreement.within == agreement.both, agreement
    assert agreement.both == agreement.live_cells == agreement.rebuilt_cells, agreement

    cli = subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "rebuild",
            str(recording),
            "--profile",
            str(PROFILE),
            "-o",
            str(tmp_path / "re.mcap"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert cli.returncode == 0, cli.stderr
    share = re.search(r"([0-9.]+)% within 1 mm", cli.stdout)
    assert share and float(share.group(1)) == 100.0, cli.stdout
    assert (tmp_path / "re.mcap").stat().st_size > 0
