"""Faithful scenes (issue 17): two lockstep runs with the same seed record the same scenes.

The scene of epoch k is drawn once that epoch's states, estimate and formation decisions
are in; netem sends the decisions of closed epochs in batches on a timer, so a scene drawn
earlier depended on timing (edge colours and the tree differed between two such runs).
The scenes are protobuf (the SDK's SceneUpdate), decoded here with the schema the file
carries and compared with their time stamps removed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from recorder.reading.decoder import as_dict, decode

pytestmark = pytest.mark.integration
EPOCHS = 150


def _untimed(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if k != "timestamp"}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def scenes(path: Path) -> list[Any]:
    with open(path, "rb") as f:
        return [
            _untimed(as_dict(decode(schema.name, schema.data, m.data)))
            for schema, ch, m in make_reader(f).iter_messages(log_time_order=True)
            if ch.metadata.get("kind") == "scene" and schema is not None
        ]


def test_two_runs_with_the_same_seed_record_the_same_scenes(
    paper_path: Path, runs_dir: Path
) -> None:
    got = []
    for n in range(2):
        out = runs_dir / f"r{n}"
        proc = subprocess.run(
            [sys.executable, "-m", "testbed.cli", "run", str(paper_path), "--epochs", str(EPOCHS),
             "--seed", "3", "--runs-dir", str(out)],
            capture_output=True, text=True, timeout=300,
            env={k: v for k, v in os.environ.items() if k != "COLUMNS"},
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        (mcap,) = out.glob("*/run.mcap")
        got.append(scenes(mcap))
    a, b = got
    assert len(a) == len(b) == EPOCHS + 1
    epochs = [int(s["entities"][0]["metadata"][0]["value"]) for s in a]
    assert epochs == list(range(EPOCHS + 1))  # every epoch once, in order
    assert all(s["entities"][0]["lines"] for s in a)  # something drawn, not empty decodes
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x == y, f"epoch {k}: the scenes differ"
    grey = [k for k, s in enumerate(a[:-1]) for ln in s["entities"][0]["lines"]
            if ln["color"]["r"] == 0.6 and ln["thickness"] != 1.0]  # fmt: skip
    assert grey == [], f"epochs drawn without their estimate: {grey[:5]}"
