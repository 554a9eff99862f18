"""What one simulated run produced (``testbed.sim.simulate``, or one member of a batch)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from analysis import Decisions, RunData, formation_error, shape_error, summarise
from formation.air import AIR_CAUSES
from netem import AIR, CAUSES

if TYPE_CHECKING:
    from analysis import Frames

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(kw_only=True)
class SimResult(RunData):
    """A run's record (:class:`analysis.RunData`) as the simulator makes it, with what only the
    simulator knows; row ``i − 1`` is agent ``i``, ``E`` epochs.

    Every delivery is decided; in the team is whoever published ``x[k]``
    (``Membership.published``: the bodies out of it stay where they were).
    report_ok, estimate_ok : (E, n) control links delivered in time
    fallbacks : substitutions that fell back to ``hold`` (no estimate to use)
    air_drops : (epoch, column, cause code) of each packet the shared air dropped; columns
        are the formation links, then the reports and the estimates by agent
    """

    report_ok: Mask
    estimate_ok: Mask
    fallbacks: int
    air_drops: tuple[tuple[int, int, int], ...] = ()

    def __post_init__(self) -> None:
        if self.present.shape != self.positions.shape[:2]:
            self.present = self.scenario.membership.published
        super().__post_init__()

    @property
    def substitution_epochs(self) -> npt.NDArray[np.int64]:
        """(N,) the epoch of each of ``substitution_errors``' rows."""
        return (
            np.zeros(0, dtype=np.int64) if self.substitutions is None else self.substitutions.epoch
        )

    def record(self, label: str | None = None) -> RunData:
        """The run's record under ``label`` (default: its strategy), as its recording holds it:
        no state of an agent out of the team (its body stays where it was), no delivery
        decided on a link with an end not taking part, substitution errors where the neighbour's
        state is known. A copy, so that setting a field of it leaves this result as it was."""
        label, s = label or self.label, self.scenario
        if self.substitutions is None or s.membership.present.all():
            return replace(self, label=label)
        x = np.where(self.present[..., None], self.positions, np.nan)
        on, links = s.membership.present[: len(self.delivered)], s.directed_links
        return replace(
            self,
            label=label,
            positions=x,
            formation_error=formation_error(x, s.edge_array, s.weights),
            shape_error=shape_error(x, s.edge_array, s.offsets),
            decided=on[:, links[:, 0] - 1] & on[:, links[:, 1] - 1],
            substitution_errors=self.substitutions.known_errors(x),
        )

    def summary(self) -> dict[str, Any]:
        """The headline numbers of the run (what ``formation simulate`` prints), as
        :func:`analysis.summarise` gives them for its :meth:`record`."""
        full = summarise(self.record())
        out = {"scenario": self.scenario.name, "strategy": self.strategy, "seed": self.seed}
        out |= {k: full[k] for k in _HEADLINE}
        out["fallbacks"] = self.fallbacks
        out |= {k: full[k] for k in _ESTIMATION}
        if self.scenario.network.air is not None:  # the shared air's drops by cause
            d = self.decisions_made()
            lost = d.verdict == "drop"
            out["air_losses"] = {c: int((lost & (d.model == c)).sum()) for c in AIR_CAUSES}
        return out

    def frames(self) -> Frames:
        """The run as the DataFrames a recording of it gives (:func:`analysis.frames`), with
        netem's record as the model decides it: a row per packet of every link class between
        agents taking part, on time or dropped (the simulator does not model what happens to
        a late packet, nor its sequence number, delay or link state: −1, NaN, empty)."""
        from analysis import frames  # pandas loads here

        return frames(replace(self, decisions=self.decisions_made()))

    def decisions_made(self) -> Decisions:
        """netem's record as the model decides it: a row per packet of every link class
        between agents taking part (no sequence number, delay, model or link state)."""
        s = self.scenario
        on = s.membership.present[: len(self.delivered)]
        src, dst = s.directed_links[:, 0], s.directed_links[:, 1]
        ids, zero = np.arange(1, s.n + 1), np.zeros(s.n, dtype=np.int64)
        classes = (  # (phase, class, sources, targets, on time (E, L), taking part (E, L))
            ("state", "formation", src, dst, self.delivered, on[:, src - 1] & on[:, dst - 1]),
            ("report", "report", ids, zero, self.report_ok, on),
            ("estimate", "estimate", zero, ids, self.estimate_ok, on),
        )
        parts: dict[str, list[Any]] = {"epoch": [], "phase": [], "class": [], "src": [], "dst": []}
        ok: list[Mask] = []
        for phase, name, sources, targets, in_time, part in classes:
            ks, cs = np.nonzero(part)
            parts["epoch"].append(ks)
            parts["phase"].append(np.full(len(ks), phase, dtype=object))
            parts["class"].append(np.full(len(ks), name, dtype=object))
            parts["src"].append(sources[cs])
            parts["dst"].append(targets[cs])
            ok.append(in_time[ks, cs])
        col = {k: np.concatenate(v) for k, v in parts.items()}
        count = len(col["epoch"])
        model, queue = np.full(count, "", dtype=object), np.full(count, None, dtype=object)
        if self.air_drops:  # what the air dropped: its cause, as netem records it
            model, queue = self._air_causes(col, model, queue)
        return Decisions(
            epoch=col["epoch"].astype(np.int64),
            phase=col["phase"],
            link_class=col["class"],
            source=col["src"].astype(np.int64),
            target=col["dst"].astype(np.int64),
            seq=np.full(count, -1, dtype=np.int64),
            verdict=np.where(np.concatenate(ok), "pass", "drop").astype(object),
            delay_epochs=np.zeros(count, dtype=np.int64),
            delay_ms=np.full(count, np.nan),
            model=model,
            state=np.full(count, "", dtype=object),
            queue=queue,
            queue_depth=np.full(count, -1, dtype=np.int64),
            sojourn_ms=np.full(count, np.nan),
        )

    def _air_causes(
        self, col: dict[str, Any], model: npt.NDArray[Any], queue: npt.NDArray[Any]
    ) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
        """``model`` and ``queue`` with the air's cause and name on the rows it dropped."""
        s = self.scenario
        n, links = s.n, s.directed_links
        ends = [(int(a), int(b)) for a, b in links]
        ends += [(i, 0) for i in range(1, n + 1)] + [(0, i) for i in range(1, n + 1)]
        row = {
            (int(k), int(a), int(b)): r
            for r, (k, a, b) in enumerate(zip(col["epoch"], col["src"], col["dst"], strict=True))
        }
        for k, c, code in self.air_drops:
            r = row.get((k, *ends[c]))
            if r is not None:
                model[r], queue[r] = CAUSES[code], AIR
        return model, queue


_HEADLINE = (
    "epochs",
    "final_formation_error_m",
    "peak_formation_error_m",
    "final_shape_error_m",
    "peak_shape_error_m",
    "substitutions",
    "substitution_cov_trace_m2",
)
_ESTIMATION = ("estimation_cov_trace_m2", "nees_mean", "drops", "longest_outage", "safety")


__all__ = ["SimResult"]
