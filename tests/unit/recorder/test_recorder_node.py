"""The recorder shell's pieces that need no network: intake, key filters, sizes, the public API."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

import recorder
from formation import keys
from formation.errors import TestbedError
from recorder.node import Intake, _filters, _size, build_parser


def sample(key: str, payload: bytes = b"{}") -> SimpleNamespace:
    return SimpleNamespace(
        key_expr=key,
        payload=SimpleNamespace(to_bytes=lambda: payload),
        attachment=None,
        timestamp=None,
    )


def test_intake_counts_what_it_cannot_keep() -> None:
    intake = Intake(limit=3)
    for k in range(5):
        intake.on_sample(sample(f"a/{k % 2}"))  # type: ignore[arg-type]
    assert intake.backlog() == 3
    assert dict(intake.dropped) == {"a/1": 1, "a/0": 1}
    items = intake.drain()
    assert [i[0] for i in items] == ["a/0", "a/1", "a/0"]
    assert intake.backlog() == 0 and intake.peak == 3
    intake.on_sample(sample("a/0"))  # type: ignore[arg-type]
    assert intake.backlog() == 1


def test_key_filters() -> None:
    assert _filters(None, "r") == [keys.everything("r")]
    assert _filters(["formation/r/agent/**,formation/r/leader/**", "formation/r/netem/*"], "r") == [
        "formation/r/agent/**",
        "formation/r/leader/**",
        "formation/r/netem/*",
    ]
    with pytest.raises(
        TestbedError, match="--keys formation/r/\\*\\* and formation/r/agent/1/state overlap"
    ):
        _filters(["formation/r/**", "formation/r/agent/1/state"], "r")


def test_sizes() -> None:
    assert _size("100M") == 100 << 20
    assert _size("1.5k") == 1536
    assert _size("2GB") == 2 << 30
    assert _size("4096") == 4096


def test_parser_defaults() -> None:
    args = build_parser().parse_args(["--run-id", "x"])
    assert args.chunk_size == 1 << 20 and args.compression is None and args.keys is None


def test_public_api() -> None:
    order = sorted(
        recorder.__all__, key=lambda n: (0 if n.isupper() else 1 if n[0].isupper() else 2, n)
    )
    assert recorder.__all__ == order  # constants, classes, functions, as ruff's RUF022 sorts
    for name in recorder.__all__:
        assert getattr(recorder, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        _ = recorder.nothing
