"""Where an agent's body is: simulated in its process (the default), or a robot on ROS 2.

A scenario's ``[body]``: ``kind = "simulated"`` keeps today's body, integrated inside the
agent process. ``kind = "ros2"`` makes the agent process also a ROS 2 node (rclpy, the
optional extra ``ros2``): it takes its state from its robot's pose topic and sends its
command as a ``geometry_msgs/msg/Twist`` on the command topic (docs/robots.md).
``kind = "rmw_zenoh"`` is the same exchange over the run's Zenoh session in rmw_zenoh's
wire format, with no DDS (body/rmw_zenoh.py).

Topics are templates on the agent: its id (``/robot{id}/pose``), its index from 0
(``/tb3_{index}/odom``) or its name in ``names`` (``/{name}/cmd_vel``); message types are
checked here, at load, against the types the bodies can read and write.
"""

from __future__ import annotations

import math
import re
import string
from collections.abc import Sequence
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

BodyKind = Literal["simulated", "ros2", "rmw_zenoh"]
ROS_BODIES: tuple[str, ...] = ("ros2", "rmw_zenoh")  # kinds whose body is a ROS 2 robot
POSE_TYPES: tuple[str, ...] = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")
COMMAND_TYPES: tuple[str, ...] = ("geometry_msgs/msg/Twist",)
CLOCK_TOPIC = "/clock"  # the stepped plant's sim time, for nodes with use_sim_time
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
EXTRA = "ros2"  # the optional extra that installs rclpy and the message packages
BODY_LOST_EXIT = 4  # exit code of an agent whose robot's pose stopped coming
# A ROS 2 topic name once ``{id}`` is filled in: absolute or relative, tokens of
# letters, digits and underscores, not starting with a digit, joined by single slashes.
_TOPIC = re.compile(r"^/?[A-Za-z_~][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")  # a robot's name: one token of a topic
TEMPLATE_FIELDS = ("id", "index", "name")  # agent i: i, i − 1, names[i − 1]


class _Settings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Qos(_Settings):
    """A ROS 2 QoS profile: reliability, durability and the history's depth (keep last)."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = Field(10, ge=1, le=10_000)

    def refuses(self, reliability: str, durability: str) -> str | None:
        """The policy by which a publisher offering ``reliability`` and ``durability`` cannot
        match a subscription asking for this (DDS's rule: it may offer more, never less);
        None if they match. An offer named otherwise (``system_default``) is not judged."""
        if self.reliability == "reliable" and reliability == "best_effort":
            return "reliability"
        if self.durability == "transient_local" and durability == "volatile":
            return "durability"
        return None


# rclpy's time source asks best effort, volatile, depth 1; reliable and transient local match
# it and serve a subscriber that asks for the last time on joining
CLOCK_QOS = Qos(reliability="reliable", durability="transient_local", depth=1)


class Transform(_Settings):
    """A robot whose poses come in a frame of its own (its ``odom``): where that frame lies in
    ``body.frame_id``, its origin at ``offset_m`` [robot m] and its x axis turned
    ``rotation_rad`` about z. A pose ``p`` in it is ``R(rotation) p + offset`` in the world."""

    agent: int
    frame_id: str  # the frame the robot stamps its poses with
    offset_m: tuple[float, ...] = Field((0.0, 0.0), min_length=2, max_length=3)
    rotation_rad: float = 0.0

    @field_validator("frame_id")
    @classmethod
    def _frame(cls, v: str) -> str:
        return _frame_name(v)

    def to_world(self, xyz: Sequence[float], yaw: float) -> tuple[list[float], float]:
        """A pose in this frame → in ``body.frame_id``: position [robot m], heading [rad]."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        x, y, *z = xyz
        o = [*self.offset_m, 0.0][:3]
        world = [c * x - s * y + o[0], s * x + c * y + o[1], *(v + o[2] for v in z)]
        return world, yaw + self.rotation_rad

    def from_world(self, xyz: Sequence[float]) -> list[float]:
        """A position in ``body.frame_id`` → in this frame [robot m]."""
        o = [*self.offset_m, 0.0][:3]
        x, y, *z = (v - w for v, w in zip(xyz, o, strict=False))
        return self.velocity_in_frame([x, y, *z])

    def velocity_to_world(self, velocity: Sequence[float]) -> list[float]:
        """A velocity in this frame [robot m/s] → in ``body.frame_id``."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        x, y, *z = velocity
        return [c * x - s * y, s * x + c * y, *z]

    def velocity_in_frame(self, velocity: Sequence[float]) -> list[float]:
        """A velocity in ``body.frame_id`` [robot m/s] → in this frame (turned back)."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        x, y, *z = velocity
        return [c * x + s * y, -s * x + c * y, *z]


class Body(_Settings):
    """The scenario's ``[body]``: where the agents' bodies are, and how to reach them.

    ``scale``: the robot's frame in metres per metre of the scenario (a lab arena that is a
    half-size model of the scenario has ``scale = 0.5``); poses are divided by it, commands
    multiplied. ``pose_timeout_s``: a robot whose pose has not come for this long is lost.
    ``max_speed_m_s``: a holonomic robot's commanded speed is clipped to it (a unicycle's
    limits are ``control.unicycle``'s). ``start_tolerance_m``: how far a robot's first pose
    may be from where the scenario starts its agent. ``tracking_warning_m``: a robot whose
    measured pose strays this far from its agent's state is warned of in the summary.
    """

    kind: BodyKind = "simulated"
    agents: tuple[int, ...] = ()  # the agents with this body; empty: every agent
    pose_topic: str = "/robot{id}/pose"
    pose_type: str = "geometry_msgs/msg/PoseStamped"
    command_topic: str = "/robot{id}/cmd_vel"
    command_type: str = "geometry_msgs/msg/Twist"
    frame_id: str = "world"  # the frame the poses are given in, and the plant's poses carry
    scale: float = Field(1.0, gt=0.0)  # robot metres per scenario metre
    pose_timeout_s: float = Field(5.0, gt=0.0)  # [s]
    max_speed_m_s: float | None = Field(None, gt=0.0)  # [scenario m/s]; None: no limit
    start_tolerance_m: float = Field(1.0, gt=0.0)  # [scenario m]
    tracking_warning_m: float = Field(0.1, gt=0.0)  # [scenario m] pose against state
    # a holonomic robot's cmd_vel: in the pose's frame ("world"), or REP 103's body frame
    command_frame: Literal["world", "body"] = "world"
    names: tuple[str, ...] = ()  # each agent's robot's name, for ``{name}``: agents 1..n
    domain_id: int | None = Field(None, ge=0, le=232)  # ROS_DOMAIN_ID; None: the environment's
    pose_qos: Qos = Qos()
    command_qos: Qos = Qos()
    transforms: tuple[Transform, ...] = ()  # robots whose poses come in frames of their own

    @field_validator("pose_topic", "command_topic")
    @classmethod
    def _template(cls, v: str) -> str:
        fields = [name for _, name, _, _ in string.Formatter().parse(v) if name is not None]
        if not set(fields) & set(TEMPLATE_FIELDS):
            raise ValueError(
                "a topic template names the agent as {id}, {index} or {name}, e.g. "
                "'/robot{id}/pose'"
            )
        if not set(fields) <= set(TEMPLATE_FIELDS):
            raise ValueError(
                "a topic template may only name {id}, {index} and {name}, got "
                f"{sorted(set(fields))}"
            )
        topic = v.format(id=1, index=0, name="robot")
        if not _TOPIC.match(topic):
            raise ValueError(
                f"not a ROS 2 topic name once filled in ({topic!r}): tokens of letters, digits "
                "and underscores joined by single slashes"
            )
        return v

    @field_validator("pose_type")
    @classmethod
    def _pose_type(cls, v: str) -> str:
        return _known(v, POSE_TYPES)

    @field_validator("command_type")
    @classmethod
    def _command_type(cls, v: str) -> str:
        return _known(v, COMMAND_TYPES)

    @field_validator("frame_id")
    @classmethod
    def _frame(cls, v: str) -> str:
        return _frame_name(v)

    def transform_of(self, agent: int) -> Transform | None:
        """The frame agent ``agent``'s robot publishes in, if not ``frame_id``."""
        return next((t for t in self.transforms if t.agent == agent), None)

    def frame_of(self, agent: int) -> str:
        """The frame agent ``agent``'s robot's poses are stamped with."""
        transform = self.transform_of(agent)
        return self.frame_id if transform is None else transform.frame_id

    def has_robot(self, agent: int) -> bool:
        """Whether agent ``agent``'s body is a ROS 2 robot."""
        return self.kind in ROS_BODIES and (not self.agents or agent in self.agents)

    def robots(self, n: int) -> list[int]:
        """The ids among ``1..n`` whose body is a ROS 2 robot, ascending."""
        return [i for i in range(1, n + 1) if self.has_robot(i)]

    def pose_topic_of(self, agent: int) -> str:
        return self.pose_topic.format(**self._fields(agent))

    def command_topic_of(self, agent: int) -> str:
        return self.command_topic.format(**self._fields(agent))

    def _fields(self, agent: int) -> dict[str, object]:
        name = self.names[agent - 1] if agent <= len(self.names) else f"robot{agent}"
        return {"id": agent, "index": agent - 1, "name": name}


def _frame_name(v: str) -> str:
    if not v or v.strip() != v:
        raise ValueError("a frame id is a non-empty name without surrounding spaces")
    return v


def _known(v: str, types: tuple[str, ...]) -> str:
    if v not in types:
        raise ValueError(f"unknown message type; expected one of {', '.join(types)}")
    return v


def body_problems(body: Body, n: int) -> list[tuple[str, object, str]]:
    """``(field, value, problem)`` of ``[body]`` against a team of ``n``; empty when it can run."""
    for k, i in enumerate(body.agents):
        if not 1 <= i <= n:
            return [(f"body.agents[{k}]", i, f"agent does not exist (agents are 1..{n})")]
    if len(set(body.agents)) != len(body.agents):
        return [("body.agents", list(body.agents), "an agent is listed twice")]
    named = any("{name}" in t for t in (body.pose_topic, body.command_topic))
    if body.names and len(body.names) != n:
        return [
            (
                "body.names",
                list(body.names),
                f"{len(body.names)} names; expected {n}, one per agent",
            )
        ]
    if named and not body.names:
        return [("body.names", [], "a topic names {name}: give each agent's robot a name")]
    for k, name in enumerate(body.names):
        if not _NAME.match(name):
            return [
                (
                    f"body.names[{k}]",
                    name,
                    "not one token of a ROS 2 topic name (letters, digits, underscores)",
                )
            ]
    if len(set(body.names)) != len(body.names):
        return [("body.names", list(body.names), "a name is given twice")]
    for k, t in enumerate(body.transforms):
        field = f"body.transforms[{k}]"
        if not 1 <= t.agent <= n:
            return [(f"{field}.agent", t.agent, f"agent does not exist (agents are 1..{n})")]
        if not body.has_robot(t.agent):
            return [(f"{field}.agent", t.agent, "no ROS 2 robot has this agent (body.agents)")]
        if [u.agent for u in body.transforms].count(t.agent) > 1:
            return [(f"{field}.agent", t.agent, "a robot has one transform; it is given twice")]
        if t.frame_id == body.frame_id:
            return [
                (
                    f"{field}.frame_id",
                    t.frame_id,
                    "the world frame itself (body.frame_id): a transform maps a robot's own frame",
                )
            ]
    return []


__all__ = [
    "BODY_LOST_EXIT",
    "CLOCK_QOS",
    "CLOCK_TOPIC",
    "CLOCK_TYPE",
    "COMMAND_TYPES",
    "EXTRA",
    "POSE_TYPES",
    "ROS_BODIES",
    "Body",
    "BodyKind",
    "Qos",
    "Transform",
    "body_problems",
]
