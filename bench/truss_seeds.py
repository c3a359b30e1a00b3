"""How often the truss modeller (paper 003) models the paper's 5- and 7-member scenes well,
over seeds: each seed renders both scenes at Kinect-2 resolution with ``DepthNoise()`` and
draws 100 000 points from each, as ``bench/truss.py``'s main table does at its ``--seed``
(which is its seed 0 here), and models them with that seed.

A run is good when every member is found, none is false and the worst relative length error
is within 2 %; runs between 2 and 5 % and beyond 5 % are counted apart (a tube end short of
an overhang, against a member cut or tilted). Prints per scene the counts, the median and
worst of the worst-member errors, and each run beyond 2 %. For another revision's modeller,
put its tree first on ``PYTHONPATH`` (``git worktree add /tmp/old/climbd REV``, then
``PYTHONPATH=/tmp/old``).

    .venv/bin/python bench/truss_seeds.py [--seeds 40]
"""

from __future__ import annotations

import argparse

import numpy as np

import climbd
from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
from climbd.plugins.perception.truss.evaluate import evaluate

POINTS = 100_000
SCENES = (("5 members", ts.five_member), ("7 members", ts.seven_member))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40, help="seeds 0 .. N-1")
    args = parser.parse_args()
    print(f"modeller from {climbd.__file__}")
    worst: dict[str, list[float]] = {name: [] for name, _ in SCENES}
    bad: dict[str, int] = {name: 0 for name, _ in SCENES}
    lines = []
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        modeller = TrussModeller(TrussConfig(seed=seed))
        for name, build in SCENES:
            scene = ts.render(build(), seed=seed)
            cloud = scene.cloud[rng.choice(len(scene.cloud), POINTS, replace=False)]
            found = [(m.p0, m.p1) for m in modeller.model(cloud).members]
            accuracy = evaluate(found, [(t.p0, t.p1, t.radius) for t in scene.members])
            if not accuracy.all_found or accuracy.false_members:
                bad[name] += 1
                lines.append(
                    f"seed {seed}, {name}: found {accuracy.found}/{len(scene.members)}, "
                    f"{accuracy.false_members} false"
                )
                continue
            error = accuracy.max("relative_length_error")
            worst[name].append(error)
            if error > 0.02:
                lines.append(f"seed {seed}, {name}: worst member {100 * error:.2f} %")
    print(
        "| scene | seeds | all found, none false, worst <= 2 % | 2-5 % | > 5 % "
        "| missed or false | worst member median % | max % |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, _ in SCENES:
        errors = np.array(worst[name])
        print(
            f"| {name} | {args.seeds} | {(errors <= 0.02).sum()} "
            f"| {((errors > 0.02) & (errors <= 0.05)).sum()} | {(errors > 0.05).sum()} "
            f"| {bad[name]} | {100 * np.median(errors):.2f} | {100 * errors.max():.2f} |"
        )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
