"""``formation report | info | recover | replay`` through testbed.cli.main."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from testbed import cli


@pytest.fixture
def formation() -> Callable[..., int]:
    """``testbed.cli.main``, the recorder's subcommands among its own."""
    return lambda *argv: cli.main([str(a) for a in argv])


@pytest.fixture
def bad(tmp_path: Path, sim_results: dict[str, Any], synth: Any) -> dict[str, Path]:
    good = tmp_path / "good.mcap"
    synth.write(good, sim_results["hold"])
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    text = tmp_path / "text.mcap"
    text.write_text("# not a recording\n")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[:-100])
    return {"empty": empty, "text": text, "cut": cut, "good": good}


@pytest.mark.parametrize("command", ["report", "info", "replay"])
@pytest.mark.parametrize("which", ["empty", "text", "cut"])
def test_bad_files_fail_with_the_file_named(
    formation: Callable[..., int],
    bad: dict[str, Path],
    capsys: pytest.CaptureFixture[str],
    command: str,
    which: str,
) -> None:
    assert formation(command, bad[which]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"formation {command}: error: {bad[which]}: ")
    assert {"empty": "empty file", "text": "not an MCAP file", "cut": "truncated MCAP file"}[
        which
    ] in err


def test_recover_then_info_and_report(
    formation: Callable[..., int],
    bad: dict[str, Path],
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:
    fixed = tmp_path / "fixed" / "run.mcap"
    fixed.parent.mkdir()
    assert formation("recover", bad["cut"], "-o", fixed) == 0
    out = capsys.readouterr().out
    assert f"{fixed}: kept " in out and "trailing bytes unreadable" in out
    assert formation("info", fixed, "--validate") == 0
    out = capsys.readouterr().out
    assert "invalid" in out and " 0 invalid" in out
    assert formation("report", fixed) == 0
    assert (fixed.parent / "report.md").is_file()


def test_recover_refuses_a_non_mcap_file(
    formation: Callable[..., int], bad: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    assert formation("recover", bad["text"]) == 1
    assert f"{bad['text']}: not an MCAP file" in capsys.readouterr().err
