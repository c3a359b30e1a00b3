"""A twin world's ground truth as the contract's map messages (what perception would map if it
were perfect), for drawing beside what perception did map: ``climbd view --truth WORLD``, and
in a ``climbd run --sim`` run the twin's ``sim/truth`` (``truth_message``), which the view and
``climbd record --scene`` draw by themselves.

Positions are in the world frame, which is the odometry frame of a ``climbd run --sim`` run:
the estimator starts at the twin's body pose (SimHost.estimator_start). Every item has
confidence 1, ``seen`` 0 and age 0. The geometry is the one the twin builds (drivers/sim/model.py):

- joists: each joist's top edge on the side facing the start, its normal pointing away from
  the start (as perception maps an edge it sees from the robot);
- stairs: each step's nosing (left to right facing up the flight), its top, rise and tread
  (the landing's depth for the last);
- holds of a hold map (``[hold_map]``): the top of each hold's column; a height-field slope
  (``[holds]``) has no discrete holds and gives none;
- truss: each member between its nodes, and each node with the members meeting at it.
"""

from __future__ import annotations

import math

import numpy as np

from climbd.daemon.contract.messages import (
    HoldMap,
    JoistMap,
    MappedHold,
    MappedJoist,
    MappedStair,
    Message,
    SimTruth,
    StairMap,
    TrussMember,
    TrussMembers,
    TrussNode,
)
from climbd.drivers.sim.worlds import World, hold_map_holds, wall_pose, yaw_matrix


def joists(world: World) -> JoistMap:
    out = []
    for row in world.joists:
        yaw = math.radians(row.yaw_deg)
        rot = yaw_matrix(row.yaw_deg)
        normal, along = rot @ [1.0, 0.0], rot @ [0.0, 1.0]
        for k in range(row.count):
            centre = np.array([row.distance, row.offset]) + rot @ [k * row.spacing, 0.0]
            edge = centre - normal * row.width / 2
            ends = [edge - along * row.length / 2, edge + along * row.length / 2]
            out.append(
                MappedJoist(
                    id=len(out) + 1,
                    confidence=1.0,
                    seen=0,
                    age=0.0,
                    heading=yaw,
                    offset=float(normal @ edge),
                    height=row.height,
                    endpoints=[[*map(float, p), row.height] for p in ends],
                )
            )
    return JoistMap(joists=out)


def stairs(world: World) -> StairMap:
    out = []
    for st in world.stairs:
        rot = yaw_matrix(st.yaw_deg)
        for k in range(st.count):
            x0 = st.distance + k * st.tread
            top = (k + 1) * st.rise
            left, right = rot @ [x0, st.width / 2], rot @ [x0, -st.width / 2]
            out.append(
                MappedStair(
                    id=len(out) + 1,
                    confidence=1.0,
                    seen=0,
                    age=0.0,
                    height=top,
                    rise=st.rise,
                    depth=st.tread if k < st.count - 1 else st.landing,
                    edge=[[*map(float, left), top], [*map(float, right), top]],
                )
            )
    return StairMap(steps=out)


def holds(world: World) -> HoldMap:
    if world.hold_map is None:
        return HoldMap()
    origin, rotation = wall_pose(world.hold_map)
    tops = origin + hold_map_holds(world) @ rotation.T
    return HoldMap(
        holds=[
            MappedHold(id=i + 1, confidence=1.0, seen=0, age=0.0, position=p.tolist())
            for i, p in enumerate(tops)
        ]
    )


def truss(world: World) -> TrussMembers:
    if world.truss is None:
        return TrussMembers()
    t = world.truss
    nodes = np.asarray(t.nodes, float)
    members = []
    meeting: list[list[int]] = [[] for _ in nodes]
    for i, m in enumerate(t.members):
        p0, p1 = nodes[m.a], nodes[m.b]
        axis = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-12)
        members.append(
            TrussMember(
                p0=p0.tolist(), p1=p1.tolist(), radius=t.radius, axis=axis.tolist(), id=i + 1
            )
        )
        meeting[m.a].append(i + 1)
        meeting[m.b].append(i + 1)
    return TrussMembers(
        members=members,
        nodes=[
            TrussNode(position=p.tolist(), members=ids)
            for p, ids in zip(nodes, meeting, strict=True)
        ],
    )


def truth(world: World) -> list[Message]:
    """The maps of ``world`` that it has: joists, stairs, holds, truss (empty ones left out)."""
    j, s, h, t = joists(world), stairs(world), holds(world), truss(world)
    return [m for m, items in ((j, j.joists), (s, s.steps), (h, h.holds), (t, t.members)) if items]


def truth_message(world: World) -> SimTruth:
    """The ``sim/truth`` message of ``world``: its maps, None for those it has none of."""
    maps = {type(msg): msg for msg in truth(world)}
    return SimTruth(
        world=world.name,
        joists=maps.get(JoistMap),
        stairs=maps.get(StairMap),
        holds=maps.get(HoldMap),
        truss=maps.get(TrussMembers),
    )
