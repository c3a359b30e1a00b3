"""Paper 001 §4 in the twin: non-periodic vs periodic free climbing on the hold-map slope.

HubRobo in the MuJoCo twin on ``slope_map`` (30° board, G/6, one hold per graspable point of a
map tiled from the detection on ClimbLab's real cloud, seeded), base height 0.06 m, swing 4 s
and 0.02 m, grippers holding only on holds and slipping above 9 N. Each seed runs every gait
for ``--seconds`` of simulated time, the default planner told that time (``duration``); the
periodic gait ([9]) is the baseline and the table gives the non-periodic / periodic ratio of
the base's travel up the slope (twin truth), the least TSM of the grippers that held (twin
truth), slips, grips that never engaged, and the planner's own (kinematic) travel beside the
twin's, the base's mean advance per swing beside the room the three stance legs leave it (how
far up the slope it could go with them in reach and TSM >= 0), the same figures for the
non-periodic gait with the paper's own limb rule
(``limb_rule = "paper"``: the limb with the most graspable options ahead, its longest feasible
stride, §3.1-3.3) as a third gait, the default search open-ended (``duration = 0``: it is not
told when the run ends, so every plan looks its full horizon ahead) as a fourth, how
far a beam search (beam 400) that knows when the run ends gets on the same map with the
default planner's steps (kinematic: the most a better choice of swings could reach), and the
CPU time of the non-periodic plans (worker thread; search and paper rule) beside that of the
runner's ticks (control thread, which no longer plans). Figure (paper Figs. 7 and 8): base x
and TSM over time for the four gaits, every seed. Goal (#36): the default planner's mean
distance ≥ 0.17 m and ≥ 2× the periodic gait's (the protocol: seeds 0-7, fixed before
looking at results; the ratio of mean distances over all of them), its plan ≥ 0.9 of the
bound on every map, TSM never below 0, no slips.

    .venv/bin/python bench/free_climb.py [--seeds 8] [--seconds 45] [--jobs 2]
        [--plot docs/img/free_climb.png]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.climb_run import ClimbLog, SlopeClimb, search_reach  # noqa: E402

from climbd.plugins.gaits.free_climb import (
    GOAL,
    NORMAL,
    ClimbConfig,
    ClimbPlanner,
    Step,
)
from climbd.plugins.gaits.tsm import tumble_stability_margins

ROOT = Path(__file__).resolve().parent.parent


class ThreadCpu:
    """CPU time (s) of each call of the functions it wraps, on the thread that runs the call
    (a tick's own work, not the worker's planning it may wait for)."""

    def __init__(self) -> None:
        self.samples: list[float] = []

    def wrap(self, function):
        """``function`` timed by ``time.thread_time``."""

        def timed(*args):
            t0 = time.thread_time()
            try:
                return function(*args)
            finally:
                self.samples.append(time.thread_time() - t0)

        return timed


@dataclass
class Run:
    """One climb: the twin's log, the planner's own travel (m: where its swings put the base,
    the swing under way at the end counted whole, as the bound counts its swings), per-swing
    base advance and
    room (m, ``swing_room``), the wall time (s) and the CPU time of the runner's ticks (control
    thread) and of the plans (worker thread)."""

    log: ClimbLog
    planned: float
    swings: np.ndarray
    wall: float
    ticks: ThreadCpu
    plans: ThreadCpu


GAITS = {
    "np": (False, {"duration": None}),
    "p": (True, {}),
    "paper": (False, {"limb_rule": "paper"}),
    "open": (False, {}),
}
"""The gaits compared: (periodic, ClimbConfig overrides) by column label: the non-periodic
search (the default planner, told the run's length: ``duration`` None stands for the run's
seconds), the periodic baseline, the non-periodic gait with the paper's own limb rule, and the
default search open-ended (not told when the run ends)."""
NAMES = {"np": "non-periodic", "p": "periodic", "paper": "paper rule", "open": "np open-ended"}


def run(periodic: bool, seed: int, seconds: float, overrides: dict | None = None) -> Run:
    """Climb map ``seed`` with one gait (``overrides`` of its ClimbConfig) for ``seconds`` in
    the twin."""
    t0 = time.perf_counter()
    climb = SlopeClimb(periodic, seed)
    overrides = {k: seconds if v is None else v for k, v in (overrides or {}).items()}
    climb.config = msgspec.structs.replace(climb.config, **overrides)
    climb.planner.config = climb.config  # before any plan: the runner shares this planner
    ticks, plans = ThreadCpu(), ThreadCpu()
    feet = climb.runner.feet.copy()
    climb.runner.tick = ticks.wrap(climb.runner.tick)
    climb.planner.plan = plans.wrap(climb.planner.plan)
    start = climb.runner.base[0]
    try:
        log = climb.run(seconds)
    finally:
        climb.close()
    wall = time.perf_counter() - t0
    swings = swing_room(climb.planner, feet, climb.runner.steps)
    steps = climb.runner.steps
    planned = float(steps[-1].base_end[0] - start) if steps else 0.0
    return Run(log, planned, swings, wall, ticks, plans)


ROOM = np.arange(0.0, 0.2001, 0.0025)
"""Base advances (m) up the slope at which a swing's room is checked."""


def swing_room(planner: ClimbPlanner, feet: np.ndarray, steps: list[Step]) -> np.ndarray:
    """Per executed swing: (base advance the plan made, room) in m, where room is how far up
    the slope the base could go from where the swing starts with the three stance legs in
    reach (IK within limits) and the TSM of their grips ≥ 0 (paper 001 §3.3 moves it only
    to the diagonals' crossing)."""
    feet = np.array(feet, float)
    rows = []
    for step in steps:
        if step.wait:
            continue
        stance = np.delete(np.arange(len(feet)), step.limb)
        bases = step.base_start + ROOM[:, None] * GOAL
        reach = planner.reach(feet[:, None, :] - bases[None, :, :])[stance].all(axis=0)
        tsm = tumble_stability_margins(
            bases, feet[stance], planner.force, planner.config.grip_force, NORMAL
        )
        blocked = np.flatnonzero(~(reach & (tsm >= 0.0)))
        room = ROOM[blocked[0] - 1] if len(blocked) and blocked[0] > 0 else ROOM[-1]
        room = 0.0 if len(blocked) and blocked[0] == 0 else room
        rows.append(((step.base_end - step.base_start) @ GOAL, room))
        feet[step.limb] = step.target
    return np.array(rows).reshape(-1, 2)


def climb_map(seed: int, seconds: float) -> tuple[dict[str, Run], float]:
    """Every gait's climb of map ``seed`` and the bound of the search that knows the end."""
    runs = {g: run(periodic, seed, seconds, over) for g, (periodic, over) in GAITS.items()}
    return runs, search_reach(seed, int(seconds // ClimbConfig().swing_period))


def plot(logs: dict[str, list[ClimbLog]], path: Path) -> None:
    """Base x and TSM over time for the three gaits (paper 001 Figs. 7 and 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_x, ax_tsm) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    colours = {"np": "tab:red", "p": "tab:blue", "paper": "tab:green", "open": "tab:orange"}
    for gait, colour in colours.items():
        label = NAMES[gait]
        for k, log in enumerate(logs[gait]):
            x = np.asarray(log.x) - log.x[0]
            ax_x.plot(log.t, x, color=colour, lw=0.8, label=label if k == 0 else None)
            ax_tsm.plot(log.t, log.tsm, color=colour, lw=0.6, label=label if k == 0 else None)
    ax_x.set_ylabel("base x up the slope (m)")
    ax_x.legend(loc="upper left")
    ax_tsm.axhline(0.0, color="k", lw=0.5)
    ax_tsm.set_ylabel("TSM (m)")
    ax_tsm.set_xlabel("time (s)")
    ax_x.set_title("HubRobo twin, 30° slope, G/6, hold maps from the real cloud (one line/seed)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


def per_gait(values: dict[str, float], fmt: str) -> str:
    """``values`` of the gaits as "np / p / paper / open" with ``fmt``."""
    return " / ".join(format(values[g], fmt) for g in GAITS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=45.0)
    parser.add_argument("--plot", type=Path, default=ROOT / "docs" / "img" / "free_climb.png")
    parser.add_argument("--jobs", type=int, default=1, help="maps climbed at once (processes)")
    args = parser.parse_args()
    logs: dict[str, list[ClimbLog]] = {g: [] for g in GAITS}
    swings: dict[str, list[np.ndarray]] = {g: [] for g in GAITS}
    reaches: list[tuple[float, float]] = []
    labels = " / ".join(GAITS)
    print(
        f"| seed | non-periodic (m) | periodic (m) | paper rule (m) | np open-ended (m)"
        f" | ratio np / paper / open to p | planned {labels} (m)"
        f" | base per swing {labels} (cm) | room per swing {labels} (cm)"
        f" | least TSM {labels} (m) | slips {labels} | missed grips {labels}"
        f" | periodic waits | wall s {labels} | search (m) | np / search"
        " | plan CPU median / max np, paper (ms) | tick CPU max np / paper (ms) |"
    )
    print("|---" * 19 + "|")
    worst_plan = worst_tick = 0.0
    seeds = range(args.seeds)
    with ProcessPoolExecutor(args.jobs) as pool:
        climbed = pool.map(climb_map, seeds, [args.seconds] * len(seeds))
    for seed, (runs, reach) in zip(seeds, climbed, strict=True):
        plan_ms = {g: 1e3 * np.asarray(runs[g].plans.samples) for g in ("np", "paper")}
        tick_ms = {g: 1e3 * max(runs[g].ticks.samples) for g in ("np", "paper")}
        worst_plan = max(worst_plan, plan_ms["np"].max())
        worst_tick = max(worst_tick, tick_ms["np"])
        for g, one in runs.items():
            logs[g].append(one.log)
            swings[g].append(one.swings)
        dist = {g: one.log.distance for g, one in runs.items()}
        ratio = " / ".join(
            f"{dist[g] / dist['p']:.2f}" if dist["p"] > 0 else "inf"
            for g in ("np", "paper", "open")
        )
        reaches.append((reach, runs["p"].planned, runs["np"].planned, runs["open"].planned))
        per_swing = {g: 100 * one.swings.mean(axis=0) for g, one in runs.items()}
        cpu = ", ".join(
            f"{np.median(plan_ms[g]):.0f} / {plan_ms[g].max():.0f}" for g in ("np", "paper")
        )
        print(
            f"| {seed} | {dist['np']:.3f} | {dist['p']:.3f} | {dist['paper']:.3f} "
            f"| {dist['open']:.3f} | {ratio} "
            f"| {per_gait({g: one.planned for g, one in runs.items()}, '.3f')} "
            f"| {per_gait({g: v[0] for g, v in per_swing.items()}, '.1f')} "
            f"| {per_gait({g: v[1] for g, v in per_swing.items()}, '.1f')} "
            f"| {per_gait({g: min(one.log.tsm) for g, one in runs.items()}, '.3f')} "
            f"| {per_gait({g: one.log.slips for g, one in runs.items()}, 'd')} "
            f"| {per_gait({g: one.log.missed for g, one in runs.items()}, 'd')} "
            f"| {runs['p'].log.waits} "
            f"| {per_gait({g: one.wall for g, one in runs.items()}, '.0f')} | {reach:.3f} "
            f"| {runs['np'].planned / reach:.2f} "
            f"| {cpu} | {tick_ms['np']:.1f} / {tick_ms['paper']:.1f} |",
            flush=True,
        )
    mean = {g: float(np.mean([log.distance for log in logs[g]])) for g in GAITS}
    least = {g: min(min(log.tsm) for log in logs[g]) for g in GAITS}
    slips = {g: sum(log.slips for log in logs[g]) for g in GAITS}
    rows = {g: 100 * np.vstack(swings[g]).mean(axis=0) for g in GAITS}
    ratios = " / ".join(f"{mean[g] / mean['p']:.2f}" for g in ("np", "paper", "open"))
    print(
        f"| mean | {mean['np']:.3f} | {mean['p']:.3f} | {mean['paper']:.3f} "
        f"| {mean['open']:.3f} | {ratios} "
        f"| | {per_gait({g: v[0] for g, v in rows.items()}, '.1f')} "
        f"| {per_gait({g: v[1] for g, v in rows.items()}, '.1f')} "
        f"| {per_gait(least, '.3f')} | {per_gait(slips, 'd')} total | | | | | | | |"
    )
    for g in GAITS:
        rows = np.vstack(swings[g])
        print(
            f"\n{NAMES[g]}: base advance per swing {100 * rows[:, 0].mean():.1f} cm mean, room "
            f"for the stance legs {100 * rows[:, 1].mean():.1f} cm mean (least "
            f"{100 * rows[:, 1].min():.1f} cm); advance > room in "
            f"{int((rows[:, 0] > rows[:, 1] + 1e-9).sum())} of {len(rows)} swings"
        )
    print(
        f"\nplanning off the tick: worst plan {worst_plan:.0f} ms CPU on the worker, worst tick "
        f"{worst_tick:.1f} ms CPU on the control thread ({worst_plan / worst_tick:.0f}x less)"
    )
    reach, per_plan, np_plan, open_plan = np.mean(reaches, axis=0)
    worst_share = min(np_p / bound for bound, _, np_p, _ in reaches)
    open_worst = min(open_p / bound for bound, _, _, open_p in reaches)
    print(
        f"\nsearch knowing the end (beam 400): {reach:.3f} m mean, "
        f"{reach / per_plan:.2f}x the periodic gait's planned {per_plan:.3f} m; the "
        f"non-periodic gait's plan reaches {np_plan / reach:.2f} of it on the mean, "
        f"{worst_share:.2f} on its worst map; open-ended {open_plan / reach:.2f} on the mean, "
        f"{open_worst:.2f} on its worst map"
    )
    free_mean, per_mean = mean["np"], mean["p"]
    met = (
        free_mean >= 0.17
        and free_mean >= 2 * per_mean
        and worst_share >= 0.9
        and least["np"] >= 0
        and slips["np"] == 0
    )
    print(
        f"\ngoal (#36: mean >= 0.17 m and >= 2x periodic, >= 0.9 of the bound on every map, "
        f"TSM >= 0, no slips): {'met' if met else 'NOT met'}; mean {free_mean:.3f} m, ratio "
        f"{free_mean / per_mean:.2f}, worst share of the bound {worst_share:.2f}, least TSM "
        f"{least['np']:.3f} m, slips {slips['np']}; "
        f"paper rule / periodic {mean['paper'] / per_mean:.2f}; "
        f"open-ended / periodic {mean['open'] / per_mean:.2f}"
    )
    plot(logs, args.plot)
    print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()
