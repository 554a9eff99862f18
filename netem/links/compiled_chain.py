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
