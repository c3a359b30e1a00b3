"""``climbd perceive``: a plugin installed through an entry point, run on files and a recording."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from climbd.daemon import cli
from climbd.daemon.contract.cloudio import write_cloud
from climbd.daemon.contract.hardware import mount_extrinsics
from climbd.daemon.contract.profile import load
from climbd.drivers.realsense.models import D435
from climbd.drivers.realsense.software import SoftwareDepthCamera

ROOT = Path(__file__).resolve().parent.parent
WIDOWX = ROOT / "robots" / "widowx.toml"

PLUGIN = '''
"""Test plugin: reports the centroid and the lowest point of the cloud as graspable points."""
import msgspec
import numpy as np
from climbd.daemon.contract.messages import GraspablePoints
from climbd.daemon.algorithms.cloud import CloudPerception


class Config(msgspec.Struct, forbid_unknown_fields=True):
    min_points: int = 1


class Centroid(CloudPerception):
    name = "centroid"
    publishes = (GraspablePoints,)
    Config = Config

    def process_cloud(self, points, body, stamp):
        if len(points) < self.config.min_points:
            return None
        points = np.asarray(points, dtype=np.float64)
        lowest = points[np.argmin(points[:, 2])]
        return GraspablePoints(
            stamp=stamp, frame_stamp=stamp, points=[points.mean(0).tolist(), lowest.tolist()]
        )
'''


@pytest.fixture
def plugin_path(tmp_path, monkeypatch):
    """Install the test plugin as a distribution with a climbd.perception entry point."""
    (tmp_path / "centroid_plugin.py").write_text(textwrap.dedent(PLUGIN))
    info = tmp_path / "centroid_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: centroid-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[climbd.perception]\ncentroid = centroid_plugin:Centroid\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def _perceive(capsys, *argv):
    code = cli.main(["perceive", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, [json.loads(line) for line in out.splitlines()], err


@pytest.fixture
def cloud():
    rng = np.random.default_rng(5)
    return rng.uniform([0.2, -0.5, 0.0], [1.2, 0.5, 0.3], (3000, 3)).astype(np.float32)


@pytest.mark.parametrize(
    "name,encoding",
    [
        ("c.pcd", "ascii"),
        ("c.pcd", "binary"),
        ("c.pcd", "binary_compressed"),
        ("c.ply", "ascii"),
        ("c.ply", "binary"),
        ("c.npy", None),
    ],
)
def test_each_file_format_gives_the_plugins_features(
    plugin_path, tmp_path, capsys, cloud, name, encoding
):
    path = tmp_path / name
    write_cloud(path, cloud, encoding)
    code, lines, err = _perceive(capsys, "centroid", path)
    assert code == 0, err
    assert len(lines) == 1
    np.testing.assert_allclose(lines[0]["points"][0], cloud.astype(np.float64).mean(0), atol=1e-6)
    assert lines[0]["schema"] == 1


def test_camera_frame_cloud_gets_the_profile_mount(plugin_path, tmp_path, capsys):
    t = mount_extrinsics(load(WIDOWX).cameras[0])
    body = np.array([[0.5, 0.1, 0.0], [0.9, -0.2, 0.05], [0.7, 0.0, 0.02]])
    optical = (body - t[:3, 3]) @ t[:3, :3]  # inverse mount: body → optical frame
    write_cloud(tmp_path / "cam.npy", optical)
    code, lines, err = _perceive(
        capsys, "centroid", tmp_path / "cam.npy", "--profile", WIDOWX, "--frame", "camera"
    )
    assert code == 0, err
    np.testing.assert_allclose(lines[0]["points"][0], body.mean(0), atol=1e-9)
    np.testing.assert_allclose(lines[0]["points"][1], body[0], atol=1e-9)
    code, _, err = _perceive(capsys, "centroid", tmp_path / "cam.npy", "--frame", "camera")
    assert code == 1 and "--frame camera needs --profile" in err


def test_recording_gives_one_json_line_per_frame(plugin_path, tmp_path, capsys):
    profile = load(WIDOWX)
    camera_config = profile.cameras[0]
    intrinsics = D435.intrinsics(640, 480)
    bag = tmp_path / "run.bag"
    camera = SoftwareDepthCamera(
        intrinsics, 0.001, mount_extrinsics(camera_config), record_to=bag, queue_size=8
    )
    camera.open()
    depths = [1000, 1500, 2000, 0]
    for k, d in enumerate(depths):
        camera.push(np.full((480, 640), d, np.uint16), 50.0 + k * 0.1)
    camera.close()
    code, lines, err = _perceive(capsys, "centroid", bag, "--profile", WIDOWX)
    assert code == 0, err
    assert len(lines) == len(depths)
    assert lines[-1] is None  # an empty frame: nothing found, still one line
    for k, line in enumerate(lines[:-1]):
        assert line["frame_stamp"] == pytest.approx(50.0 + k * 0.1, abs=1e-6)
        # a wall of constant optical depth d: its centroid lies d metres along the optical axis
        centre = mount_extrinsics(camera_config) @ [0.0, 0.0, depths[k] / 1000, 1.0]
        np.testing.assert_allclose(line["points"][0], centre[:3], atol=0.01)


def test_errors_are_clear_and_exit_1(plugin_path, tmp_path, capsys, cloud):
    bad = tmp_path / "bad.pcd"
    write_cloud(bad, cloud, "binary")
    bad.write_bytes(bad.read_bytes()[:-50])
    code, _, err = _perceive(capsys, "centroid", bad)
    assert code == 1 and f"{bad}: PCD binary data truncated" in err
    code, _, err = _perceive(capsys, "nosuch", bad)
    assert code == 1 and "no plugin named 'nosuch'" in err and "centroid" in err
    code, _, err = _perceive(capsys, "centroid", tmp_path / "run.bag")
    assert code == 1 and "a recording needs --profile" in err


def test_the_installed_command_runs_in_a_fresh_process(plugin_path, tmp_path, cloud):
    write_cloud(tmp_path / "c.pcd", cloud, "binary_compressed")
    env = dict(os.environ, PYTHONPATH=f"{plugin_path}{os.pathsep}{ROOT}")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "perceive",
            "centroid",
            str(tmp_path / "c.pcd"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    line = json.loads(done.stdout)
    np.testing.assert_allclose(line["points"][0], cloud.astype(np.float64).mean(0), atol=1e-6)
