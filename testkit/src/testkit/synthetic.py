"""Synthetic recordings: what a distributed run of a simulated result records, without processes.

Used by the recorder's tests (``synth`` fixture) and by ``bench/bench_foxglove.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from formation import keys
from formation.codec import attachment, encode
from formation.messages import (
    CoordinationState,
    DecisionBatch,
    DecisionColumns,
    Judgement,
    LeaderEstimate,
)
from formation.scenario import Scenario
from recorder.live.epoch_assembly import TAPS, EpochAssembler
from recorder.recording.stored_scenario import SCENARIO, scenario_metadata
from recorder.recording.writer import RecordingWriter

RUN = "synthetic"
EPOCH_NS = 1_000_000_000  # log time between epochs in the synthetic recording [ns]


def _header(sender: str, seq: int, epoch: int) -> dict[str, Any]:
    return {"run_id": RUN, "sender": sender, "seq": seq, "epoch": epoch, "stamp_ns": 1000 + epoch}


def traffic(result: Any) -> list[tuple[str, bytes, bytes | None, int]]:
    """What a distributed run of ``result`` (a SimResult) puts on the wire, in epoch order."""
    s: Scenario = result.scenario
    out: list[tuple[str, bytes, bytes | None, int]] = []
    edges = [tuple(int(v) for v in e) for e in s.edge_array]
    x = result.positions
    th, sat = getattr(result, "headings", None), getattr(result, "saturated", None)
    for k in range(len(x)):
        t = k * EPOCH_NS
        for i in range(1, s.n + 1):
            pose = (
                {}
                if th is None or sat is None
                else {"heading": float(th[k, i - 1]),
                      "saturated": int(sat[k - 1, i - 1]) if k else 0}
            )  # fmt: skip
            msg = CoordinationState(
                **_header(f"agent/{i}", k, k), agent=i, position=x[k, i - 1].tolist(), **pose
            )
            out.append((keys.agent_state(RUN, i), encode(msg), attachment(k, k, i), t + i))
        if k >= len(result.estimates):
            continue
        dropped = ~np.asarray(result.delivered[k], dtype=bool)
        records = DecisionColumns(
            source=[int(a) for a, _ in s.directed_links],
            target=[int(b) for _, b in s.directed_links],
            epoch=[k] * len(dropped),
            seq=[k] * len(dropped),
            judgement=dropped.astype(int).tolist(),  # 0: passed, 1: dropped
        )
        batch = DecisionBatch(
            **_header("netem", k, k),
            phase="state",
            judgements=[Judgement(verdict="pass"), Judgement(verdict="drop")],
            records=records,
        )
        out.append((keys.netem_decision(RUN), encode(batch), None, t + 100))
        est, cov, obs = result.estimates[k], result.estimate_cov[k], result.observable[k]
        msg = LeaderEstimate(
            **_header("leader", k, k),
            positions=[est[i].tolist() if obs[i] else None for i in range(s.n)],
            # None where the leader computed no covariances (estimator.covariance_every)
            covariances=[
                cov[i].tolist() if obs[i] and not np.isnan(cov[i]).any() else None
                for i in range(s.n)
            ],
            observable=obs.tolist(),
            tree=[e for e, t_ in zip(edges, result.tree[k], strict=True) if t_],
            healthy=[e for e, h in zip(edges, result.healthy[k], strict=True) if h],
            components=int(result.components[k]),
            rigidity_rank=int(result.rigidity_rank[k]),
            rigid=bool(result.rigid[k] == 1),
            x_ref=x[k, s.reference_agent - 1].tolist(),
            v_ref=[0.0] * s.dimension,
            reports_received=s.n,
        )
        out.append((keys.leader_estimate_out(RUN), encode(msg), attachment(k, k, 0), t + 200))
    return out


def write_synthetic(
    path: Path,
    result: Any,
    inject: list[tuple[str, bytes, bytes | None, int]] = (),  # type: ignore[assignment]
    messages: list[tuple[str, bytes, bytes | None, int]] | None = None,
    derived: list[tuple[str, bytes, int]] = (),  # type: ignore[assignment]
    **options: Any,
) -> dict[str, int]:
    """Record ``traffic(result)`` as the recorder would (with metrics and scene); counts per key.

    ``inject``: more ``(key, payload, attachment, log time)`` received among them (forgeries);
    ``messages``: what to record instead of ``traffic(result)``;
    ``derived``: more ``(key, payload, log time)`` on the recorder's own channels (as if it
    wrote them: a corrupt or older recorder);
    ``options`` go to :class:`RecordingWriter` (e.g. ``split_size``).
    """
    s = result.scenario
    meta = {SCENARIO: scenario_metadata(s)}
    options = {"chunk_size": 64 * 1024, **options}
    rec = RecordingWriter(path, metadata=meta, taps=TAPS, **options)
    asm = EpochAssembler(s, RUN, clock=lambda: 0)
    wire = traffic(result) if messages is None else messages
    extra = iter(sorted(derived, key=lambda m: m[2]))
    pending = next(extra, None)
    for key, data, att, t in sorted([*wire, *inject], key=lambda m: m[3]):
        while pending is not None and pending[2] <= t:
            rec.write(*pending)
            pending = next(extra, None)
        for kind, k_, d_, recv in rec.write_batch([(key, data, att, None, t)]):
            for out_key, payload in asm.on(kind, k_, d_, recv):
                rec.write(out_key, payload, recv + 1)
    for forged in [*([pending] if pending else []), *extra]:
        rec.write(*forged)
    for out_key, payload in asm.finish(len(result.positions) * EPOCH_NS):
        rec.write(out_key, payload, len(result.positions) * EPOCH_NS)
    counts = rec.counts()
    rec.close()
    return counts


__all__ = ["EPOCH_NS", "RUN", "traffic", "write_synthetic"]
