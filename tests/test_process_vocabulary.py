"""An edge process searches every device's archive under one vocabulary of visual words
(``shared_vocabulary``): the k-means that learns one runs once a process, not once a device.
"""

from __future__ import annotations

from rclpy.parameter import Parameter

from edge_mapper.node import EdgeMapperNode
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession
from twinslam.slam.back_end.place_words import PlaceWords

DEVICES = ("ar1", "ar2", "ar3")


def _sources(ros: RosSession, shared: bool) -> list[PlaceWords]:
    """The words each device's archive searches under, on an edge made with
    ``shared_vocabulary`` as given."""
    edge = EdgeMapperNode(context=ros.context, parameter_overrides=[
        Parameter("devices", value=list(DEVICES)), Parameter("policy", value="lff"),
        Parameter("shared_vocabulary", value=shared)])
    try:
        return [edge.links[d].core.archive.words.source() for d in DEVICES]
    finally:
        for link in edge.links.values():
            link.close(keep_checkpoint=True)
        edge.destroy_node()


def test_the_devices_of_one_edge_process_search_under_one_vocabulary(
        domain: LoopbackDomain, ros: RosSession) -> None:
    sources = _sources(ros, shared=True)
    assert all(words is sources[0] for words in sources)


def test_without_a_shared_vocabulary_each_device_learns_its_own(
        domain: LoopbackDomain, ros: RosSession) -> None:
    sources = _sources(ros, shared=False)
    assert len({id(words) for words in sources}) == len(DEVICES)
