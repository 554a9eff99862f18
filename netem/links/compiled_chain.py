"""Many links' finite chains, compiled: :func:`netem.links.chains.run_chain` link by link in one
pass, where numpy steps every link once per epoch. Table look-ups only: the same states."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from formation.compiled import jit


@jit
def step_chains(
    table: npt.NDArray[np.int64], s0: npt.NDArray[np.int64], post: npt.NDArray[np.int64]
) -> None:
    """``post[l, k] = table[l, k, post[l, k − 1]]`` with ``post[l, −1] = s0[l]``, in place."""
    for link in range(table.shape[0]):
        s = s0[link]
        for k in range(table.shape[1]):
            s = table[link, k, s]
            post[link, k] = s


@jit
def gilbert_elliott_chains(
    u_move: npt.NDArray[np.float64],
    u_loss: npt.NDArray[np.float64],
    p: float,
    r: float,
    loss: npt.NDArray[np.float64],
    s0: npt.NDArray[np.int64],
    entry: npt.NDArray[np.int8],
    drop: npt.NDArray[np.bool_],
) -> npt.NDArray[np.int64]:
    """The Gilbert–Elliott layer's chain, link by link: each epoch's entry state (``entry``),
    its drop ``u_loss < loss[entry]`` (``drop``), then the move (good → bad iff
    ``u_move < p``, bad → good iff ``u_move < r``); returns the states after the last epoch.
    The same comparisons as the layer's table through :func:`step_chains`."""
    last = np.empty(u_move.shape[0], dtype=np.int64)
    for link in range(u_move.shape[0]):
        s = s0[link]
        for k in range(u_move.shape[1]):
            entry[link, k] = s
            drop[link, k] = u_loss[link, k] < loss[s]
            u = u_move[link, k]
            s = int(u < p) if s == 0 else int(u >= r)
        last[link] = s
    return last
