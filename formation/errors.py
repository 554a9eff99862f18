"""One error base for the testbed; subclasses build their message from the values that caused it."""

from __future__ import annotations

from typing import ClassVar


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


class RunEnded(RuntimeFailure):
    """A run that a failure of the user's code ended (a plug-in raised, or gave a wrong shape
    or a value that is not finite): every process was ended and the recording closed and kept."""

    def __init__(self, reason: str, epoch: int, run_dir: str) -> None:
        self.reason, self.epoch, self.run_dir = reason, epoch, run_dir
        super().__init__(
            f"the run ended at epoch {epoch}: {reason}; what was recorded is kept in {run_dir}"
        )


class UnreadableFile(RuntimeFailure):
    """A file a service needs (credentials, a certificate, the router's passwords) that its
    user cannot read: names the file, who names it, the user, the file's owner and the fix."""

    REMEDIES: ClassVar[dict[str, str]] = {  # problem → what to do
        "permission denied": "run the service as the file's owner (for the compose deployment: "
        "`export FORMATION_UID=$(id -u) FORMATION_GID=$(id -g)` before `up`, as the README "
        "says) or let uid {uid} read it",
        "no such file": "name an existing file (`formation keys keys/` writes a key set)",
        "is a directory": "name a file; an engine makes a missing secret or bind-mount source "
        "a directory, so check that the file exists on the host (`formation keys keys/`)",
    }

    def __init__(
        self,
        path: str,
        named_by: str,
        problem: str,
        uid: int,
        user: str,
        owner: tuple[int, str, int] | None = None,  # (uid, user, mode) when stat could tell
    ) -> None:
        self.path, self.named_by, self.problem, self.uid = path, named_by, problem, uid
        self.user, self.owner = user, owner
        owned = (
            ""
            if owner is None
            else f"; it is owned by uid {owner[0]} ({owner[1]}) with mode {owner[2]:04o}"
        )
        remedy = self.REMEDIES.get(problem, "make it readable by uid {uid}").format(uid=uid)
        super().__init__(
            f"{path} ({named_by}) cannot be read by uid {uid} ({user}): {problem}{owned}; {remedy}"
        )


NO_VALUE = _NO_VALUE
