"""Every error the testbed raises on purpose: one base, :class:`TestbedError`, and subclasses
that build their message from the values that caused it.

The vocabulary's module: every layer imports its errors from here. Exceptions that only
carry control inside one module (the scenario's ``FieldProblem`` through pydantic, the
leader's ``PatternError`` and ``_OffPattern``, the trust gate's ``Skip``) stay there.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar, Literal

PluginKind = Literal["strategy", "controller", "link_model"]
PLUGIN_LABELS: dict[PluginKind, str] = {
    "strategy": "loss strategy",
    "controller": "controller",
    "link_model": "link model",
}


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


# -- the vocabulary: plug-ins and the arrays of the formation graph ---------------------------
class PluginError(TestbedError):
    """A plug-in that cannot be found, loaded or used: names its kind, its name and the problem."""

    def __init__(self, kind: PluginKind, name: str, problem: str) -> None:
        self.kind, self.name, self.problem = kind, name, problem
        super().__init__(f"{PLUGIN_LABELS[kind]} plug-in {name!r}: {problem}")


class PluginParameterError(PluginError):
    """A plug-in's parameter that its own model refuses: ``param`` (None: the parameters as a
    whole), the ``value`` given and the ``rule`` it breaks."""

    def __init__(
        self, kind: PluginKind, name: str, param: str | None, value: object, rule: str
    ) -> None:
        self.param, self.value, self.rule = param, value, rule
        super().__init__(kind, name, f"parameter {param or '(parameters)'} = {value!r}; {rule}")


class PluginFailure(TestbedError):
    """A plug-in that failed while a run used it: names it, the agents (or link) and the epoch."""

    def __init__(self, kind: PluginKind, name: str, where: str, epoch: int, problem: str) -> None:
        self.kind, self.name, self.where, self.epoch = kind, name, where, epoch
        self.problem = problem
        super().__init__(
            f"{PLUGIN_LABELS[kind]} plug-in {name!r} failed at epoch {epoch} ({where}): {problem}"
        )


class GraphInputError(TestbedError, ValueError):
    """Arrays handed to a graph or estimation routine that do not fit; says expected vs actual."""

    def __init__(self, what: str, expected: str) -> None:
        self.what, self.expected = what, expected
        super().__init__(f"{what}; expected {expected}")


class ShapeError(GraphInputError):
    """An array of the wrong shape: ``z has shape (5, 3); expected (7, 2)``."""

    def __init__(self, name: str, shape: tuple[int, ...], expected: str) -> None:
        self.name, self.shape = name, shape
        super().__init__(f"{name} has shape {shape}", expected)


class AgentIdError(GraphInputError):
    """An agent id outside ``1..n`` (or an edge joining an agent to itself)."""


class CovarianceError(GraphInputError):
    """A measurement covariance that is not symmetric positive definite."""


# -- the services ----------------------------------------------------------------------------
class Ros2Missing(TestbedError):
    """A ROS 2 body without rclpy: names the extra to install."""

    def __init__(self, who: str, missing: str) -> None:
        from formation.body import EXTRA  # here: the errors load without pydantic (a --help)

        self.who, self.missing = who, missing
        super().__init__(
            f"{who} needs the ROS 2 Python packages ({missing} is not installed); "
            f"install the extra: pip install 'formation-testbed[{EXTRA}]'"
        )


class BodyLost(RuntimeFailure):
    """No usable pose from a robot for longer than the scenario's ``pose_timeout_s``."""

    def __init__(self, agent: int, topic: str, waited_s: float, epoch: int) -> None:
        self.agent, self.topic, self.waited_s, self.epoch = agent, topic, waited_s, epoch
        waiting = "its newest pose" if epoch < 0 else f"waiting for epoch {epoch}"
        super().__init__(
            f"agent {agent}: body lost: no usable pose on {topic} for {waited_s:g} s ({waiting})"
        )


class RobotNotAtStart(RuntimeFailure):
    """A robot's first pose too far from where the scenario starts its agent."""

    def __init__(
        self,
        agent: int,
        topic: str,
        pose: Sequence[float],
        start: Sequence[float],
        tolerance_m: float,
    ) -> None:
        self.agent, self.topic, self.pose, self.start = agent, topic, list(pose), list(start)
        self.tolerance_m = tolerance_m
        where = ", ".join(f"{c:.6g}" for c in pose)
        want = ", ".join(f"{c:.6g}" for c in start)
        super().__init__(
            f"agent {agent}: its robot's first pose on {topic} is at ({where}) m, "
            f"{_distance(pose, start):.6g} m from its start ({want}) m in the scenario; "
            f"body.start_tolerance_m = {tolerance_m:g}: place the robot there (formation robots "
            "SCENARIO prints each start) or raise the tolerance"
        )


class QosMismatch(RuntimeFailure):
    """A robot's publisher whose QoS cannot match the agent's subscription."""

    def __init__(self, agent: int, topic: str, offered: str, requested: str, policy: str) -> None:
        self.agent, self.topic, self.offered, self.requested = agent, topic, offered, requested
        super().__init__(
            f"agent {agent}: the robot's publisher on {topic} offers {offered}, the agent's "
            f"subscription requests {requested} ({policy} incompatible): no pose can arrive; "
            "set body.pose_qos to what the robot publishes"
        )


class PoseFrameMismatch(RuntimeFailure):
    """A robot's poses in a frame other than the one the scenario declares for it
    (``body.frame_id``, or its transform's ``frame_id``)."""

    def __init__(
        self, agent: int, topic: str, frame: str, expected: str, field: str = "body.frame_id"
    ) -> None:
        self.agent, self.topic, self.frame, self.expected = agent, topic, frame, expected
        super().__init__(
            f"agent {agent}: the poses on {topic} are in frame {frame!r}, not "
            f"{field} = {expected!r}: none is used; publish them in {expected!r}, or declare "
            "the frame they are in (body.frame_id, or the robot's own in body.transforms)"
        )


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return float(sum((x - y) ** 2 for x, y in zip(a, b, strict=False)) ** 0.5)


class LinkModelError(TestbedError):
    """A link model that cannot be built or asked: names the link and the broken rule."""

    def __init__(self, link: str, problem: str) -> None:
        self.link, self.problem = link, problem
        super().__init__(f"link {link}: {problem}")


# -- the testbed: deployment, batches, experiments ---------------------------------------------
class KeysError(TestbedError):
    """Credentials that cannot be generated where asked."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path, self.problem = path, problem
        super().__init__(f"{path}: {problem}")


class BatchError(TestbedError):
    """A batch that cannot be built or asked: names what (a member, the seeds) and the rule."""

    def __init__(self, subject: str, problem: str) -> None:
        self.subject, self.problem = subject, problem
        super().__init__(f"{subject}: {problem}")


class ExecutorError(TestbedError):
    """A ``--scheduler`` (or ``--jobs``) that cannot be used: names the option, its value and
    what is wrong with it."""

    def __init__(self, option: str, value: object, problem: str) -> None:
        self.option, self.value, self.problem = option, value, problem
        super().__init__(f"{option} {value}: {problem}")


class SweepError(TestbedError):
    """A sweep that cannot run or resume: names the argument or file and the broken rule."""

    def __init__(self, subject: str, problem: str) -> None:
        self.subject, self.problem = subject, problem
        super().__init__(f"{subject}: {problem}")


class UnknownLossModel(TestbedError):
    """A loss model name that is not one of the ``known`` ones."""

    def __init__(self, model: str, known: Sequence[str]) -> None:
        self.model, self.known = model, tuple(known)
        super().__init__(f"loss model {model!r}: expected one of {', '.join(known)}")
