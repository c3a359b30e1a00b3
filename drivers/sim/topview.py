"""Top-view PNG of a twin world: obstacles, the robot's path and detected joists (no display).

``render_top_view(world, path, "out.png", detected=[((x0, y0), (x1, y1)), ...])`` draws the
world's joists and stairs as footprints shaded by height, the holds slope and truss members,
the path (world frame, m) from start to end, and detected joist lines dashed on top.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from climbd.drivers.sim.worlds import World, holds_heightfield, yaw_matrix

Segment = tuple[Sequence[float], Sequence[float]]


def _footprint(cx: float, cy: float, length: float, width: float, yaw_deg: float) -> np.ndarray:
    """Corners (5×2, closed) of a rectangle of ``length`` along x and ``width`` along y."""
    half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * [length / 2, width / 2]
    return half @ yaw_matrix(yaw_deg).T + [cx, cy]


def render_top_view(
    world: World,
    path: np.ndarray,
    png: str | Path,
    detected: Sequence[Segment] = (),
    title: str = "",
) -> Path:
    """Write the top view to ``png`` and return its path; ``path`` is N×2 (or N×3) in metres."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm
    from matplotlib.colors import Normalize

    path = np.asarray(path, float).reshape(-1, np.shape(path)[-1] if np.size(path) else 2)
    fig, ax = plt.subplots(figsize=(8, 6), dpi=100)
    ax.set_facecolor(np.array(world.floor.rgba[:3]) * 0.6 + 0.4)
    heights = [r.height for r in world.joists] + [s.rise * s.count for s in world.stairs]
    norm = Normalize(0.0, max(heights, default=0.2))
    colours = matplotlib.colormaps["copper_r"]
    for row in world.joists:
        rot = yaw_matrix(row.yaw_deg)
        for k in range(row.count):
            cx, cy = np.array([row.distance, row.offset]) + rot @ [k * row.spacing, 0.0]
            box = _footprint(cx, cy, row.width, row.length, row.yaw_deg)
            ax.fill(box[:, 0], box[:, 1], color=colours(norm(row.height)), zorder=2)
        ax.annotate(
            f"{row.height * 100:.0f} cm",
            (row.distance, row.offset + row.length / 2),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    for st in world.stairs:
        rot = yaw_matrix(st.yaw_deg)
        for k in range(st.count):
            depth = st.tread if k < st.count - 1 else st.landing
            cx, cy = rot @ [st.distance + k * st.tread + depth / 2, 0.0]
            box = _footprint(cx, cy, depth, st.width, st.yaw_deg)
            ax.fill(box[:, 0], box[:, 1], color=colours(norm((k + 1) * st.rise)), zorder=2 + k)
            ax.plot(box[:, 0], box[:, 1], color="k", lw=0.5, zorder=2 + k)
    if world.holds is not None:
        h = world.holds
        base = Path(world.source).parent if world.source else Path.cwd()
        relief, length, width = holds_heightfield(h, base)
        run = length * math.cos(math.radians(h.incline_deg))
        ax.imshow(
            relief.T,
            extent=(h.distance, h.distance + run, -width / 2, width / 2),
            origin="lower",
            cmap="copper",
            alpha=0.8,
            zorder=1,
        )
        ax.annotate(
            f"holds, {h.incline_deg:.0f}° up +x", (h.distance + 0.05, width / 2), fontsize=8
        )
    if world.truss is not None:
        nodes = np.asarray(world.truss.nodes, float)
        for m in world.truss.members:
            ax.plot(*nodes[[m.a, m.b], :2].T, color="0.3", lw=3, zorder=3)
        ax.scatter(*nodes[:, :2].T, marker="s", color="0.2", zorder=4)
    if len(path):
        ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=2, zorder=5, label="robot path")
        ax.scatter(*path[0, :2], color="tab:green", zorder=6, label="start")
        ax.scatter(*path[-1, :2], color="tab:red", marker="x", s=60, zorder=6, label="end")
    for i, (a, b) in enumerate(detected):
        ax.plot(
            [a[0], b[0]],
            [a[1], b[1]],
            "--",
            color="tab:red",
            lw=1.5,
            zorder=7,
            label="detected joist" if i == 0 else None,
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")
    ax.set_title(title or f"world {world.name}: top view")
    ax.grid(True, alpha=0.3)
    fig.colorbar(cm.ScalarMappable(norm=norm, cmap=colours), ax=ax, label="height (m)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right", fontsize=8)
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)
    plt.close(fig)
    return png
