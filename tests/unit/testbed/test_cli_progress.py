"""Progress lines off a terminal: a line per slow stage, a line every tenth of a run."""

from __future__ import annotations

import io
import threading

from testbed.cli.progress import Stages, every
from testbed.cli.run import epoch_lines


class _Watched(io.StringIO):
    """A stream that says when a whole line was written to it."""

    def __init__(self) -> None:
        super().__init__()
        self.written = threading.Event()

    def write(self, s: str) -> int:
        n = super().write(s)
        if s.endswith("\n"):  # print writes the text and its end apart
            self.written.set()
        return n


def test_every_stage_is_announced_and_timed_when_asked_at_once() -> None:
    out = io.StringIO()
    stages = Stages("simulate", 2, quiet_s=None, out=out)
    for name in ("zero", "hold"):
        with stages.stage(name):
            pass
    lines = out.getvalue().splitlines()
    assert lines[0] == "simulate: [1/2] zero ..." and lines[2] == "simulate: [2/2] hold ..."
    assert lines[1].startswith("simulate: [1/2] zero: done in ") and lines[1].endswith(" s")
    assert len(lines) == 4


def test_a_quick_stage_says_nothing() -> None:
    out = io.StringIO()
    with Stages("simulate", 1, quiet_s=60.0, out=out).stage("zero"):
        pass
    assert out.getvalue() == ""


def test_a_slow_stage_is_announced_while_it_runs() -> None:
    out = _Watched()
    with Stages("experiment", 1, quiet_s=0.01, out=out).stage("variants"):
        assert out.written.wait(30), "no line while the stage ran"
        assert out.getvalue() == "experiment: [1/1] variants ...\n"
    assert out.getvalue().splitlines()[1].startswith("experiment: [1/1] variants: done in ")


def test_a_run_prints_a_line_every_tenth_of_its_epochs_and_at_its_end() -> None:
    lines: list[str] = []
    progress = epoch_lines("estimate", 47, lines.append)
    for done in range(1, 48):
        progress(done, 47, done // 10)
    progress(47, 47, 4)  # a repeated report of the end prints nothing more
    assert every(47) == 5 and len(lines) == 10
    assert lines[0].startswith("estimate: epoch 5/47, 0 packets dropped, ")
    assert lines[-1].startswith("estimate: epoch 47/47, 4 packets dropped, ")
    assert all(line.endswith(" epochs/s") for line in lines)
