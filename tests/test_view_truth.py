"""The twin's truth beside perception's maps (``climbd view --truth WORLD``).

drivers/sim/truth.py's maps are checked against the geoms the twin compiles for each stock
world (MuJoCo's own positions, sizes and orientations), then drawn on their /truth/ topics in
their own colour, on the schedule of the robot's geometry, and advertised by the view.
"""

from __future__ import annotations

import math
from pathlib import Path

import foxglove
import numpy as np
import pytest
from support.scene_decode import decoded

from climbd.daemon.cli.main import main
from climbd.daemon.cli.view import Viewer
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.runtime import scene
from climbd.drivers.sim.model import build
from climbd.drivers.sim.truth import truth
from climbd.drivers.sim.worlds import load

ROOT = Path(__file__).resolve().parent.parent


def geoms(world_name: str) -> tuple[list, dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The world's truth, and the twin's compiled geoms: name → (position, half sizes, rotation)."""
    world = load(world_name)
    model = build(profiles.load(ROOT / "robots/widowx.toml"), world).model
    out = {}
    for i in range(model.ngeom):
        g = model.geom(i)
        if g.name:
            out[g.name] = (g.pos.copy(), g.size.copy(), rotation(g.quat))
    return truth(world), out


def test_true_joists_are_the_near_top_edges_of_the_twins_joists() -> None:
    (joist_map,), world = geoms("attic_paper")
    boxes = [v for k, v in world.items() if k.startswith("joist")]
    assert isinstance(joist_map, m.JoistMap) and len(joist_map.joists) == len(boxes) >= 2
    for j, (pos, half, r) in zip(joist_map.joists, boxes, strict=True):
        near = [pos + r @ [-half[0], side * half[1], half[2]] for side in (-1, 1)]
        np.testing.assert_allclose(j.endpoints, near, atol=1e-9)
        np.testing.assert_allclose(
            r[:, 0], [math.cos(j.heading), math.sin(j.heading), 0], atol=1e-9
        )
        assert j.height == pytest.approx(2 * half[2]) and j.confidence == 1.0


def test_true_stairs_are_the_nosings_of_the_twins_steps() -> None:
    (stair_map,), world = geoms("stairs")
    boxes = [v for k, v in world.items() if k.startswith("stair")]
    assert isinstance(stair_map, m.StairMap) and len(stair_map.steps) == len(boxes) > 1
    for step, (pos, half, r) in zip(stair_map.steps, boxes, strict=True):
        left, right = (pos + r @ [-half[0], side * half[1], half[2]] for side in (1, -1))
        np.testing.assert_allclose(step.edge, [left, right], atol=1e-9)
        assert step.height == pytest.approx(2 * half[2]) and step.depth == pytest.approx(
            2 * half[0]
        )


def test_true_truss_members_and_holds_are_the_twins() -> None:
    (members,), world = geoms("truss")
    cylinders = [v for k, v in world.items() if k.startswith("member")]
    assert len(members.members) == len(cylinders) > 3
    for member, (pos, half, r) in zip(members.members, cylinders, strict=True):
        ends = sorted(map(tuple, (pos - r[:, 2] * half[1], pos + r[:, 2] * half[1])))
        np.testing.assert_allclose(sorted([tuple(member.p0), tuple(member.p1)]), ends, atol=1e-9)
        assert member.radius == pytest.approx(half[0])
    assert all(len(node.members) >= 2 for node in members.nodes)

    (hold_map,), world = geoms("slope_map")
    columns = [v for k, v in world.items() if k.startswith("hold_")]
    assert len(hold_map.holds) == len(columns) > 10
    for hold, (pos, half, r) in zip(hold_map.holds, columns, strict=True):
        np.testing.assert_allclose(hold.position, pos + r[:, 2] * half[1], atol=1e-9)
    assert truth(load("slope")) == [], "a height-field slope has no discrete holds"


def test_truth_is_drawn_in_its_colour_with_the_geometry_and_advertised_by_the_view() -> None:
    world_truth = truth(load("attic_paper"))
    viewer = Viewer(
        scene.RobotScene(profiles.load(ROOT / "robots/widowx.toml")),
        foxglove.Context(),
        truth=world_truth,
    )
    assert "/truth/joists" not in viewer.channels
    out = dict(viewer.stream.update([], 0, 0.0))
    joists = decoded(out["/truth/joists"])
    assert len(joists["entities"]) == len(world_truth[0].joists)
    (box,) = joists["entities"][0]["cubes"]
    rgba = [box["color"][c] for c in "rgba"]
    assert rgba == pytest.approx(scene.TRUTH_COLOR)
    assert "/truth/joists" not in dict(viewer.stream.update([], 1, 0.5)), "with the geometry"
    assert "/truth/joists" in dict(viewer.stream.update([], 2, 1.0))
    viewer.publish({}, 3, 2.0)
    assert "/truth/joists" in viewer.channels, "advertised once drawn"


def test_view_with_an_unknown_world_says_so(capsys) -> None:
    assert main(["view", "--robot", "widowx", "--truth", "nowhere", "--port", "0"]) == 2
    assert "world 'nowhere': no such file and no stock world" in capsys.readouterr().err
