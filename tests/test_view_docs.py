"""docs/view.md's material: the Foxglove layout names only the scene's topics, and the screenshot
script renders a PNG from a scene recording it makes (``climbd record --scene`` of the
fake-driver robot), decoding it from the file's schemas rather than with climbd's translation.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
from pathlib import Path

from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime import scene

ROOT = Path(__file__).resolve().parent.parent
LAYOUT = ROOT / "docs/foxglove/climbd-layout.json"
SCRIPT = ROOT / "docs/view_screenshot.py"


def panel_ids(node) -> list[str]:
    """The panel ids a layout tree (``layout``) places."""
    if isinstance(node, str):
        return [node]
    return panel_ids(node["first"]) + panel_ids(node["second"])


def topic_of(path: str) -> str:
    """The topic of a Foxglove message path (``/health{role=="control"}.loop.rate_hz``)."""
    return re.match(r"/[^.{\[]*", path).group(0)


def test_layout_is_json_naming_only_the_scenes_topics_and_frames() -> None:
    layout = json.loads(LAYOUT.read_text())
    config = layout["configById"]
    assert sorted(panel_ids(layout["layout"])) == sorted(config), "every panel placed, once"

    topics: set[str] = set()
    kinds = {panel.split("!")[0] for panel in config}
    assert {"3D", "Plot", "StateTransitions", "RawMessages"} <= kinds
    for panel, cfg in config.items():
        kind = panel.split("!")[0]
        if kind == "3D":
            topics |= set(cfg["topics"])
            assert all(t["visible"] for t in cfg["topics"].values())
            frames = scene.RobotScene(profiles.load(ROOT / "robots/widowx.toml")).frames
            assert cfg["followTf"] == scene.BODY and cfg["followTf"] in frames
            for layer in cfg.get("layers", {}).values():
                assert layer.get("frameId", scene.ODOM) in frames
        elif kind in ("Plot", "StateTransitions"):
            topics |= {topic_of(p["value"]) for p in cfg["paths"]}
        elif kind == "RawMessages":
            topics.add(topic_of(cfg["topicPath"]))
    known = set(scene.TOPICS) | set(scene.OPTIONAL_TOPICS)
    assert topics <= known, topics - known
    assert {"/robot", "/joists", "/holds", "/stairs", "/truss", "/health", "/mode"} <= topics
    assert {"/loop", "/estop", "/plan", "/grasp", "/depth"} <= topics
    assert set(scene.TRUTH.values()) <= topics, "the twin's truth shows in the 3-D panel"

    # plotted fields exist in the messages the JSON channels carry
    fields_of = {
        "/health": scene.json_schema(m.Health)["properties"],
        "/loop": scene.json_schema(scene.Loop)["properties"],
        "/estop": scene.json_schema(scene.EStopState)["properties"],
        "/mode": scene.json_schema(m.ModeState)["properties"],
    }
    loop = scene.json_schema(m.Health)["$defs"]["LoopStats"]["properties"]
    plotted = set()
    for cfg in config.values():
        for p in cfg.get("paths", []):
            fields = re.sub(r"\{[^}]*\}", "", p["value"]).split(".")
            plotted.add(fields[0])
            assert fields[1] in fields_of[fields[0]], p["value"]
            if fields[0] == "/health":
                assert fields[1] == "loop" and fields[2] in loop, p["value"]
            else:
                assert len(fields) == 2, p["value"]
    assert {"/loop", "/mode", "/estop"} <= plotted


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_screenshot_script_renders_a_png_from_a_scene_recording(tmp_path: Path) -> None:
    text = SCRIPT.read_text()
    assert "climbd.daemon.runtime" not in text, "decodes the file, not climbd's translation"
    recording, image = tmp_path / "scene.mcap", tmp_path / "view.png"
    made = subprocess.run(
        [sys.executable, str(SCRIPT), "--make", "--seconds", "2", "--keep", str(recording)]
        + ["-o", str(image)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert made.returncode == 0, made.stdout + made.stderr
    assert recording.exists() and "wrote" in made.stdout
    width, height = png_size(image.read_bytes())
    assert (width, height) == (1100, 700)
    assert image.stat().st_size < 300_000

    # the script's reading of the recording: the whole tree and one of each map
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import view_screenshot
    finally:
        sys.path.remove(str(SCRIPT.parent))
    drawn = view_screenshot.read(recording)
    assert {"body", "rf_foot", "camera_front"} <= set(drawn.frames)
    assert drawn.pose("rf_foot") is not None
    assert len(view_screenshot.leg_chains(drawn)) == 6
    for topic in ("/robot", "/joists", "/holds", "/stairs", "/truss"):
        assert drawn.entities[topic], topic
    assert drawn.grid is not None and view_screenshot.grid_polygons(drawn.grid)
    assert drawn.mode is not None and drawn.health is not None

    again = subprocess.run(
        [sys.executable, str(SCRIPT), str(recording), "--at", "1", "-o", str(tmp_path / "a.png")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert again.returncode == 0, again.stderr
    assert png_size((tmp_path / "a.png").read_bytes()) == (1100, 700)
