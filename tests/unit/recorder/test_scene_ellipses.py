"""The estimates' ellipses of a scene are drawn all at once, to the bit as one by one."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from foxglove.messages import Point3

from recorder.live.scene import ELLIPSE_POINTS, SIGMAS, ellipses


def _one_by_one(centre: npt.NDArray[np.float64], cov: npt.NDArray[np.float64]) -> list[bytes]:
    """The ellipse of one estimate, point by point: eigen-decomposition of its x–y block."""
    block = cov[:2, :2]
    if not np.isfinite(block).all():
        return []
    values, vectors = np.linalg.eigh((block + block.T) / 2)
    axes = vectors * (SIGMAS * np.sqrt(np.clip(values, 0.0, None)))
    t = np.linspace(0.0, 2 * np.pi, ELLIPSE_POINTS, endpoint=False)
    out = []
    for r in (axes @ np.stack([np.cos(t), np.sin(t)])).T:
        p = centre.copy()
        p[:2] += r
        z = float(p[2]) if len(p) > 2 else 0.0
        out.append(Point3(x=float(p[0]), y=float(p[1]), z=z).encode())
    return out


def test_every_ellipse_is_the_one_drawn_alone_to_the_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for d in (2, 3):
        a = rng.normal(size=(60, d, d)) * rng.uniform(1e-4, 10.0, size=(60, 1, 1))
        covariances = a @ np.swapaxes(a, 1, 2)
        covariances[7, 0, 1] = np.nan  # not drawn
        covariances[8] = 0.0  # a point
        centres = rng.normal(size=(60, d)) * 50.0
        drawn = ellipses(centres, covariances)
        for centre, cov, ring in zip(centres, covariances, drawn, strict=True):
            assert [p.encode() for p in ring] == _one_by_one(centre, cov)
        assert drawn[7] == [] and len(drawn[8]) == ELLIPSE_POINTS
