"""Small scenario files for the loader's tests: a valid triangle, and a file written from text."""

from __future__ import annotations

from pathlib import Path

TRIANGLE = """
name = "tri"
edges = [[1, 2], [2, 3], [1, 3]]
[[agents]]
id = 1
offset = [0.0, 0.0]
[[agents]]
id = 2
offset = [1.0, 0.0]
[[agents]]
id = 3
offset = [0.0, 0.5]
"""
"""Three agents in the plane, rigid; a test appends its own sections."""


def scenario_file(folder: Path, text: str, name: str = "bad.toml") -> Path:
    """``text`` as the scenario file ``folder/name`` (errors name the file: ``bad.toml``)."""
    path = folder / name
    path.write_text(text)
    return path
