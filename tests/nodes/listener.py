"""A listener node run as its own OS process by the cross-process tests.

It subscribes to one topic (parameters ``topic`` and ``type``), prints one JSON line when it is
ready (its resolved names, parameters and endpoint GIDs) and one JSON line per message it
accepts, holding the SHA-256 of the message re-encoded by rosbags, the independent reference.
"""

from __future__ import annotations

import hashlib
import json
import sys

import node_runtime
from msg_schemas import typestore


def main() -> int:
    node_runtime.init()
    node = node_runtime.Node("listener")
    topic = node.declare_parameter("topic", "chatter").value
    type_name = node.declare_parameter("type", "std_msgs/msg/String").value
    qos_name = node.declare_parameter("qos", "default").value
    extra = node.declare_parameter("extra", "none").value
    qos = node_runtime.SENSOR_DATA if qos_name == "sensor_data" else node_runtime.DEFAULT
    store = typestore()

    def on_msg(msg: object) -> None:
        ref = bytes(store.serialize_cdr(msg, type_name))
        print(json.dumps({"event": "msg", "type": type_name,
                          "sha256": hashlib.sha256(ref).hexdigest()}), flush=True)

    sub = node.create_subscription(type_name, topic, on_msg, qos)
    print(json.dumps({
        "event": "ready", "name": node.get_name(), "namespace": node.get_namespace(),
        "topic": sub.topic_name, "extra": extra,
        "reader_gids": [g.bytes.hex() for g in node._reader_gids()],
        "participant_gid": node.context.gid.bytes.hex(),
    }), flush=True)
    node_runtime.run(node)
    return 0


if __name__ == "__main__":
    sys.exit(main())
