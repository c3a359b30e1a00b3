"""The house's rules: dependencies point one way (import-linter's contracts in pyproject.toml),
and no module of climbd is imported inside a function except to keep a heavy library out of
the start-up of code that does not need it."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("daemon", "drivers", "plugins")
HEAVY = {"mujoco", "pyrealsense2", "cv2", "open3d", "matplotlib"}
"""Third-party libraries whose import costs a start-up a tenth of a second or more: a command or
role that does not need them should not pay for them."""


def test_import_contracts_are_kept() -> None:
    lint = Path(sys.executable).with_name("lint-imports")
    done = subprocess.run([str(lint)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "0 broken" in done.stdout


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(("climbd", *parts))


def _imports(tree: ast.AST, module: str, is_package: bool) -> list[tuple[ast.AST, str]]:
    """Every import in ``tree`` as (node, absolute module name)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            name = node.module or ""
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([name] if name else []))
            out.append((node, name))
            out += [(node, f"{name}.{alias.name}") for alias in node.names]
    return out


def _top_level(tree: ast.Module) -> set[ast.AST]:
    """Import nodes that run at import time (module level, or under a module-level if/try)."""
    found: set[ast.AST] = set()
    stack: list[ast.AST] = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.add(node)
        elif isinstance(node, (ast.If, ast.Try)):
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue
            stack += node.body + node.orelse
            stack += [s for h in getattr(node, "handlers", []) for s in h.body]
            stack += getattr(node, "finalbody", [])
    return found


def test_no_function_level_import_of_climbd_except_to_defer_a_heavy_library() -> None:
    sources = {_module(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py") if p.is_file()}
    top: dict[str, set[str]] = {}
    inner: list[tuple[str, int, str]] = []
    for module, path in sources.items():
        tree = ast.parse(path.read_text(), str(path))
        at_start = _top_level(tree)
        names = set()
        for node, name in _imports(tree, module, path.name == "__init__.py"):
            if node in at_start:
                names.add(name)
            elif name.startswith("climbd.") and name in sources:
                inner.append((module, node.lineno, name))
        top[module] = names

    def loads_heavy(module: str, seen: set[str]) -> bool:
        if module in seen:
            return False
        seen.add(module)
        for name in top.get(module, ()):
            if name.split(".")[0] in HEAVY:
                return True
            if name in sources and loads_heavy(name, seen):
                return True
        return False

    light = [(m, line, n) for m, line, n in inner if not loads_heavy(n, set())]
    assert not light, "import these at the top of the module:\n" + "\n".join(
        f"{sources[m].relative_to(ROOT)}:{line} {n}" for m, line, n in light
    )
