"""A recording as pandas DataFrames: :func:`load_run` (``recorder.load_run``) and ``formation export``.

One pass over the recording and its rotated parts, every message through the
:class:`~recorder.reading.trust.Gate` first (what it skips is in :attr:`Run.skipped`). Axes are
``x``, ``y`` (and ``z`` in 3-D); lengths in metres, covariances in m². Columns:

``states`` — one row per recorded true state ``x_i[k]`` (sender side, before loss):
    ``epoch``, ``agent``, ``x``, ``y`` [, ``z``], ``substituted`` (how many lost neighbour
    values the agent filled in at this epoch, from what it reported with its next state);
    unicycles (``dynamics = "unicycle"``) add ``heading`` [rad] and ``saturated`` (sub-steps of
    the step into this epoch with a clipped speed; NaN / −1 where not recorded).
``estimates`` — the leader's BLUE, one row per epoch and agent:
    ``epoch``, ``agent``, ``observable``, ``x``, ``y`` [, ``z``] (NaN if unobservable),
    ``cov_xx``, ``cov_xy``, ... (every entry of the d×d covariance block, NaN if unobservable).
``decisions`` — netem's verdict on each packet: ``epoch``, ``phase``, ``link_class``
    (formation, report, estimate), ``source``, ``target``, ``link`` (``"1->2"``), ``seq``,
    ``verdict`` (pass, drop, duplicate, delayed), ``on_time`` (delivered in its epoch),
    ``delay_epochs``, ``delay_ms``, ``model``, ``state`` (the link model's state).
``metrics`` — one row per epoch with a state: ``epoch``, ``agents`` (how many took part:
    their states recorded), ``formation_error_m``, ``shape_error_m`` (recomputed from
    ``states``, over the edges between the agents that took part, as the recorder's,
    :func:`recorder.analysis.membership.team_errors`; NaN when no edge is),
    ``recorded_formation_error_m`` (the recorder's live value, NaN if absent), and from the leader's estimate ``components``,
    ``rigidity_rank``, ``tree_edges``, ``healthy_edges``, ``observable`` (counts; −1 / NaN
    without an estimate), ``formation_drops`` (formation packets not on time).
``substitutions`` — each value an agent used for a lost packet: ``epoch`` (when used),
    ``agent``, ``neighbour``, ``fallback``, ``x``, ``y`` [, ``z``] (the value ``x̃_j``),
    ``error_x``, ... (``x̃_j[k] − x_j[k]`` against the recorded truth, NaN if unknown).

Plus :attr:`Run.scenario`, :attr:`Run.metadata` (MCAP metadata records by name) and
:attr:`Run.skipped` (:class:`~recorder.reading.trust.Skipped`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation.errors import RecordingError
from formation.messages import CoordinationState, DecisionBatch, EpochMetrics, LeaderEstimate
from formation.scenario import Scenario
from recorder.analysis.membership import errors_of_team, present
from recorder.analysis.rundata import iter_trusted
from recorder.reading.reader import parts, scenario_of
from recorder.reading.trust import Gate, Skipped

TABLES = ("states", "estimates", "decisions", "metrics", "substitutions")
AXES = ("x", "y", "z")


@dataclass
class Run:
    """One recording as DataFrames; see the module docstring for every column."""

    states: pd.DataFrame
    estimates: pd.DataFrame
    decisions: pd.DataFrame
    metrics: pd.DataFrame
    substitutions: pd.DataFrame
    scenario: Scenario
    metadata: dict[str, dict[str, str]]
    skipped: Skipped
    source: Path
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


class _Rows:
    def __init__(self, s: Scenario) -> None:
        self.s, self.d = s, s.dimension
        self.states: dict[tuple[int, int], list[float]] = {}
        self.poses: dict[tuple[int, int], tuple[float | None, int | None]] = {}
        self.subs: dict[tuple[int, int], list[tuple[int, bool, list[float]]]] = {}
        self.ests: dict[int, LeaderEstimate] = {}
        self.decisions: list[tuple[Any, ...]] = []
        self.recorded: dict[int, float | None] = {}

    def add(self, kind: str, msg: Any) -> None:
        if kind == "agent_state":
            st: CoordinationState = msg
            self.states[st.epoch, st.agent] = st.position
            self.poses[st.epoch, st.agent] = (st.heading, st.saturated)
            if st.substituted:
                self.subs[st.epoch - 1, st.agent] = [
                    (u.neighbour, u.fallback, u.value) for u in st.substituted
                ]
        elif kind == "leader_estimate":
            self.ests[msg.epoch] = msg
        elif kind == "decision":
            batch: DecisionBatch = msg
            for c in batch.decisions:
                on_time = c.verdict in ("pass", "duplicate") and c.delay_epochs == 0
                self.decisions.append(
                    (
                        c.epoch,
                        batch.phase,
                        c.link_class,
                        c.source,
                        c.target,
                        f"{c.source}->{c.target}",
                        c.seq,
                        c.verdict,
                        on_time,
                        c.delay_epochs,
                        c.delay_ms,
                        c.model,
                        c.state,
                    )
                )
        elif kind == "metrics":
            m: EpochMetrics = msg
            self.recorded[m.epoch] = m.formation_error_m

    def frames(self) -> dict[str, pd.DataFrame]:
        s, d = self.s, self.d
        axes = list(AXES[:d])
        subs_per = {key: len(v) for key, v in self.subs.items()}
        keys_sorted = sorted(self.states)
        pos = np.array([self.states[k] for k in keys_sorted], dtype=float).reshape(-1, d)
        states = pd.DataFrame(
            {
                "epoch": np.array([k for k, _ in keys_sorted], dtype=np.int64),
                "agent": np.array([i for _, i in keys_sorted], dtype=np.int64),
                **{a: pos[:, c] for c, a in enumerate(axes)},
                "substituted": np.array([subs_per.get(k, 0) for k in keys_sorted], dtype=np.int64),
            }
        )
        if s.control.dynamics == "unicycle":
            poses = [self.poses.get(k, (None, None)) for k in keys_sorted]
            states["heading"] = np.array(
                [np.nan if h is None else h for h, _ in poses], dtype=float
            )
            states["saturated"] = np.array(
                [-1 if n is None else n for _, n in poses], dtype=np.int64
            )
        count = int(states["epoch"].max()) + 1 if len(states) else 0
        x = np.full((count, s.n, d), np.nan)
        if len(states):
            x[states["epoch"].to_numpy(), states["agent"].to_numpy() - 1] = pos
        return {
            "states": states,
            "estimates": self._estimates(axes),
            "decisions": pd.DataFrame(
                self.decisions,
                columns=[
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
                ],
            ).sort_values(
                ["epoch", "link_class", "source", "target"], kind="stable", ignore_index=True
            ),
            "metrics": self._metrics(x),
            "substitutions": self._substitutions(x, axes),
        }

    def _estimates(self, axes: list[str]) -> pd.DataFrame:
        n, d = self.s.n, self.d
        epochs = sorted(self.ests)
        e = len(epochs)
        est = np.full((e, n, d), np.nan)
        cov = np.full((e, n, d, d), np.nan)
        obs = np.zeros((e, n), dtype=bool)
        for r, k in enumerate(epochs):
            msg = self.ests[k]
            obs[r] = msg.observable
            for i, (p, c) in enumerate(zip(msg.positions, msg.covariances, strict=True)):
                if p is not None:
                    est[r, i] = p
                if c is not None:
                    cov[r, i] = c
        cols: dict[str, Any] = {
            "epoch": np.repeat(np.array(epochs, dtype=np.int64), n),
            "agent": np.tile(np.arange(1, n + 1, dtype=np.int64), e),
            "observable": obs.reshape(-1),
        }
        for u, a in enumerate(axes):
            cols[a] = est[:, :, u].reshape(-1)
        for u, a in enumerate(axes):
            for v, b in enumerate(axes):
                cols[f"cov_{a}{b}"] = cov[:, :, u, v].reshape(-1)
        return pd.DataFrame(cols)

    def _metrics(self, x: np.ndarray) -> pd.DataFrame:
        s = self.s
        team = present(x)
        complete = np.flatnonzero(team.any(axis=1))  # every epoch with a state
        xs, team = x[complete], team[complete]
        fe, se = errors_of_team(xs, team, s.edge_array, s.weights, s.offsets)
        drops: dict[int, int] = {}
        for row in self.decisions:
            if row[2] == "formation" and not row[8]:
                drops[row[0]] = drops.get(row[0], 0) + 1

        def from_est(k: int, what: str) -> float:
            e = self.ests.get(k)
            if e is None:
                return np.nan
            return float(
                {
                    "components": e.components,
                    "rigidity_rank": e.rigidity_rank,
                    "tree_edges": len(e.tree),
                    "healthy_edges": len(e.healthy),
                    "observable": sum(e.observable),
                }[what]
            )

        ks = complete.tolist()
        out = pd.DataFrame(
            {
                "epoch": complete.astype(np.int64),
                "agents": team.sum(axis=1).astype(np.int64),
                "formation_error_m": fe,
                "shape_error_m": se,
                "recorded_formation_error_m": np.array(
                    [self.recorded.get(k, np.nan) for k in ks], dtype=float
                ),
            }
        )
        for what in ("components", "rigidity_rank", "tree_edges", "healthy_edges", "observable"):
            out[what] = [from_est(k, what) for k in ks]
        for what in ("components", "rigidity_rank"):
            out[what] = out[what].fillna(-1).astype(np.int64)
        out["formation_drops"] = np.array([drops.get(k, 0) for k in ks], dtype=np.int64)
        return out

    def _substitutions(self, x: np.ndarray, axes: list[str]) -> pd.DataFrame:
        rows = sorted((k, i, j, fb, v) for (k, i), subs in self.subs.items() for j, fb, v in subs)
        d = self.d
        values = np.array([r[4] for r in rows], dtype=float).reshape(-1, d)
        errors = np.full_like(values, np.nan)
        for m, (k, _, j, _, _) in enumerate(rows):
            if 0 <= k < len(x):
                errors[m] = values[m] - x[k, j - 1]
        cols: dict[str, Any] = {
            "epoch": np.array([r[0] for r in rows], dtype=np.int64),
            "agent": np.array([r[1] for r in rows], dtype=np.int64),
            "neighbour": np.array([r[2] for r in rows], dtype=np.int64),
            "fallback": np.array([r[3] for r in rows], dtype=bool),
        }
        for c, a in enumerate(axes):
            cols[a] = values[:, c]
        for c, a in enumerate(axes):
            cols[f"error_{a}"] = errors[:, c]
        return pd.DataFrame(cols)


_WANTED = frozenset({"agent_state", "leader_estimate", "decision", "metrics"})


def load_run(path: str | Path) -> Run:
    """The recording at ``path`` (and its rotated parts ``run-001.mcap``, ...) as DataFrames.

    Needs the scenario stored as metadata (every ``formation run`` recording has it).
    Malformed and forged messages are skipped and counted in :attr:`Run.skipped`.
    """
    path = Path(path)
    held: dict[str, Any] = {}

    def gate_of(meta: dict[str, dict[str, str]]) -> Gate:
        scenario = scenario_of(meta, path)
        if scenario is None:
            raise RecordingError(str(path), "no scenario in the metadata (record with --scenario)")
        held.update(meta=meta, scenario=scenario, rows=_Rows(scenario), gate=Gate(scenario))
        return held["gate"]  # type: ignore[no-any-return]

    for kind, _, _, msg, _ in iter_trusted(path, gate_of):
        if kind in _WANTED:
            held["rows"].add(kind, msg)
    return Run(
        **held["rows"].frames(),
        scenario=held["scenario"],
        metadata=held["meta"],
        skipped=held["gate"].skipped,
        source=path,
        files=parts(path),
    )


def export(run: Run, out_dir: Path, fmt: str = "parquet") -> list[Path]:
    """Write every table as ``<name>.parquet`` or ``<name>.csv``, plus ``scenario.toml`` and
    ``metadata.json`` (the MCAP metadata and the skip counts); returns the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, frame in run.tables().items():
        target = out_dir / f"{name}.{fmt}"
        if fmt == "parquet":
            try:
                frame.to_parquet(target, index=False)
            except ImportError as exc:
                raise RecordingError(
                    str(target), f"parquet needs pyarrow ({exc}); use --format csv"
                ) from None
        elif fmt == "csv":
            frame.to_csv(target, index=False)
        else:
            raise ValueError(f"format {fmt!r}; expected parquet or csv")
        written.append(target)
    (out_dir / "scenario.toml").write_text(run.scenario.to_toml(), encoding="utf-8")
    meta = {"source": str(run.source), "metadata": run.metadata, "skipped": run.skipped.as_json()}
    (out_dir / "metadata.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return [*written, out_dir / "scenario.toml", out_dir / "metadata.json"]


__all__ = ["AXES", "TABLES", "Run", "export", "load_run"]
