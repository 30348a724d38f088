"""QoS profiles of twinslam's topics (docs/architecture.md §6), as rclpy profiles.

* ``PROTOCOL``: the per-slot protocol — reliable and deep enough that a slow slot (a retrain,
  a bundle adjustment next door) loses nothing (a KEEP_LAST 10 queue dropped 11 slots in a test).
* ``MAP``: the edge's map — reliable and transient local, so a device that joins or restarts
  gets the latest map at once.
* ``CAMERA``: camera images as the player writes and the device reads them — reliable, 5 s
  deep. A reader keeps the last ``depth`` samples not yet taken; a device that falls behind by
  more loses frames (a clean checkout's device lagged 2.5 s over its first frames on a 2-core
  host). A best-effort reader (a viewer, ``SENSOR_DATA``) still matches a reliable writer.
* ``TF`` and ``TF_STATIC``: tf2's own profiles for ``/tf`` (reliable, volatile, 100 deep) and
  ``/tf_static`` (reliable, transient local: a late viewer still gets the static transforms),
  so RViz's and Foxglove's TF listeners match them.
"""

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

PROTOCOL = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
MAP = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: the held time the paced cameras of a group tell each other (topics.PLAYBACK_PACE): the last
#: of each camera for one that joins later, and room for several cameras' at once
PACE = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                  reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
CAMERA = QoSProfile(depth=150, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
TF = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
               reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
TF_STATIC = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
SENSOR_DATA = qos_profile_sensor_data

__all__ = ["CAMERA", "MAP", "PROTOCOL", "SENSOR_DATA", "TF", "TF_STATIC", "QoSProfile"]
