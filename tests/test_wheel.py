"""The wheel: ``climbd`` is its only top-level package, it carries every module and data file,
and installed (not editable) in a fresh venv, away from the source tree, the ``climbd`` command,
the shipped profiles and every entry point work, with python-daemon's ``daemon`` beside it.

The wheel is built from a clean copy of the source tree (tracked and untracked-but-not-ignored
files): an in-tree build reuses ``build/lib`` and would ship modules deleted since, and would
write ``build/`` and ``climbd.egg-info`` into the repo. The fresh venv gets the wheel with
``--no-deps``; the dev venv's dependencies are made visible by a ``.pth`` path line (which does
not run the dev venv's own ``.pth`` files, so its editable climbd finder stays out).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import sysconfig
import textwrap
import warnings
import zipfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TOP_DIRS = ("daemon", "drivers", "plugins")

STOCK = {
    "climbd.drivers": {"fake", "torque", "torque-bridge", "dynamixel", "realsense"},
    "climbd.perception": {"truss", "elevation", "joists", "graspable", "stairs"},
    "climbd.gaits": {
        "tripod",
        "ripple",
        "wave",
        "crawl",
        "joist_climb",
        "free_climb",
        "periodic_climb",
        "stairs",
    },
}


@dataclass
class Installed:
    wheel: Path
    names: list[str]
    venv: Path
    python: Path
    site: Path
    cwd: Path
    env: dict[str, str]
    daemon_error: str | None  # why python-daemon could not be installed, if it could not


def run(cmd: list, **kw) -> subprocess.CompletedProcess:
    kw.setdefault("timeout", 180)
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)


def source_files() -> list[str]:
    """Files of the working tree that a build sees: tracked or untracked, not ignored."""
    res = run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
    )
    if res.returncode != 0:
        pytest.skip(f"not a git checkout: {res.stderr.strip()}")
    return sorted({p for p in res.stdout.split("\0") if p and (ROOT / p).is_file()})


def pypi_reachable() -> bool:
    try:
        socket.create_connection(("pypi.org", 443), timeout=3).close()
        return True
    except OSError:
        return False


def clean_env() -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")
    }
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1", PYTHONNOUSERSITE="1")
    return env


def build_wheel(src: Path, out: Path, env: dict[str, str]) -> Path:
    """``pip wheel --no-build-isolation`` with the dev venv's setuptools; if that fails (e.g.
    it is older than ``[build-system] requires``), an isolated build, which needs PyPI."""
    base = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", out]
    first = run([*base, "--no-build-isolation", src], cwd=src, env=env)
    if first.returncode != 0:
        if not pypi_reachable():
            pytest.skip(
                "the wheel does not build without isolation with the dev venv's setuptools and "
                f"PyPI is unreachable for an isolated build:\n{first.stderr[-2000:]}"
            )
        why = [ln.strip() for ln in first.stderr.splitlines() if "Error" in ln][:2]
        warnings.warn(
            "the wheel does not build with --no-build-isolation in the dev venv (setuptools "
            f"{metadata.version('setuptools')}; pyproject.toml needs the version in "
            f"[build-system] requires), building isolated instead: {' | '.join(why)}",
            stacklevel=1,
        )
        second = run([*base, src], cwd=src, env=env)
        assert second.returncode == 0, (
            f"wheel build failed\n--- no isolation:\n{first.stderr[-3000:]}"
            f"\n--- isolated:\n{second.stderr[-3000:]}"
        )
    wheels = list(out.glob("climbd-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installed:
    tmp = tmp_path_factory.mktemp("wheel")
    env = clean_env()

    # 1. the wheel, from a clean copy of the source tree
    src = tmp / "src"
    for rel in source_files():
        dest = src / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, dest)
    wheel = build_wheel(src, tmp / "dist", env)
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()

    # 2. a fresh venv (no system site-packages) with the wheel, not editable, no deps
    venv = tmp / "venv"
    res = run([sys.executable, "-m", "venv", venv], env=env)
    assert res.returncode == 0, res.stderr
    python = venv / "bin" / "python"
    res = run([python, "-m", "pip", "install", "--no-deps", wheel], env=env)
    assert res.returncode == 0, res.stderr
    res = run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], env=env)
    site = Path(res.stdout.strip())
    assert site.is_dir() and site.is_relative_to(venv), site

    # python-daemon before the .pth below, so pip sees only this venv
    daemon_error = None
    res = run([python, "-m", "pip", "install", "python-daemon"], env=env)
    if res.returncode != 0:
        daemon_error = res.stderr.strip()[-2000:]
        if not pypi_reachable():
            daemon_error = f"PyPI unreachable (no network?): {daemon_error}"

    # 3. the dev venv's dependencies, by a path line (its own .pth files are not processed)
    dev_site = Path(sysconfig.get_path("purelib"))
    (site / "zz_climbd_dev_deps.pth").write_text(f"{dev_site}\n")

    cwd = tmp / "elsewhere"  # not the repo: the source tree must not be importable
    cwd.mkdir()
    return Installed(wheel, names, venv, python, site, cwd, env, daemon_error)


def in_venv(inst: Installed, *args, **kw) -> subprocess.CompletedProcess:
    return run([*args], cwd=inst.cwd, env=inst.env, **kw)


# --- the wheel's contents -----------------------------------------------------------------


def test_climbd_is_the_only_top_level_package(installed: Installed) -> None:
    tops = {n.split("/", 1)[0] for n in installed.names}
    dist_info = {t for t in tops if t.endswith((".dist-info", ".data"))}
    assert tops - dist_info == {"climbd"}, sorted(tops)
    stray = [n for n in installed.names if n.endswith(".py") and not n.startswith("climbd/")]
    assert not stray, stray
    for bad in (*TOP_DIRS, "tests", "bench"):
        assert not [n for n in installed.names if n.startswith(f"{bad}/")], bad
    assert not [n for n in installed.names if n.startswith(("climbd/tests/", "climbd/bench/"))]
    top_level = [n for n in installed.names if n.endswith(".dist-info/top_level.txt")]
    if top_level:
        with zipfile.ZipFile(installed.wheel) as zf:
            assert zf.read(top_level[0]).decode().split() == ["climbd"]


def test_every_module_and_data_file_is_in_the_wheel(installed: Installed) -> None:
    files = source_files()
    names = set(installed.names)
    under = tuple(f"{d}/" for d in TOP_DIRS)
    modules = [p for p in files if p.endswith(".py") and p.startswith(under)]
    assert len(modules) > 50, "found the source modules"
    missing = [p for p in ["__init__.py", *modules] if f"climbd/{p}" not in names]
    assert not missing, f"source modules missing from the wheel: {missing}"

    data = [
        p
        for p in files
        if (p.startswith("robots/") and p.endswith(".toml"))
        or (p.startswith("systemd/") and p.endswith((".in", ".rules")))
        or (p.startswith("docs/") and p.endswith(".md") and p.count("/") == 1)
        or (p.startswith("drivers/sim/worlds/") and not p.endswith(".py"))
    ]
    assert any(p.startswith("robots/") for p in data)
    assert any(p.startswith("systemd/") and p.endswith(".in") for p in data)
    assert any(p.startswith("drivers/sim/worlds/data/") for p in data)
    missing = [p for p in data if f"climbd/{p}" not in names]
    assert not missing, f"data files missing from the wheel: {missing}"

    # nothing stale: every module shipped has its source
    shipped = [n for n in names if n.startswith("climbd/") and n.endswith(".py")]
    stale = [n for n in shipped if n.removeprefix("climbd/") not in set(files)]
    assert not stale, f"modules in the wheel without a source file: {stale}"


# --- installed, away from the source tree ------------------------------------------------


def test_climbd_is_imported_from_the_fresh_venv(installed: Installed) -> None:
    res = in_venv(
        installed,
        installed.python,
        "-c",
        "import json, sys, climbd, climbd.daemon, numpy;"
        "print(json.dumps([climbd.__file__, climbd.daemon.__file__, sys.prefix,"
        " [type(f).__module__ for f in sys.meta_path]]))",
    )
    assert res.returncode == 0, res.stderr
    climbd_file, daemon_file, prefix, finders = json.loads(res.stdout)
    for f in (climbd_file, daemon_file):
        assert Path(f).is_relative_to(installed.site), f
        assert not Path(f).is_relative_to(ROOT), f
    assert Path(prefix) == installed.venv
    assert not [f for f in finders if "editable" in f], finders


def test_the_climbd_command_and_the_shipped_profiles(installed: Installed) -> None:
    climbd = installed.venv / "bin" / "climbd"
    assert climbd.is_file()
    res = in_venv(installed, climbd, "--help")
    assert res.returncode == 0, res.stderr
    assert "profile" in res.stdout

    profiles = sorted((installed.site / "climbd" / "robots").glob("*.toml"))
    assert profiles, "profiles are installed"
    for profile in profiles:
        res = in_venv(installed, climbd, "profile", "check", profile)
        assert res.returncode == 0, f"{profile.name}:\n{res.stdout}\n{res.stderr}"


LOAD_ENTRY_POINTS = textwrap.dedent(
    """
    import json, sys
    from importlib.metadata import entry_points
    out = {}
    for group in sys.argv[1:]:
        out[group] = {}
        for ep in entry_points(group=group):
            obj = ep.load()
            out[group][ep.name] = [obj.__module__, ep.dist.name if ep.dist else None]
    print(json.dumps(out))
    """
)


def test_every_entry_point_loads_from_the_installed_package(installed: Installed) -> None:
    res = in_venv(installed, installed.python, "-c", LOAD_ENTRY_POINTS, *STOCK)
    assert res.returncode == 0, res.stderr
    loaded = json.loads(res.stdout)
    for group, stock in STOCK.items():
        assert stock <= set(loaded[group]), (group, sorted(loaded[group]))
        for name, (module, _dist) in loaded[group].items():
            assert module.startswith("climbd."), (group, name, module)


def test_python_daemon_beside_climbd(installed: Installed) -> None:
    if installed.daemon_error is not None:
        if "unreachable" in installed.daemon_error:
            pytest.skip(f"python-daemon could not be installed: {installed.daemon_error}")
        pytest.fail(f"pip install python-daemon failed:\n{installed.daemon_error}")
    res = in_venv(
        installed,
        installed.python,
        "-c",
        "import json, daemon, daemon.daemon, climbd, climbd.daemon;"
        "from importlib.metadata import distribution;"
        "files = [str(f.locate().resolve()) for f in distribution('python-daemon').files];"
        "print(json.dumps([daemon.__file__, climbd.daemon.__file__, files,"
        " hasattr(daemon, 'DaemonContext')]))",
    )
    assert res.returncode == 0, res.stderr
    daemon_file, climbd_daemon_file, dist_files, has_context = json.loads(res.stdout)
    assert str(Path(daemon_file).resolve()) in dist_files, daemon_file
    assert Path(daemon_file).is_relative_to(installed.site)
    assert Path(climbd_daemon_file).parent.parent == installed.site / "climbd"
    assert has_context
