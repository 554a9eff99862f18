"""The team as a ``foxglove.SceneUpdate``: agents as spheres, formation edges as lines.

Edges are coloured by link health at the epoch (docs/model.md §4): green when healthy,
red when not, grey when the recorder has no estimate for the epoch; edges of the
leader's minimum spanning tree are drawn thicker and gold. A directed link whose packet
of the epoch netem did not deliver in time is drawn red on its sender's half of the edge.
The leader's estimates are small violet spheres with their 2σ covariance ellipse (the
x–y block in 3-D). The desired shape, anchored at the leader, is drawn as thin
translucent lines. A unicycle's heading is an arrow from its position. Every primitive array
of a ``SceneEntity`` is present (Foxglove's schema requires them), empty when
unused. Pure: arrays in, a JSON-ready dict out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

FRAME = "world"
Color = tuple[float, float, float, float]
LEADER_COLOR: Color = (1.0, 0.55, 0.0, 1.0)
AGENT_COLOR: Color = (0.12, 0.47, 0.71, 1.0)
HEALTHY: Color = (0.17, 0.63, 0.17, 1.0)
BROKEN: Color = (0.84, 0.15, 0.16, 1.0)
UNKNOWN: Color = (0.6, 0.6, 0.6, 1.0)
TREE: Color = (1.0, 0.84, 0.0, 1.0)
SHAPE: Color = (0.5, 0.5, 0.5, 0.35)
LOST: Color = (0.84, 0.15, 0.16, 1.0)
ESTIMATE: Color = (0.58, 0.4, 0.74, 0.8)
HEADING: Color = (1.0, 1.0, 1.0, 0.9)
LINE_LOOP = 1  # foxglove.LineType
LINE_LIST = 2
ELLIPSE_POINTS = 24
SIGMAS = 2.0  # the ellipse drawn: x̂ + 2σ

_PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def _time(stamp_ns: int) -> dict[str, int]:
    return {"sec": stamp_ns // 1_000_000_000, "nsec": stamp_ns % 1_000_000_000}


def _vec(p: npt.NDArray[np.float64]) -> dict[str, float]:
    """A point of dimension 2 or 3 as a ``foxglove.Vector3`` (z = 0 in the plane)."""
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]) if p.shape[0] > 2 else 0.0}


def _color(c: Color) -> dict[str, float]:
    return {"r": c[0], "g": c[1], "b": c[2], "a": c[3]}


def _pose(p: npt.NDArray[np.float64] | None = None) -> dict[str, Any]:
    origin = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {"position": origin if p is None else _vec(p), "orientation": dict(_IDENTITY)}


def _lines(
    points: list[dict[str, float]], color: Color, thickness: float, kind: int = LINE_LIST
) -> dict[str, Any]:
    return {
        "type": kind,
        "pose": _pose(),
        "thickness": thickness,
        "scale_invariant": True,
        "points": points,
        "color": _color(color),
        "colors": [],
        "indices": [],
    }


def entity(entity_id: str, stamp_ns: int, epoch: int, **primitives: list[Any]) -> dict[str, Any]:
    """A ``foxglove.SceneEntity`` with every primitive array present."""
    out: dict[str, Any] = {
        "timestamp": _time(stamp_ns),
        "frame_id": FRAME,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": "epoch", "value": str(epoch)}],
    }
    for name in _PRIMITIVES:
        out[name] = primitives.get(name, [])
    return out


def edge_colors(
    healthy: npt.NDArray[np.bool_] | None, tree: npt.NDArray[np.bool_] | None, m: int
) -> list[Color]:
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
) -> dict[str, Any]:
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
    """
    n = positions.shape[0]
    span = float(np.ptp(offsets, axis=0).max()) if n > 1 else 1.0
    radius = max(0.04 * span, 1e-3)  # [m], visible at the formation's scale
    spheres = []
    texts = []
    for i in range(n):
        color = LEADER_COLOR if i + 1 == leader else AGENT_COLOR
        size = {"x": 2 * radius, "y": 2 * radius, "z": 2 * radius}
        spheres.append({"pose": _pose(positions[i]), "size": size, "color": _color(color)})
        texts.append(
            {
                "pose": _pose(positions[i] + np.r_[radius, radius, 0.0][: positions.shape[1]]),
                "billboard": True,
                "font_size": 14.0,
                "scale_invariant": True,
                "color": _color((1.0, 1.0, 1.0, 1.0)),
                "text": str(i + 1),
            }
        )
    colors = edge_colors(healthy, tree, edges.shape[0])
    groups: dict[Color, list[dict[str, float]]] = {}
    for (i, j), color in zip(edges, colors, strict=True):
        groups.setdefault(color, []).extend((_vec(positions[i - 1]), _vec(positions[j - 1])))
    lines = [_lines(pts, c, 4.0 if c == TREE else 2.0) for c, pts in groups.items()]
    anchor = positions[leader - 1] - offsets[leader - 1]
    shape_pts: list[dict[str, float]] = []
    for i, j in edges:
        shape_pts += [_vec(anchor + offsets[i - 1]), _vec(anchor + offsets[j - 1])]
    if shape_pts:
        lines.append(_lines(shape_pts, SHAPE, 1.0))
    half: list[dict[str, float]] = []
    for i, j in sorted(lost or []):
        a, b = positions[i - 1], positions[j - 1]
        half += [_vec(a), _vec((a + b) / 2)]
    if half:
        lines.append(_lines(half, LOST, 3.0))
    for p, c in zip(estimates or [], covariances or [], strict=False):
        if p is None:
            continue
        centre = np.asarray(p, dtype=float)
        e_size = {"x": radius, "y": radius, "z": radius}
        spheres.append({"pose": _pose(centre), "size": e_size, "color": _color(ESTIMATE)})
        if c is not None:
            ring = ellipse(centre, np.asarray(c, dtype=float))
            if ring:
                lines.append(_lines(ring, ESTIMATE, 1.0, LINE_LOOP))
    arrows = [] if headings is None else heading_arrows(positions, headings, radius)
    team = entity(
        "formation", stamp_ns, epoch, spheres=spheres, lines=lines, texts=texts, arrows=arrows
    )
    return {"deletions": [], "entities": [team]}


def heading_arrows(
    positions: npt.NDArray[np.float64], headings: npt.NDArray[np.float64], radius: float
) -> list[dict[str, Any]]:
    """``foxglove.ArrowPrimitive`` per agent: from ``positions`` (n, d) [m] along ``headings``
    (n,) [rad], a yaw about z (an arrow points along its pose's +x)."""
    out = []
    for p, th in zip(positions, headings, strict=True):
        if not np.isfinite(th):
            continue
        yaw = {"x": 0.0, "y": 0.0, "z": float(np.sin(th / 2)), "w": float(np.cos(th / 2))}
        out.append({
            "pose": {"position": _vec(p), "orientation": yaw},
            "shaft_length": 3.0 * radius, "shaft_diameter": 0.4 * radius,
            "head_length": 1.5 * radius, "head_diameter": 1.0 * radius,
            "color": _color(HEADING),
        })  # fmt: skip
    return out


def ellipse(
    centre: npt.NDArray[np.float64], cov: npt.NDArray[np.float64]
) -> list[dict[str, float]]:
    """Points of the ``SIGMAS``-σ ellipse of the x–y block of ``cov`` around ``centre``."""
    block = cov[:2, :2]
    if not np.isfinite(block).all():
        return []
    values, vectors = np.linalg.eigh((block + block.T) / 2)
    axes = vectors * (SIGMAS * np.sqrt(np.clip(values, 0.0, None)))
    t = np.linspace(0.0, 2 * np.pi, ELLIPSE_POINTS, endpoint=False)
    ring = (axes @ np.stack([np.cos(t), np.sin(t)])).T
    out = []
    for r in ring:
        p = centre.copy()
        p[:2] += r
        out.append(_vec(p))
    return out


__all__ = ["FRAME", "edge_colors", "ellipse", "entity", "heading_arrows", "scene_update"]
