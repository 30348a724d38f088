"""Message schemas of twinslam: the custom ``.msg`` files and what the nodes share about them.

``msg_schemas/msg/*.msg`` define the per-slot protocol (docs/architecture.md §1) as the
ROS 2 interface package ``twinslam_msgs``, which rosidl generates (``make`` builds it into the
venv; colcon on a ROS host). Here: :func:`new` to fill a generated message from numpy
arrays, the topic names and QoS profiles, header stamps, and the validation of decoded content.
"""

from msg_schemas.interfaces import (
    INTERFACE_PACKAGE,
    UnknownMessageType,
    custom_message_names,
    message_class,
    new,
    type_name_of,
)

__all__ = [
    "INTERFACE_PACKAGE",
    "UnknownMessageType",
    "custom_message_names",
    "message_class",
    "new",
    "type_name_of",
]
