"""twinslam: the project package beside the card's node folders (docs/architecture.md §5).

``device_tracker``, ``edge_mapper``, ``udt_node`` and ``msg_schemas`` stay top-level as the
card names them; everything else lives here, one subpackage per layer's concern, so nothing
generic (``simulator``, ``cli``) is installed as a top-level Python package. This module
imports nothing: importing a subpackage never pulls in another one.
"""
