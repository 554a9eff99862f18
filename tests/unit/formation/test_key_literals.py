"""formation/keys.py builds every key: no key literal appears elsewhere in the product."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("formation", "shell", "agent", "leader", "netem", "recorder", "testbed")
# A string piece that spells part of a key expression: the run root, a lockstep inbox, a
# liveliness token, or a run prefix followed by a key's first segment.
KEY_PIECE = re.compile(r"^formation/|/inbox/|(^|/)alive/")
# After a run prefix in an f-string (Foxglove topics such as "/netem/decisions" are not keys).
AFTER_PREFIX = re.compile(r"^/(agent|link|leader|netem|status|viz|recorder)/")


def key_literals(source: str) -> list[tuple[int, str]]:
    """``(line, text)`` of every string constant (or f-string piece) in ``source`` that
    looks like part of a key expression."""
    tree = ast.parse(source)
    pieces = {
        id(v) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for v in node.values
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            in_fstring = id(node) in pieces and AFTER_PREFIX.search(node.value)
            if KEY_PIECE.search(node.value) or in_fstring:
                found.append((node.lineno, node.value))
    return found


def product_modules() -> list[Path]:
    return sorted(
        path
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if path != ROOT / "formation" / "keys.py"
    )


def test_the_scan_finds_a_key_built_by_hand() -> None:
    assert key_literals('k = f"{prefix}/agent/*/state"') == [(1, "/agent/*/state")]
    assert key_literals('k = "formation/run/alive/agent/1"')
    assert key_literals("k = f'{p}/inbox/{i}/state'")
    assert key_literals('doc = "agent i publishes its state"') == []


@pytest.mark.parametrize("path", product_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_key_literal_outside_keys(path: Path) -> None:
    found = key_literals(path.read_text(encoding="utf-8"))
    assert found == [], f"{path.relative_to(ROOT)}: build these keys in formation/keys.py: {found}"
