"""A run's record as pandas DataFrames: :func:`frames` (``recorder.load_run``, ``formation export``,
``SimResult.frames()``).

The same tables from a recording and from a simulation, column for column. Axes are ``x``,
``y`` (and ``z`` in 3-D); lengths in metres, covariances in m². Columns:

``states`` — one row per true state ``x_i[k]`` of an agent in the team (sender side, before
    loss): ``epoch``, ``agent``, ``x``, ``y`` [, ``z``], ``substituted`` (how many lost neighbour
    values the agent filled in at this epoch, from what it reported with its next state);
    unicycles (``dynamics = "unicycle"``) add ``heading`` [rad] and ``saturated`` (sub-steps of
    the step into this epoch with a clipped speed; NaN / −1 where not recorded).
``estimates`` — the leader's BLUE, one row per estimated epoch and agent:
    ``epoch``, ``agent``, ``observable``, ``x``, ``y`` [, ``z``] (NaN if unobservable),
    ``cov_xx``, ``cov_xy``, ... (every entry of the d×d covariance block, NaN if unobservable).
``decisions`` — netem's verdict on each packet: ``epoch``, ``phase``, ``link_class``
    (formation, report, estimate), ``source``, ``target``, ``link`` (``"1->2"``), ``seq``,
    ``verdict`` (pass, drop, duplicate, delayed), ``on_time`` (delivered in its epoch),
    ``delay_epochs``, ``delay_ms``, ``model``, ``state`` (the link model's state); the
    text columns are categoricals of their sorted values (equal to strings when compared).
``metrics`` — one row per epoch with a state: ``epoch``, ``agents`` (how many took part),
    ``formation_error_m``, ``shape_error_m`` (over the edges between the agents that took
    part, :func:`analysis.membership.errors_of_team`; NaN when no edge is),
    ``recorded_formation_error_m`` (the recorder's live value, NaN if absent), and from the
    leader's estimate ``components``, ``rigidity_rank``, ``tree_edges``, ``healthy_edges``,
    ``observable`` (counts; −1 / NaN without an estimate), ``formation_drops`` (formation
    packets not on time).
``substitutions`` — each value an agent used for a lost packet: ``epoch`` (when used),
    ``agent``, ``neighbour``, ``fallback``, ``x``, ``y`` [, ``z``] (the value ``x̃_j``),
    ``error_x``, ... (``x̃_j[k] − x_j[k]`` against the true state, NaN if unknown or ``j`` is
    out of the team at ``k``).

Plus :attr:`Frames.scenario`, :attr:`Frames.metadata` (a recording's MCAP metadata records by
name) and :attr:`Frames.skipped` (what a recording's trust gate refused; None if simulated).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd

from analysis.membership import errors_of_team
from analysis.record import Decisions, RunData, Skips, Substitutions
from formation.scenario import Scenario

TABLES = ("states", "estimates", "decisions", "metrics", "substitutions")
AXES = ("x", "y", "z")
_DECISIONS = (
    "epoch",
    "phase",
    "link_class",
    "source",
    "target",
    "link",
    "seq",
    "verdict",
    "on_time",
    "delay_epochs",
    "delay_ms",
    "model",
    "state",
)


@dataclass
class Frames:
    """One run as DataFrames; see the module docstring for every column."""

    states: pd.DataFrame
    estimates: pd.DataFrame
    decisions: pd.DataFrame
    metrics: pd.DataFrame
    substitutions: pd.DataFrame
    scenario: Scenario
    metadata: dict[str, dict[str, str]]
    skipped: Skips | None
    source: str
    files: list[Path] = field(default_factory=list)

    def tables(self) -> dict[str, pd.DataFrame]:
        return {name: getattr(self, name) for name in TABLES}

    def positions(self) -> np.ndarray:
        """True positions as an array (epochs, n, d), NaN where not recorded."""
        s = self.scenario
        count = int(self.states["epoch"].max()) + 1 if len(self.states) else 0
        x = np.full((count, s.n, s.dimension), np.nan)
        axes = list(AXES[: s.dimension])
        x[self.states["epoch"].to_numpy(), self.states["agent"].to_numpy() - 1] = self.states[
            axes
        ].to_numpy()
        return x


def frames(run: RunData) -> Frames:
    """``run`` as DataFrames (the module docstring has every column)."""
    s, rec = run.scenario, run.recorded
    axes = list(AXES[: s.dimension])
    subs = run.substitutions or Substitutions.none(s.dimension)
    decisions = run.decisions or _known_deliveries(run)
    return Frames(
        states=_states(run, subs, axes),
        estimates=_estimates(run, axes),
        decisions=_decisions(decisions),
        metrics=_metrics(run, decisions),
        substitutions=_substitutions(run, subs, axes),
        scenario=s,
        metadata={k: dict(v) for k, v in rec.metadata.items()} if rec else {},
        skipped=rec.skipped if rec else None,
        source=run.source,
        files=[Path(f) for f in rec.files] if rec else [],
    )


def _states(run: RunData, subs: Substitutions, axes: list[str]) -> pd.DataFrame:
    ks, rows = np.nonzero(run.present)  # epoch-major, then agent
    count = np.zeros(run.present.shape, dtype=np.int64)
    seen = (subs.epoch >= 0) & (subs.epoch < len(count))
    np.add.at(count, (subs.epoch[seen], subs.agent[seen] - 1), 1)
    pos = run.positions[ks, rows]
    out = pd.DataFrame(
        {
            "epoch": ks.astype(np.int64),
            "agent": (rows + 1).astype(np.int64),
            **{a: pos[:, c] for c, a in enumerate(axes)},
            "substituted": count[ks, rows],
        }
    )
    if run.scenario.control.dynamics == "unicycle":
        headings = run.headings if run.headings is not None else np.full(run.present.shape, np.nan)
        out["heading"] = headings[ks, rows]
        saturated = np.full(run.present.shape, -1, dtype=np.int64)
        if len(saturated):  # no step into epoch 0: nothing saturated
            saturated[0] = np.where(np.isfinite(headings[0]), 0, -1)
        if run.saturated is not None and len(run.saturated):
            saturated[1:] = run.saturated
        out["saturated"] = saturated[ks, rows]
    return out


def _estimates(run: RunData, axes: list[str]) -> pd.DataFrame:
    epochs = np.flatnonzero(run.estimated)
    n, e = run.scenario.n, len(epochs)
    est, cov = run.estimates[epochs], run.estimate_cov[epochs]
    cols: dict[str, Any] = {
        "epoch": np.repeat(epochs.astype(np.int64), n),
        "agent": np.tile(np.arange(1, n + 1, dtype=np.int64), e),
        "observable": run.observable[epochs].reshape(-1),
    }
    for u, a in enumerate(axes):
        cols[a] = est[:, :, u].reshape(-1)
    for u, a in enumerate(axes):
        for v, b in enumerate(axes):
            cols[f"cov_{a}{b}"] = cov[:, :, u, v].reshape(-1)
    return pd.DataFrame(cols)


def _decisions(d: Decisions) -> pd.DataFrame:
    texts = {
        name: d.coded.get(name) or _factorized(getattr(d, name))
        for name in ("phase", "link_class", "verdict", "model", "state")
    }
    order = _decision_order(d, texts["link_class"])
    cols = {
        "epoch": d.epoch,
        "source": d.source,
        "target": d.target,
        "seq": d.seq,
        "on_time": d.on_time,
        "delay_epochs": d.delay_epochs,
        "delay_ms": d.delay_ms,
    }
    out = {name: _categorical(coded, order) for name, coded in texts.items()}
    out["link"] = _categorical(_link_names(d.source, d.target), order)
    return pd.DataFrame(
        {name: out[name] if name in out else cols[name][order] for name in _DECISIONS}
    )


def _decision_order(
    d: Decisions, link_class: tuple[npt.NDArray[np.intp], Any]
) -> npt.NDArray[np.intp]:
    """The rows sorted by epoch, link class, source, target, as a stable sort of the
    columns would: one sort of one key where the ids allow it."""
    codes, classes = link_class
    rank = np.argsort(np.argsort(np.asarray(classes, dtype=str), kind="stable"))[codes]
    if not len(codes):
        return np.zeros(0, dtype=np.intp)
    low = min(int(d.epoch.min()), int(d.source.min()), int(d.target.min()))
    span = max(int(d.epoch.max()), int(d.source.max()), int(d.target.max())) + 1
    if low < 0 or span**3 * len(classes) >= 2**62:  # no one key: the columns sorted
        return np.lexsort((d.target, d.source, rank, d.epoch))
    key = ((d.epoch * len(classes) + rank) * span + d.source) * span + d.target
    return np.argsort(key, kind="stable")


def _categorical(coded: tuple[npt.NDArray[np.intp], Any], order: npt.NDArray[np.intp]) -> Any:
    """The text column ``values[codes]`` (``coded``) in ``order``, as a categorical of its
    values sorted (None missing): made from its few values, not string by string."""
    codes, values = coded
    values = np.asarray(values, dtype=object)
    given = np.array([v is not None for v in values], dtype=bool)
    names = np.array(sorted(values[given]), dtype=object)
    remap = np.full(len(values), -1, dtype=np.int64)
    remap[given] = np.searchsorted(names, values[given])
    return pd.Categorical.from_codes(remap[codes[order]], categories=pd.Index(names, dtype=str))


def _factorized(values: npt.NDArray[Any]) -> tuple[npt.NDArray[np.intp], Any]:
    codes, uniques = pd.factorize(values, use_na_sentinel=False)
    return codes, uniques


def _link_names(
    source: npt.NDArray[np.int64], target: npt.NDArray[np.int64]
) -> tuple[npt.NDArray[np.intp], Any]:
    """``"1->2"`` for each row, as codes into the names of the links, each written once: a
    run holds millions of decisions."""
    if not len(source):
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=object)
    low = int(min(source.min(), target.min()))
    base = int(max(source.max(), target.max())) - low + 1
    if base > 2**31:  # ids too far apart for one code: each row written
        names = [f"{a}->{b}" for a, b in zip(source.tolist(), target.tolist(), strict=True)]
        return _factorized(np.asarray(names, dtype=object))
    row, links = pd.factorize((source - low) * base + (target - low))
    pairs = zip((links // base + low).tolist(), (links % base + low).tolist(), strict=True)
    return row, [f"{a}->{b}" for a, b in pairs]


def _known_deliveries(run: RunData) -> Decisions:
    """The formation rows a run without netem's record knows: its decided deliveries."""
    ks, cols = np.nonzero(run.decided)
    links = run.links[cols]
    ok = run.delivered[ks, cols]
    count = len(ks)
    text = np.full(count, "", dtype=object)
    return Decisions(
        epoch=ks.astype(np.int64),
        phase=np.full(count, "state", dtype=object),
        link_class=np.full(count, "formation", dtype=object),
        source=links[:, 0].astype(np.int64),
        target=links[:, 1].astype(np.int64),
        seq=np.full(count, -1, dtype=np.int64),
        verdict=np.where(ok, "pass", "drop").astype(object),
        delay_epochs=np.zeros(count, dtype=np.int64),
        delay_ms=np.full(count, np.nan),
        model=text,
        state=text.copy(),
        queue=np.full(count, None, dtype=object),
        queue_depth=np.full(count, -1, dtype=np.int64),
        sojourn_ms=np.full(count, np.nan),
    )


def _metrics(run: RunData, decisions: Decisions) -> pd.DataFrame:
    s = run.scenario
    complete = np.flatnonzero(run.present.any(axis=1))  # every epoch with a state
    xs, team = run.positions[complete], run.present[complete]
    fe, se = errors_of_team(xs, team, s.edge_array, s.weights, s.offsets)
    late = decisions.text_in("link_class", ("formation",)) & ~decisions.on_time
    drops = np.bincount(decisions.epoch[late], minlength=len(run.present))
    recorded = np.full(len(run.present), np.nan)
    if run.recorded is not None:
        live = run.recorded.formation_error[: len(recorded)]
        recorded[: len(live)] = live
    known = complete < len(run.estimated)
    at = complete[known]
    at = at[run.estimated[at]]
    ints = np.full((2, len(complete)), -1, dtype=np.int64)
    counts = np.full((3, len(complete)), np.nan)
    where = np.searchsorted(complete, at)
    ints[:, where] = run.components[at], run.rigidity_rank[at]
    counts[:2, where] = run.tree[at].sum(axis=1), run.healthy[at].sum(axis=1)
    counts[2, where] = run.observable[at].sum(axis=1)
    return pd.DataFrame(
        {
            "epoch": complete.astype(np.int64),
            "agents": team.sum(axis=1).astype(np.int64),
            "formation_error_m": fe,
            "shape_error_m": se,
            "recorded_formation_error_m": recorded[complete],
            "components": ints[0],
            "rigidity_rank": ints[1],
            "tree_edges": counts[0],
            "healthy_edges": counts[1],
            "observable": counts[2],
            "formation_drops": drops[complete].astype(np.int64),
        }
    )


def _substitutions(run: RunData, subs: Substitutions, axes: list[str]) -> pd.DataFrame:
    order = np.lexsort((subs.neighbour, subs.agent, subs.epoch))
    values = subs.values[order]
    states = np.where(run.present[..., None], run.positions, np.nan)  # no state out of the team
    errors = subs.errors(states)[order]
    cols: dict[str, Any] = {
        "epoch": subs.epoch[order],
        "agent": subs.agent[order],
        "neighbour": subs.neighbour[order],
        "fallback": subs.fallback[order],
    }
    for c, a in enumerate(axes):
        cols[a] = values[:, c]
    for c, a in enumerate(axes):
        cols[f"error_{a}"] = errors[:, c]
    return pd.DataFrame(cols)


__all__ = ["AXES", "TABLES", "Frames", "frames"]
