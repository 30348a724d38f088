"""Message schemas of twinslam: the custom ``.msg`` files and everything derived from them.

``msg_schemas/msg/*.msg`` define the per-slot protocol (DESIGN.md §1) as ROS 2 interface package
``twinslam_msgs``; ROS 2 Jazzy's standard messages come from rosbags. Use :func:`new` to build a
message with ROS defaults, :func:`serialize`/:func:`deserialize` for CDR bytes.
"""

from msg_schemas.cdr import CdrError, deserialize, serialize
from msg_schemas.registry import (
    INTERFACE_PACKAGE,
    custom_message_names,
    message_class,
    new,
    type_hash,
    type_name_of,
    typestore,
)

__all__ = [
    "INTERFACE_PACKAGE",
    "CdrError",
    "custom_message_names",
    "deserialize",
    "message_class",
    "new",
    "serialize",
    "type_hash",
    "type_name_of",
    "typestore",
]
