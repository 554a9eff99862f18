"""One error base for the testbed; subclasses build their message from the values that caused it."""

from __future__ import annotations


class TestbedError(Exception):
    """Base of every error the testbed raises on purpose; the CLI prints it and exits non-zero."""

    __test__ = False  # not a pytest test class despite the name


class ScenarioError(TestbedError):
    """A scenario file that cannot be used: names the file, the field path and the value."""

    def __init__(self, path: str, field: str, value: object, problem: str) -> None:
        self.path, self.field, self.value, self.problem = path, field, value, problem
        if not field:
            super().__init__(f"{path}: {problem}")
            return
        shown = "" if value is _NO_VALUE else f" = {value!r}"
        super().__init__(f"{path}: {field}{shown}; {problem}")


class _NoValue:
    def __repr__(self) -> str:
        return "<no value>"


_NO_VALUE = _NoValue()


class RecordingError(TestbedError):
    """An MCAP file that cannot be read as a recording of a run."""

    def __init__(self, path: str, problem: str) -> None:
        self.path, self.problem = path, problem
        super().__init__(f"{path}: {problem}")


class RuntimeFailure(TestbedError):
    """A distributed run that could not start or finish (a process died, an endpoint unreachable)."""


NO_VALUE = _NO_VALUE
