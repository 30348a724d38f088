"""Uplink families: each draws the uplink its name promises, and a live scenario runs over one
when its name says so — the device gets the family's channel, the scenario keeps its walk."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.live.scenarios import scenario
from twinslam.uplink.channels import TraceChannel, parse_channel
from twinslam.uplink.families import FAMILIES


def _slots(name: str, seed: int) -> np.ndarray:
    chan = parse_channel(FAMILIES[name].channel, seed=seed)
    assert isinstance(chan, TraceChannel)
    chan.reset(seed)
    return chan.slot_rates()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_family_draws_the_uplink_it_describes(seed: int) -> None:
    lte, mmwave, constrained = (_slots(n, seed) for n in ("lte", "mmwave", "constrained"))
    # LTE-like: never down, rates within its regimes (noise around 5-45), some under 10
    assert lte.min() > 0 and 3 < np.median(lte) < 45 and 0.02 < np.mean(lte < 10) < 0.3
    # mmWave-like: fast between blockages that take whole slots down
    up = mmwave[mmwave > 0]
    assert np.median(up) > 50 and 0.02 < np.mean(mmwave == 0) < 0.4
    # constrained: 0-2 keyframes a slot at Table I's alpha and D_req
    assert constrained.min() > 0 and constrained.max() < 30 and np.mean(constrained < 10) > 0.1
    assert parse_channel(FAMILIES["table1"].channel, FAMILIES["table1"].rate_mbps).rates \
        .tolist() == [40.0, 80.0]


def test_a_scenario_over_a_family_gives_the_device_the_familys_channel() -> None:
    over = scenario("revisit-v15@lte")
    assert over.vmax == 15 and over.order == "forward_backward"    # the scenario's walk
    device = over.node_params(300, 30.0)["device_tracker"]
    assert device == [f"channel:={FAMILIES['lte'].channel}"]
    table1 = scenario("revisit-v25@table1").node_params(300, 30.0)["device_tracker"]
    assert table1 == ["rate_min:=40.0", "rate_max:=80.0", "channel:=markov:N=2"]
    # the outages scenario adds its outages to a family's trace, and refuses where none fit
    outages = scenario("outages@lte").channel
    assert outages is not None and outages.endswith("outage_every=20,outage=3")
    for refused in ("outages@table1", "outages@mmwave"):
        with pytest.raises(ValueError, match="outage"):
            scenario(refused)
    with pytest.raises(ValueError, match="unknown uplink family 'wifi'"):
        scenario("revisit@wifi")
    with pytest.raises(ValueError, match="unknown scenario 'nowhere'"):
        scenario("nowhere@lte")


def test_a_device_with_short_slots_replays_a_trace_at_its_real_speed() -> None:
    """A device of 1 s slots (30 frames at 30 Hz) steps its trace a second a slot: the
    blockages of the mmWave family last as long in its run as in the trace (stepped 2 s a
    slot, as a channel's default, they had passed twice as fast)."""
    from device_tracker.parameters import PARAMETERS
    from device_tracker.uplink_setup import uplink_from_parameters

    params = {p.name: p.default for p in PARAMETERS}
    params.update(channel=FAMILIES["mmwave"].channel, slot_frames=30, seed=2)
    channel, _ = uplink_from_parameters(params, lambda: None)
    assert isinstance(channel, TraceChannel) and channel.slot_seconds == 1.0
    channel.reset(2)
    stepped = [channel.step()[1] for _ in range(60)]
    assert stepped == pytest.approx([channel.rate_over(float(s), 1.0) for s in range(60)])
