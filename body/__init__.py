"""The link to ROS 2 robots (docs/robots.md): an rclpy node beside the bus, or rmw_zenoh's
wire format on a Zenoh session, behind one :class:`BodyLink`.

Beside the shell, between the vocabulary (:mod:`formation`) and its users, the agents and the
headless plant. rclpy is the optional extra ``ros2``: nothing here imports it until a link
opens, and :func:`require_ros2` names the extra to install.
"""

from body.link import BodyLink, open_body_link
from body.rmw_zenoh import ADMIN_SPACE, pose_cdr, topic_key, twist_cdr
from body.ros2 import NS_PER_S, exit_process, require_ros2

__all__ = [
    "ADMIN_SPACE",
    "NS_PER_S",
    "BodyLink",
    "exit_process",
    "open_body_link",
    "pose_cdr",
    "require_ros2",
    "topic_key",
    "twist_cdr",
]
