"""Scenario generators for teams of any size (tests, benchmarks, sweeps)."""

from __future__ import annotations

from typing import Any

import numpy as np

from formation.scenario import Scenario, load_dict


def henneberg_team(n: int, spacing_m: float = 1.0, seed: int = 0, **overrides: Any) -> Scenario:
    """``n`` agents on a perturbed square grid joined by a Henneberg (vertex addition) construction.

    Agent ``k ≥ 3`` is linked to its two nearest earlier agents, so the graph has
    ``2n − 3`` edges and is minimally rigid in the plane (generic positions). The
    gain is set to ``0.9 / max_degree`` so the scenario is always stable.
    """
    side = int(np.ceil(np.sqrt(n)))
    rng = np.random.default_rng(seed)
    grid = np.array([(c, r) for r in range(side) for c in range(side)][:n], dtype=float) * spacing_m
    pts = grid + rng.uniform(-0.15, 0.15, size=grid.shape) * spacing_m
    edges: list[list[int]] = [[1, 2]] if n >= 2 else []
    for k in range(3, n + 1):
        dist = np.linalg.norm(pts[: k - 1] - pts[k - 1], axis=1)
        edges += [[int(a) + 1, k] for a in sorted(np.argsort(dist)[:2])]
    degree = np.bincount(np.array(edges).ravel(), minlength=n + 1) if edges else np.zeros(1, int)
    data: dict[str, Any] = {
        "name": f"henneberg{n}",
        "epochs": 100,
        "agents": [{"id": i + 1, "offset": [float(v) for v in p]} for i, p in enumerate(pts)],
        "edges": edges,
        "control": {"gain": round(0.9 / max(int(degree.max()), 1), 6)},
        "reference": {"kind": "line", "velocity": [0.01, 0.005]},
        "initial": {"spread_m": 0.2 * spacing_m},
    }
    data.update(overrides)
    return load_dict(data, source=f"henneberg_team(n={n})")
