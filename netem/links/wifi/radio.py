"""Received power between every pair of agents, from their true positions.

Log-distance path loss (Rappaport, *Wireless Communications*, 2nd ed., §4.9, eq. 4.69; ns-3's
``LogDistancePropagationLossModel``): ``P_r = P_t − PL(d0) − 10 γ log10(d / d0) − X`` [dBm],
``d`` floored at ``d0``. The shadowing ``X ~ N(0, σ²)`` [dB] is drawn per unordered pair and
epoch from the keyed generator, so the channel is reciprocal and the same in every phase of
an epoch (docs/model.md §11).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.keyed_random import Stream, keyed_normal
from netem.links.wifi.config import AirConfig

Floats = npt.NDArray[np.float64]

AIR_STREAM = int(Stream.AIR)  # the air model's stream of keyed_random
SHADOWING = 1  # sub-stream: per-pair shadowing (0 is the backoff draws)


def received_dbm(config: AirConfig, positions_m: Floats, seed: int, epoch: int) -> Floats:
    """Power each agent receives from each other [dBm].

    Parameters
    ----------
    positions_m : (n, d) array [m]
        The agents' true positions.

    Returns
    -------
    (n, n) array [dBm]
        ``[i, j]``: what ``j`` receives when ``i`` sends; ``-inf`` on the diagonal.
    """
    x = np.asarray(positions_m, dtype=np.float64)
    n = x.shape[0]
    distance = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(axis=-1))
    d = np.maximum(distance, config.reference_distance_m)
    loss = config.reference_loss_db + 10.0 * config.path_loss_exponent * np.log10(
        d / config.reference_distance_m
    )
    power = config.tx_power_dbm - loss
    if config.shadowing_sigma_db > 0.0:
        i, j = np.triu_indices(n, 1)
        draws = keyed_normal(seed, AIR_STREAM, SHADOWING, epoch, i, j)
        shadow = np.zeros((n, n))
        shadow[i, j] = shadow[j, i] = config.shadowing_sigma_db * draws
        power = power - shadow
    np.fill_diagonal(power, -np.inf)
    return np.asarray(power, dtype=np.float64)


def to_mw(dbm: Floats | float) -> Floats:
    return np.asarray(np.power(10.0, np.asarray(dbm, dtype=np.float64) / 10.0), dtype=np.float64)


__all__ = ["AIR_STREAM", "SHADOWING", "received_dbm", "to_mw"]
