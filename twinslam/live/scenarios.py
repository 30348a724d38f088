"""Live scenarios: how a run plays its sequence and shapes its uplink.

On a sequence played once forward at 40–80 Mbit/s the edge's choice of keyframes decides
nothing a user sees: the device tracks from its own recent points, never comes back, and the
uplink never binds. Each scenario changes one of those:

* ``forward`` — the sequence as recorded (the default, ``make run``'s);
* ``revisit`` — forward then backward: every place is seen again after the edge's map moved
  on, so the device tracks against the keyframes the policy kept;
* ``revisit-lost`` — ``revisit`` with the lens covered for ``blank_s`` = 3 s at 70 % of the
  run (on the way back; a phone put down for a moment): tracking is lost and must be regained
  by relocalising against the edge's map wherever the camera went meanwhile (after 1 s the
  camera has rarely moved far enough for the map to matter);
* ``small-map`` — ``revisit-lost`` with an edge map of V_max = 15 keyframes instead of 45:
  on a few hundred frames 45 keyframes cover nearly every place the camera saw, whatever the
  policy keeps; 15 do not, so where the lens uncovers, the map may or may not hold it;
* ``constrained`` — ``revisit-lost`` over a 5–20 Mbit/s uplink (0–2 keyframes a slot at
  α = 5 Mbit, D_req = 0.5 s instead of 4–8).

For the paper's device (``map_source: edge``), where the kept keyframes decide tracking, the
map budget and the uplink are what bind:

* ``revisit-v25`` / ``revisit-v15`` — ``revisit`` with an edge map of 25 / 15 keyframes (the
  paper's range is 25–45: 45 covers a few hundred frames whatever the policy keeps);
* ``outages`` — ``revisit-v25`` over a replayed trace at real rates drawn per seed (regimes
  of 5–80 Mbit/s lasting ~30 s, an outage of ~3 s every ~20 s: slots that upload nothing).

Any scenario runs over an uplink family instead of its own uplink when its name says so:
``revisit-v15@lte`` (:mod:`twinslam.uplink.families`: ``table1``, ``lte``, ``mmwave``,
``constrained``); ``outages@FAMILY`` adds its ~3 s outages every ~20 s to a family's trace
(a family with outages of its own, or a Markov one, refuses).

A scenario only adds node parameters (:meth:`Scenario.node_params`); the nodes know nothing of
it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from twinslam.uplink.families import uplink_family


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    order: str = "forward"                    #: the player's order
    blank_at: float | None = None             #: a covered-lens burst starts at this share
    blank_s: float = 3.0                      #: of played frames, for this many seconds
    rate_mbps: tuple[float, float] | None = None   #: the device channel's rate range
    vmax: int | None = None                   #: the edge's V_max (None: the parameter file's)
    channel: str | None = None                #: the device's uplink channel (None: the file's)
    #: (every, seconds): the outages its channel has, which it adds to an uplink family's
    outages: tuple[float, float] | None = None

    def played_frames(self, frames: int) -> int:
        """Frames played when ``frames`` of the sequence are selected (-1 / 0: unknown)."""
        if frames <= 0:
            return frames
        return frames if self.order == "forward" else 2 * frames - 1

    def blank_burst(self, frames: int, frame_rate_hz: float) -> tuple[int, int] | None:
        """(first played position, count) of the covered-lens burst, if any."""
        played = self.played_frames(frames)
        if self.blank_at is None or played <= 0:
            return None
        count = max(1, round(self.blank_s * frame_rate_hz))
        return min(int(played * self.blank_at), max(played - count, 0)), count

    def node_params(self, frames: int, frame_rate_hz: float) -> dict[str, list[str]]:
        """The ``-p name:=value`` items this scenario adds, by node."""
        player = [f"order:={self.order}"]
        burst = self.blank_burst(frames, frame_rate_hz)
        if burst is not None:
            player.append(f"blank:={burst[0]}:{burst[1]}")
        device = ([f"rate_min:={self.rate_mbps[0]!r}", f"rate_max:={self.rate_mbps[1]!r}"]
                  if self.rate_mbps else [])
        if self.channel:
            device.append(f"channel:={self.channel}")
        edge = [f"vmax:={self.vmax}"] if self.vmax is not None else []
        return {"sequence_player": player, "device_tracker": device, "edge_mapper": edge}


SCENARIOS = {s.name: s for s in (
    Scenario("forward", "the sequence once, as recorded"),
    Scenario("revisit", "forward then backward: every place seen twice",
             order="forward_backward"),
    Scenario("revisit-lost", "revisit, the lens covered for 3 s at 70 % of the run",
             order="forward_backward", blank_at=0.7),
    Scenario("small-map", "revisit-lost with an edge map of 15 keyframes",
             order="forward_backward", blank_at=0.7, vmax=15),
    Scenario("constrained", "revisit-lost over a 5-20 Mbit/s uplink",
             order="forward_backward", blank_at=0.7, rate_mbps=(5.0, 20.0)),
    Scenario("revisit-v25", "revisit with an edge map of 25 keyframes",
             order="forward_backward", vmax=25),
    Scenario("revisit-v15", "revisit with an edge map of 15 keyframes",
             order="forward_backward", vmax=15),
    Scenario("outages", "revisit-v25 over a trace of 5-80 Mbit/s regimes with ~3 s outages",
             order="forward_backward", vmax=25,
             channel="generated:regime=30,outage_every=20,outage=3,range=5-80",
             outages=(20.0, 3.0)),
)}


def scenario(name: str) -> Scenario:
    """The scenario called ``name`` — ``NAME`` or ``NAME@FAMILY``, over an uplink family;
    ValueError naming the known ones otherwise."""
    base, at, family_name = name.partition("@")
    try:
        chosen = SCENARIOS[base]
    except KeyError:
        raise ValueError(f"unknown scenario {base!r}; known: {', '.join(SCENARIOS)}") from None
    if not at:
        return chosen
    family = uplink_family(family_name)
    if chosen.outages is not None:
        family = family.with_outages(*chosen.outages)
    return dataclasses.replace(chosen, name=name,
                               description=f"{chosen.description}, over {family.description}",
                               channel=family.channel, rate_mbps=family.rate_mbps,
                               outages=None)
