"""A recording as pandas DataFrames: :func:`load_run` (``recorder.load_run``) and ``formation export``.

:func:`load_run` is ``analysis.frames(read_run(path))``: the one decoder of a recording, every
message through the trust gate first (what it skips is in :attr:`analysis.Frames.skipped`),
then the same tables a simulation gives (the columns are in :mod:`analysis.tables`).
"""

from __future__ import annotations

import json
from pathlib import Path

from analysis import Frames, frames
from formation.errors import RecordingError
from recorder.reading.run import read_run


def load_run(path: str | Path) -> Frames:
    """The recording at ``path`` (and its rotated parts ``run-001.mcap``, ...) as DataFrames.

    Needs the scenario stored as metadata (every ``formation run`` recording has it).
    Malformed and forged messages are skipped and counted in :attr:`analysis.Frames.skipped`.
    """
    return frames(read_run(path))


def export(run: Frames, out_dir: Path, fmt: str = "parquet") -> list[Path]:
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
    skipped = None if run.skipped is None else run.skipped.as_json()
    meta = {"source": str(run.source), "metadata": run.metadata, "skipped": skipped}
    (out_dir / "metadata.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return [*written, out_dir / "scenario.toml", out_dir / "metadata.json"]


__all__ = ["export", "load_run"]
