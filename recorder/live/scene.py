"""The team as Foxglove's typed messages: the ``SceneUpdate`` and the agents' ``FrameTransforms``.

Edges are coloured by link health at the epoch (docs/model.md §4): green when healthy,
red when not, grey when the recorder has no estimate for the epoch; edges of the
leader's minimum spanning tree are drawn thicker and gold. A directed link whose packet
of the epoch netem did not deliver in time is drawn red on its sender's half of the edge.
The leader's estimates are small violet spheres with their 2σ covariance ellipse (the
x–y block in 3-D). The desired shape, anchored at the leader, is drawn as thin
translucent lines. A unicycle's heading is an arrow from its position. An agent out of the
team at the epoch (not yet joined, left, crashed, lost) is a translucent grey sphere labelled
``<i> out`` where its body was last seen, its edges translucent grey, and the entity's ``out``
metadata lists the ids. Past ``LABELLED_MAX`` agents only the leader and the agents out are
labelled, and a sphere is never wider than half the median edge. Pure: arrays in,
the SDK's messages (``foxglove.messages``) out; ``.encode()`` gives the recorded protobuf.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import numpy.typing as npt
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    FrameTransform,
    FrameTransforms,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)

FRAME = "world"
RGBA = tuple[float, float, float, float]
LEADER_COLOR: RGBA = (1.0, 0.55, 0.0, 1.0)
AGENT_COLOR: RGBA = (0.12, 0.47, 0.71, 1.0)
HEALTHY: RGBA = (0.17, 0.63, 0.17, 1.0)
BROKEN: RGBA = (0.84, 0.15, 0.16, 1.0)
UNKNOWN: RGBA = (0.6, 0.6, 0.6, 1.0)
TREE: RGBA = (1.0, 0.84, 0.0, 1.0)
SHAPE: RGBA = (0.5, 0.5, 0.5, 0.35)
LOST: RGBA = (0.84, 0.15, 0.16, 1.0)
ESTIMATE: RGBA = (0.58, 0.4, 0.74, 0.8)
HEADING: RGBA = (1.0, 1.0, 1.0, 0.9)
LABEL: RGBA = (1.0, 1.0, 1.0, 1.0)
OUT: RGBA = (0.6, 0.6, 0.6, 0.3)  # an agent out of the team, and its edges
ROBOT: RGBA = (0.1, 0.85, 0.85, 0.9)  # a robot's measured pose, beside its agent's state
ROBOT_SIZE_M = 0.12
ELLIPSE_POINTS = 24
LABELLED_MAX = 200  # larger teams label only the leader and the agents out
SIGMAS = 2.0  # the ellipse drawn: x̂ + 2σ


def timestamp(stamp_ns: int) -> Timestamp:
    """``stamp_ns`` [ns] as a ``foxglove.Timestamp``."""
    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _xyz(p: npt.NDArray[np.float64] | Sequence[float]) -> tuple[float, float, float]:
    """A point of dimension 2 or 3 in 3-D (z = 0 in the plane)."""
    return float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 0.0


def _point(p: npt.NDArray[np.float64]) -> Point3:
    x, y, z = _xyz(p)
    return Point3(x=x, y=y, z=z)


def _xyzs(rows: npt.NDArray[np.float64]) -> Iterator[tuple[float, float, float]]:
    """:func:`_xyz` of each row of ``rows`` (m, d), from flat lists (see :func:`ellipses`)."""
    z = rows[:, 2].tolist() if rows.shape[1] > 2 else [0.0] * len(rows)
    return zip(rows[:, 0].tolist(), rows[:, 1].tolist(), z, strict=True)


def _points(rows: npt.NDArray[np.float64]) -> list[Point3]:
    """:func:`_point` of each row of ``rows`` (m, d)."""
    return [Point3(x=x, y=y, z=z) for x, y, z in _xyzs(rows)]


def _poses(rows: npt.NDArray[np.float64]) -> list[Pose]:
    """:func:`_pose` of each row of ``rows`` (m, d), unturned."""
    turn = _identity()
    return [Pose(position=Vector3(x=x, y=y, z=z), orientation=turn) for x, y, z in _xyzs(rows)]


def _color(c: RGBA) -> Color:
    return Color(r=c[0], g=c[1], b=c[2], a=c[3])


def _identity() -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _pose(
    p: npt.NDArray[np.float64] | Sequence[float] | None = None, yaw: float | None = None
) -> Pose:
    """At ``p`` (the origin if None), turned by ``yaw`` [rad] about z (none if None)."""
    x, y, z = (0.0, 0.0, 0.0) if p is None else _xyz(p)
    turn = (
        _identity()
        if yaw is None
        else Quaternion(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))
    )
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=turn)


def _lines(
    points: list[Point3],
    color: RGBA,
    thickness: float,
    kind: LinePrimitiveLineType = LinePrimitiveLineType.LineList,
) -> LinePrimitive:
    return LinePrimitive(
        type=kind,
        pose=_pose(),
        thickness=thickness,
        scale_invariant=True,
        points=points,
        color=_color(color),
    )


def entity(
    entity_id: str,
    stamp_ns: int,
    epoch: int,
    *,
    spheres: list[SpherePrimitive] | None = None,
    lines: list[LinePrimitive] | None = None,
    texts: list[TextPrimitive] | None = None,
    arrows: list[ArrowPrimitive] | None = None,
    out: Sequence[int] = (),
) -> SceneEntity:
    """A ``foxglove.SceneEntity`` in :data:`FRAME`, its epoch (and the agents ``out``) as metadata."""
    metadata = [KeyValuePair(key="epoch", value=str(epoch))]
    if len(out):
        metadata.append(KeyValuePair(key="out", value=",".join(str(i) for i in out)))
    return SceneEntity(
        timestamp=timestamp(stamp_ns),
        frame_id=FRAME,
        id=entity_id,
        metadata=metadata,
        spheres=spheres,
        lines=lines,
        texts=texts,
        arrows=arrows,
    )


def edge_colors(
    healthy: npt.NDArray[np.bool_] | None, tree: npt.NDArray[np.bool_] | None, m: int
) -> list[RGBA]:
    """Colour of each of ``m`` edges: tree gold, healthy green, broken red, unknown grey."""
    if healthy is None:
        return [UNKNOWN] * m
    in_tree = np.zeros(m, dtype=bool) if tree is None else tree
    return [
        TREE if t else (HEALTHY if h else BROKEN) for h, t in zip(healthy, in_tree, strict=True)
    ]


def scene_update(
    epoch: int,
    stamp_ns: int,
    positions: npt.NDArray[np.float64],
    edges: npt.NDArray[np.int64],
    offsets: npt.NDArray[np.float64],
    leader: int,
    healthy: npt.NDArray[np.bool_] | None = None,
    tree: npt.NDArray[np.bool_] | None = None,
    lost: list[tuple[int, int]] | None = None,
    estimates: list[list[float] | None] | None = None,
    covariances: list[list[list[float]] | None] | None = None,
    headings: npt.NDArray[np.float64] | None = None,
    out: npt.NDArray[np.bool_] | None = None,
) -> SceneUpdate:
    """The scene of one epoch.

    Parameters
    ----------
    positions : (n, d) array [m]
        True positions ``x_i[k]``; row ``i − 1`` is agent ``i``.
    edges : (m, 2) array of agent ids
    offsets : (n, d) array [m]
        The shape ``d0``; drawn anchored at the leader's position.
    leader : the reference agent's id
    healthy, tree : (m,) bool arrays or None
        Link health and MST membership of each edge at this epoch (docs/model.md §4).
    headings : (n,) array [rad] or None
        Unicycles' headings ``θ_i[k]`` in the x–y plane, drawn as arrows (NaN: not drawn).
    out : (n,) bool array or None
        Agents out of the team at this epoch; ``positions`` holds where their bodies were.
    """
    n = positions.shape[0]
    away = np.zeros(n, dtype=bool) if out is None else out
    span = float(np.ptp(offsets, axis=0).max()) if n > 1 else 1.0
    radius = max(0.04 * span, 1e-3)  # [m], visible at the formation's scale
    if edges.shape[0]:  # but no larger than a quarter of the typical neighbour distance
        lengths = np.linalg.norm(offsets[edges[:, 0] - 1] - offsets[edges[:, 1] - 1], axis=1)
        radius = max(min(radius, 0.25 * float(np.median(lengths))), 1e-3)
    size = Vector3(x=2 * radius, y=2 * radius, z=2 * radius)
    spheres = []
    texts = []
    gone = away.tolist()
    paint = {c: _color(c) for c in (OUT, LEADER_COLOR, AGENT_COLOR)}  # shared, as ``size``
    for i, pose in enumerate(_poses(positions)):
        color = OUT if gone[i] else LEADER_COLOR if i + 1 == leader else AGENT_COLOR
        spheres.append(SpherePrimitive(pose=pose, size=size, color=paint[color]))
        if n > LABELLED_MAX and not gone[i] and i + 1 != leader:
            continue  # ten thousand labels are a smear: the leader and agents out only
        label = positions[i] + np.r_[radius, radius, 0.0][: positions.shape[1]]
        texts.append(
            TextPrimitive(
                pose=_pose(label),
                billboard=True,
                font_size=14.0,
                scale_invariant=True,
                color=_color(LABEL),
                text=f"{i + 1} out" if gone[i] else str(i + 1),
            )
        )
    colors = edge_colors(healthy, tree, edges.shape[0])
    groups: dict[RGBA, list[Point3]] = {}
    at = _points(positions)
    pairs = edges.tolist()
    for (i, j), color in zip(pairs, colors, strict=True):
        color = OUT if gone[i - 1] or gone[j - 1] else color
        groups.setdefault(color, []).extend((at[i - 1], at[j - 1]))
    lines = [
        _lines(pts, c, 4.0 if c == TREE else 1.0 if c == OUT else 2.0) for c, pts in groups.items()
    ]
    shape = _points(positions[leader - 1] - offsets[leader - 1] + offsets)
    shape_pts: list[Point3] = []
    for i, j in pairs:
        shape_pts += [shape[i - 1], shape[j - 1]]
    if shape_pts:
        lines.append(_lines(shape_pts, SHAPE, 1.0))
    half: list[Point3] = []
    for i, j in sorted(lost or []):
        a, b = positions[i - 1], positions[j - 1]
        half += [_point(a), _point((a + b) / 2)]
    if half:
        lines.append(_lines(half, LOST, 3.0))
    e_size = Vector3(x=radius, y=radius, z=radius)
    ringed: list[tuple[list[float], list[list[float]]]] = []
    for p, c in zip(estimates or [], covariances or [], strict=False):
        if p is None:
            continue
        spheres.append(SpherePrimitive(pose=_pose(p), size=e_size, color=_color(ESTIMATE)))
        if c is not None:
            ringed.append((p, c))
    for ring in _rings(ringed):
        if ring:
            lines.append(_lines(ring, ESTIMATE, 1.0, LinePrimitiveLineType.LineLoop))
    arrows = (
        []
        if headings is None
        else heading_arrows(positions, np.where(away, np.nan, headings), radius)
    )
    ids = [int(i) + 1 for i in np.flatnonzero(away)]
    team = entity(
        "formation",
        stamp_ns,
        epoch,
        spheres=spheres,
        lines=lines,
        texts=texts,
        arrows=arrows,
        out=ids,
    )
    return SceneUpdate(entities=[team])


def robot_entity(i: int, epoch: int, point: Sequence[float], stamp_ns: int) -> SceneUpdate:
    """Robot ``i``'s measured pose ``point`` [m] of ``epoch``: entity ``robot <i>``, a cyan
    sphere labelled ``robot <i>``, drawn beside its agent's state."""
    size = Vector3(x=ROBOT_SIZE_M, y=ROBOT_SIZE_M, z=ROBOT_SIZE_M)
    where = _pose(np.asarray(point, dtype=float))
    label = TextPrimitive(
        pose=where,
        billboard=True,
        font_size=12.0,
        scale_invariant=True,
        color=_color(ROBOT),
        text=f"robot {i}",
    )
    robot = entity(
        f"robot {i}",
        stamp_ns,
        epoch,
        spheres=[SpherePrimitive(pose=where, size=size, color=_color(ROBOT))],
        texts=[label],
    )
    return SceneUpdate(entities=[robot])


def heading_arrows(
    positions: npt.NDArray[np.float64], headings: npt.NDArray[np.float64], radius: float
) -> list[ArrowPrimitive]:
    """``foxglove.ArrowPrimitive`` per agent: from ``positions`` (n, d) [m] along ``headings``
    (n,) [rad], a yaw about z (an arrow points along its pose's +x)."""
    return [
        ArrowPrimitive(
            pose=_pose(p, float(th)),
            shaft_length=3.0 * radius,
            shaft_diameter=0.4 * radius,
            head_length=1.5 * radius,
            head_diameter=1.0 * radius,
            color=_color(HEADING),
        )
        for p, th in zip(positions, headings, strict=True)
        if np.isfinite(th)
    ]


def ellipse(centre: npt.NDArray[np.float64], cov: npt.NDArray[np.float64]) -> list[Point3]:
    """Points of the ``SIGMAS``-σ ellipse of the x–y block of ``cov`` around ``centre``."""
    return ellipses(centre[None], cov[None])[0]


def ellipses(
    centres: npt.NDArray[np.float64], covariances: npt.NDArray[np.float64]
) -> list[list[Point3]]:
    """:func:`ellipse` of each row: ``centres`` (m, d) [m], ``covariances`` (m, d, d) [m²];
    no points where the x–y block is not finite."""
    blocks = covariances[:, :2, :2]
    finite = np.isfinite(blocks).all(axis=(1, 2))
    out: list[list[Point3]] = [[] for _ in range(len(centres))]
    if not finite.any():
        return out
    block = blocks[finite]
    values, vectors = np.linalg.eigh((block + np.swapaxes(block, 1, 2)) / 2)
    axes = vectors * (SIGMAS * np.sqrt(np.clip(values, 0.0, None)))[:, None, :]
    t = np.linspace(0.0, 2 * np.pi, ELLIPSE_POINTS, endpoint=False)
    rings = np.swapaxes(axes @ np.stack([np.cos(t), np.sin(t)]), 1, 2)  # (k, points, 2)
    centre = centres[finite]
    xy = centre[:, None, :2] + rings
    z = np.broadcast_to(centre[:, 2:3] if centre.shape[1] > 2 else 0.0, xy.shape[:2])
    # flat lists of floats: nested ones are a list per point for the collector to walk
    xs, ys, zs = (a.ravel().tolist() for a in (xy[..., 0], xy[..., 1], z))
    points = [Point3(x=x, y=y, z=z) for x, y, z in zip(xs, ys, zs, strict=True)]
    for k, r in enumerate(np.flatnonzero(finite).tolist()):
        out[r] = points[k * ELLIPSE_POINTS : (k + 1) * ELLIPSE_POINTS]
    return out


def _rings(ringed: list[tuple[list[float], list[list[float]]]]) -> list[list[Point3]]:
    """The ellipses of (estimate, covariance) pairs, all at once where their shapes agree."""
    if not ringed:
        return []
    try:
        centres = np.array([p for p, _ in ringed], dtype=float)
        covariances = np.array([c for _, c in ringed], dtype=float)
    except ValueError:  # of different dimensions: one by one
        return [ellipse(np.asarray(p, dtype=float), np.asarray(c, dtype=float)) for p, c in ringed]
    return ellipses(centres, covariances)


def agent_frame(i: int) -> str:
    """The frame id of agent ``i`` in :data:`FRAME`."""
    return f"agent{i}"


def frame_transforms(
    positions: npt.NDArray[np.float64] | Sequence[Sequence[float]], stamp_ns: int
) -> FrameTransforms:
    """``agent<i>`` in :data:`FRAME` for each row of ``positions`` (n, d) [m]; z = 0 in the plane."""
    stamp = timestamp(stamp_ns)
    return FrameTransforms(
        transforms=[
            FrameTransform(
                timestamp=stamp,
                parent_frame_id=FRAME,
                child_frame_id=agent_frame(i + 1),
                translation=Vector3(x=x, y=y, z=z),
                rotation=_identity(),
            )
            for i, (x, y, z) in enumerate(_xyz(p) for p in positions)
        ]
    )


__all__ = [
    "FRAME",
    "OUT",
    "agent_frame",
    "edge_colors",
    "ellipse",
    "ellipses",
    "entity",
    "frame_transforms",
    "heading_arrows",
    "robot_entity",
    "scene_update",
    "timestamp",
]
