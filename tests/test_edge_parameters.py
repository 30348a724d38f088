"""The edge's parameters through ROS 2's standard parameter services, from another rclpy
process: listed, described, refused with a reason when out of range or read-only, and a live
``policy`` change that decides the next slot."""

from __future__ import annotations

import time

import numpy as np
import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, ListParameters, SetParameters
from twinslam_msgs.msg import FrameSummaries, UploadRequest

from device_tracker.messages import FrameRecord, frame_summaries_message
from msg_schemas import qos, topics
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.matched_readers import WRITERS, matched_line
from twinslam.node_runtime.session import RosSession

#: how long one request waits for its answer before it is sent again, and how often
ANSWER_WAIT_S, TRIES = 10.0, 3


def _call(ros: RosSession, srv_type: type, name: str, request: object) -> object:
    """One parameter request, sent again where no answer came. A service can be ready for
    the client (it sees the server's endpoints) before the server has matched the client's
    reader of answers; Fast DDS' service then waits a bounded moment for that match and
    drops the answer past it (ros2/rmw_fastrtps#390), which a loaded host reaches: on a clean
    clone's suite the first list_parameters went unanswered for 30 s once. The parameter
    services' requests are idempotent, so sending one again is safe."""
    client = ros.node.create_client(srv_type, name)
    assert ros.spin_until(client.service_is_ready, 60.0), f"{name} is not offered"
    for _ in range(TRIES):
        future = client.call_async(request)
        if ros.spin_until(future.done, ANSWER_WAIT_S):
            return future.result()
        client.remove_pending_request(future)
    raise AssertionError(f"{name} did not answer {TRIES} requests in "
                         f"{TRIES * ANSWER_WAIT_S:.0f} s")


def _value(value: object) -> ParameterValue:
    if isinstance(value, str):
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=int(value))


def _set(ros: RosSession, **values: object) -> list:
    request = SetParameters.Request(parameters=[Parameter(name=k, value=_value(v))
                                                for k, v in values.items()])
    return _call(ros, SetParameters, "/edge_mapper/set_parameters", request).results


def _summaries(slot: int) -> FrameSummaries:
    frames = [FrameRecord(f, 0.1 * f, np.eye(4), True, np.arange(5, dtype=np.uint64) + f,
                          np.zeros(0, np.uint64), slot) for f in range(slot * 6, slot * 6 + 6)]
    return frame_summaries_message(slot, 40.0, 0, 0, frames, time.time())


def test_edge_parameters_are_listed_refused_with_reasons_and_changed_live(
        domain: LoopbackDomain, ros: RosSession) -> None:
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "vmax:=10"])
    # rclpy offers a node's parameter services as the node is made, before the edge has built
    # its cores and spins: a request then waits for the spin (measured on a loaded clean clone:
    # no answer within 30 s). The edge says it listens just before it spins
    assert domain.wait_for_log(edge, "listening on", 120), domain.log(edge)
    listed = _call(ros, ListParameters, "/edge_mapper/list_parameters",
                   ListParameters.Request()).result.names
    assert {"policy", "vmax", "alpha_mbit", "fallback_policy", "latent_max_age",
            "use_sim_time"} <= set(listed)
    described = _call(ros, DescribeParameters, "/edge_mapper/describe_parameters",
                      DescribeParameters.Request(names=["vmax", "alpha_mbit"])).descriptors
    vmax, alpha = described
    assert vmax.integer_range[0].from_value == 2 and "V_max" in vmax.description
    assert not vmax.read_only and alpha.read_only

    out_of_range, read_only, unknown = (_set(ros, vmax=1)[0], _set(ros, alpha_mbit="7")[0],
                                        _set(ros, policy="fastest")[0])
    assert not out_of_range.successful and "range" in out_of_range.reason
    assert not read_only.successful and "read-only" in read_only.reason
    assert not unknown.successful and "unknown policy 'fastest'" in unknown.reason

    requests: list[UploadRequest] = []
    ros.node.create_subscription(UploadRequest, topics.UPLOAD_REQUEST, requests.append,
                                 qos.PROTOCOL)
    pub = ros.node.create_publisher(FrameSummaries, topics.FRAME_SUMMARIES, qos.PROTOCOL)
    # known here, and matched there: a volatile reader that learns of this writer after its
    # first sample skips it (twinslam.node_runtime.matched_readers)
    matched = matched_line(topics.FRAME_SUMMARIES, 1, WRITERS)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0
                          and matched in domain.log(edge), 30.0)
    pub.publish(_summaries(0))
    assert ros.spin_until(lambda: len(requests) == 1, 30.0)
    assert requests[0].policy == "lff"                                   # the default
    assert all(r.successful for r in _set(ros, policy="pu", vmax=12))    # from the next slot
    pub.publish(_summaries(1))
    assert ros.spin_until(lambda: len(requests) == 2, 30.0)
    assert requests[1].policy == "pu"
    # accepted when set (its checkpoint may follow), but not makeable at the next slot: the
    # edge says so once and goes on with the policy it has
    assert all(r.successful for r in _set(ros, policy="mbrl"))
    for slot in (2, 3):
        pub.publish(_summaries(slot))
    assert ros.spin_until(lambda: len(requests) == 4, 30.0), domain.log(edge)[-3000:]
    assert [r.policy for r in requests[2:]] == ["pu", "pu"]
    code, _, err = domain.stop(edge)
    assert code == 0, err[-2000:]
    assert "slot 1: parameters now" in err and "V_max 12" in err
    assert err.count("cannot switch to {'policy': 'mbrl'}") == 1


def test_a_whole_number_given_to_a_float_parameter_is_refused_with_what_to_write(
        domain: LoopbackDomain) -> None:
    """``-p slot_timeout_s:=60`` is an integer to ROS and a float parameter refuses it at
    start (rclpy's rule); the error says to write 60.0."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter as RclpyParameter

    from edge_mapper.parameters import PARAMETERS
    from twinslam.node_runtime.parameters import ParameterStartError, declare

    spec = next(s for s in PARAMETERS if s.name == "slot_timeout_s")
    with RosSession("float_parameter_given_60") as session:
        node = Node("edge_mapper", context=session.context, parameter_overrides=[
            RclpyParameter("slot_timeout_s", RclpyParameter.Type.INTEGER, 60)])
        try:
            with pytest.raises(ParameterStartError, match=r"write slot_timeout_s:=60\.0"):
                declare(node, [spec])
        finally:
            node.destroy_node()


def test_a_value_given_for_a_parameter_the_node_does_not_have_is_named_in_a_warning(
        domain: LoopbackDomain, monkeypatch: pytest.MonkeyPatch) -> None:
    """A misspelt name in ``-p`` or a parameter file leaves the node on the default: the node
    says so at start, with the name it likely meant (rclpy's own parameters are no concern)."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter as RclpyParameter

    from edge_mapper.parameters import PARAMETERS
    from twinslam.node_runtime.parameters import declare

    warned: list[str] = []

    class Logger:
        def warning(self, text: str) -> None:
            warned.append(text)

    with RosSession("unread_parameter") as session:
        node = Node("edge_mapper", context=session.context, parameter_overrides=[
            RclpyParameter("vmaxx", RclpyParameter.Type.INTEGER, 20),
            RclpyParameter("use_sim_time", RclpyParameter.Type.BOOL, False)])
        monkeypatch.setattr(node, "get_logger", Logger)
        try:
            values = declare(node, PARAMETERS)
        finally:
            node.destroy_node()
    assert values["vmax"] == next(s.default for s in PARAMETERS if s.name == "vmax")
    assert warned == ["parameter vmaxx is given but edge_mapper has no such parameter "
                      "(did you mean vmax?): ignored"]
