"""The device's uplink from its parameters: the channel model that draws d_k and the shaper
that paces the uploads at it. Errors are ValueError with the reason (the node refuses to
start with it)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from twinslam.uplink.channels import (
    ChannelError,
    MarkovChannel,
    TraceChannel,
    initial_rate,
    parse_channel,
)
from twinslam.uplink.shaper import ShaperError, UplinkShaper
from twinslam.uplink.tc_shaper import NetemConfig, TcShaper, make_shaper


def uplink_from_parameters(p: Mapping[str, Any], flush: Callable[[], object]
                           ) -> tuple[MarkovChannel | TraceChannel, UplinkShaper | TcShaper]:
    """The channel (``channel``, ``rate_min``/``rate_max``, ``seed``) and the shaper
    (``shaper``, ``uplink_interface``, netem impairments), starting at the channel's first
    rate; ``flush`` waits for the keyframes in flight (the tc shaper calls it before a rate
    change)."""
    try:
        # a trace advances one of the device's slots a slot: its real rates, whatever F is
        channel = parse_channel(str(p["channel"]), (float(p["rate_min"]), float(p["rate_max"])),
                                int(p["seed"]),
                                float(p["slot_frames"]) / float(p["frame_rate_hz"]))
        shaper = make_shaper(str(p["shaper"]), initial_rate(channel), str(p["uplink_interface"]),
                             NetemConfig(float(p["netem_delay_ms"]),
                                         float(p["netem_loss_percent"])), flush=flush)
    except (ChannelError, ShaperError) as exc:
        raise ValueError(str(exc)) from None
    return channel, shaper
