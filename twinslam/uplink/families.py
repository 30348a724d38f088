"""Uplink families: the kinds of uplink a default device is judged over, each a channel spec
(:func:`~twinslam.uplink.channels.parse_channel`) drawn anew per seed.

One channel tunes a device to that channel. The configuration the project once tuned on Table
I's Markov chain starved on a held-out LTE trace (2 uploads in 19 slots) and lost its map on a
5G mmWave one; a default is only as good as the worst family it was measured on.

* ``table1`` — the paper's Table I: a two-state Markov chain between 40 and 80 Mbit/s;
* ``lte`` — an LTE-like driving uplink: regimes of 5–45 Mbit/s lasting ~8 s (uniform means:
  an eighth of the regimes under 10 Mbit/s), 25 % noise around each;
* ``mmwave`` — a mmWave-like uplink: regimes of 50–500 Mbit/s, blockages to 0 Mbit/s lasting
  1–20 s (uniform) every ~60 s;
* ``constrained`` — 5–20 Mbit/s regimes of ~10 s: 0–2 keyframes a slot at Table I's α and
  D_req (none under 10 Mbit/s without the progress rule).

``twinslam trace family NAME --seed S`` describes the trace a family draws for a seed: its
per-slot rates, the share of slots down and under 10 Mbit/s. A live scenario runs over a
family when its name says so (``revisit-v15@lte``, :mod:`twinslam.live.scenarios`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class UplinkFamily:
    name: str
    description: str
    channel: str                     #: the device's ``channel`` parameter
    #: the Markov chain's rate range (the device's ``rate_min`` / ``rate_max``); None: the
    #: trace's own rates
    rate_mbps: tuple[float, float] | None = None

    def with_outages(self, every_s: float, length_s: float) -> UplinkFamily:
        """The family with outages of ~``length_s`` (exponential) every ~``every_s``; a
        Markov family has none to add (ValueError)."""
        kind, _, options = self.channel.partition(":")
        if kind != "generated":
            raise ValueError(f"uplink family {self.name!r} is a Markov chain: outages apply to "
                             "a generated trace only")
        if "outage" in options:
            raise ValueError(f"uplink family {self.name!r} has outages of its own")
        return UplinkFamily(self.name, f"{self.description}, an outage of ~{length_s:g} s "
                            f"every ~{every_s:g} s",
                            f"{self.channel},outage_every={every_s:g},outage={length_s:g}")


FAMILIES = {f.name: f for f in (
    UplinkFamily("table1", "Table I's two-state Markov chain, 40-80 Mbit/s", "markov:N=2",
                 (40.0, 80.0)),
    UplinkFamily("lte", "LTE-like driving: 5-45 Mbit/s regimes of ~8 s",
                 "generated:regime=8,range=5-45,noise=0.25,N=2"),
    UplinkFamily("mmwave", "mmWave-like: 50-500 Mbit/s, blockages to 0 of 1-20 s every ~60 s",
                 "generated:regime=10,range=50-500,noise=0.2,outage_every=60,outage=1-20,N=2"),
    UplinkFamily("constrained", "5-20 Mbit/s regimes of ~10 s",
                 "generated:regime=10,range=5-20,noise=0.15,N=2"),
)}


def uplink_family(name: str) -> UplinkFamily:
    """The family called ``name``; ValueError naming the known ones otherwise."""
    try:
        return FAMILIES[name]
    except KeyError:
        raise ValueError(f"unknown uplink family {name!r}; known: {', '.join(FAMILIES)}"
                         ) from None
