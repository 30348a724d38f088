"""``bench.edge_scaling --places``: a recorded walk replayed as a place of its own keeps the
walk's own descriptor distances (its map is built as the recording's was) and shares no
near descriptor with another place's (place recognition relates no two places); with several
edge processes each serves whole places."""

from __future__ import annotations

import math

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from twinslam_msgs.msg import Keyframe

from bench.edge_scaling import Recording, by_sharing, edge_devices


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Bits apart, every descriptor of ``a`` against every one of ``b``."""
    return np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)


def _descriptors(raw: bytes) -> np.ndarray:
    return np.asarray(deserialize_message(raw, Keyframe).descriptors,
                      dtype=np.uint8).reshape(-1, 32)


def test_a_place_of_its_own_keeps_its_walks_distances_and_nears_no_other_place() -> None:
    rng = np.random.default_rng(0)
    walk = {frame: rng.integers(0, 256, (40, 32), dtype=np.uint8) for frame in (3, 4)}
    walk[4][:10] = walk[3][:10]                        # ten features seen again,
    walk[4][:10, 0] ^= np.uint8(1)                     # a bit off
    recording = Recording({0: b""}, {0: 10.0},
                          {frame: bytes(serialize_message(Keyframe(
                              frame_id=frame, descriptors=d.reshape(-1))))
                           for frame, d in walk.items()})
    assert recording.of_place(0) is recording
    first, second = recording.of_place(1), recording.of_place(2)
    for frame, raw in first.keyframes.items():
        assert deserialize_message(raw, Keyframe).frame_id == frame
    own = [_descriptors(first.keyframes[f]) for f in (3, 4)]
    np.testing.assert_array_equal(hamming_matrix(own[0], own[1]),
                                  hamming_matrix(walk[3], walk[4]))
    assert hamming_matrix(own[0][:10], own[1][:10]).diagonal().max() == 1
    for other in (walk[3], _descriptors(second.keyframes[3])):
        across = hamming_matrix(own[0], other)
        assert across.min() > 64 and 96 < across.mean() < 160
    assert first.summaries is recording.summaries and first.slot_s == recording.slot_s


def test_each_edge_serves_whole_places_and_a_fair_share_of_the_devices() -> None:
    """Fifty devices over 38 places (k and k + 38 share one) on two edges: no place split
    between them (its maps could never merge), 25 devices each; with fewer places than
    edges, runs of neighbours as before."""
    names = [f"ar{k + 1}" for k in range(50)]
    served = edge_devices(names, 2, 38)
    assert [len(b) for b in served] == [25, 25]
    assert sorted(d for block in served for d in block) == sorted(names)
    places = [{(int(d[2:]) - 1) % 38 for d in block} for block in served]
    assert not places[0] & places[1]
    assert edge_devices(names[:6], 2, 1) == [names[:3], names[3:6]]


def test_the_fleets_figures_split_the_devices_that_share_a_place_from_those_alone() -> None:
    # five devices over four places: ar1 and ar5 walk place 0, the others a place each
    names = [f"ar{k}" for k in range(1, 6)]
    slots = [{"device": d, "slot": k, "latency_ms": 1500.0 if d == "ar5" else 300.0,
              "compute_ms": 40.0 if d in ("ar1", "ar5") else 20.0,
              "restored": 2 if d in ("ar1", "ar5") else 0,
              "lost_share": 0.5 if d == "ar5" else 0.0}
             for d in names for k in range(4) if not (d == "ar3" and k == 3)]
    split = by_sharing(slots, names, 4, 1.0, 4)
    assert (split["devices_sharing"], split["devices_alone"]) == (2, 3)
    assert split["missed_share_sharing"] == 0.5          # ar5's four slots late of eight
    assert split["missed_share_alone"] == 1 / 12         # ar3's last slot never answered
    assert (split["compute_ms_median_sharing"], split["compute_ms_median_alone"]) == (40, 20)
    assert (split["restored_a_slot_sharing"], split["restored_a_slot_alone"]) == (2, 0)
    assert (split["lost_share_sharing"], split["lost_share_alone"]) == (0.25, 0.0)
    every_place_its_own = by_sharing(slots, names, 5, 1.0, 4)
    assert every_place_its_own["devices_sharing"] == 0
    assert math.isnan(every_place_its_own["missed_share_sharing"])
