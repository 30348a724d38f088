"""Uplink channel models: Markov statistics, interval changes, trace files and bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from twinslam.uplink.channels import (
    ChannelError,
    MarkovChannel,
    TraceChannel,
    parse_channel,
    state_rates,
    two_state_matrix,
)


def _transition_counts(states: list[int], n: int) -> np.ndarray:
    counts = np.zeros((n, n))
    for a, b in itertools.pairwise(states):
        counts[a, b] += 1
    return counts


def test_empirical_transitions_match_the_matrix_over_1e5_slots() -> None:
    matrix = np.array([[0.7, 0.2, 0.1], [0.1, 0.6, 0.3], [0.25, 0.25, 0.5]])
    chan = MarkovChannel(state_rates(3), matrix=matrix, seed=4)
    states = [chan.step()[0] for _ in range(100_000)]
    counts = _transition_counts(states, 3)
    empirical = counts / counts.sum(axis=1, keepdims=True)
    assert np.abs(empirical - matrix).max() < 0.01


def test_non_stationary_mode_changes_the_matrix_at_interval_boundaries() -> None:
    chan = MarkovChannel(state_rates(2), interval_slots=20_000, stationary=False, seed=1)
    states = [chan.step()[0] for _ in range(60_000)]
    assert len(chan.matrices) == 3
    assert np.abs(chan.matrices[0] - chan.matrices[1]).max() > 0.05
    for t, matrix in enumerate(chan.matrices):
        seg = states[t * 20_000:(t + 1) * 20_000]
        counts = _transition_counts(seg, 2)
        emp = counts / counts.sum(axis=1, keepdims=True)
        assert np.abs(emp - matrix).max() < 0.03, f"interval {t} does not follow its matrix"
    stationary = MarkovChannel(state_rates(2), interval_slots=100, seed=1)
    for _ in range(1000):
        stationary.step()
    assert len(stationary.matrices) == 1


def test_high_rate_ratio_knob_sets_the_stationary_share() -> None:
    chan = MarkovChannel(state_rates(2), matrix=two_state_matrix(0.8), seed=2)
    states = np.array([chan.step()[0] for _ in range(50_000)])
    assert states.mean() == pytest.approx(0.8, abs=0.02)


@pytest.mark.parametrize("n", [2, 4])
def test_balanced_chains_share_one_mean_rate_whatever_n(n: int) -> None:
    """Fig. 8's setting: N = 2 and N = 4 at the same mean rate (60 Mbit/s on 40-80)."""
    rates = []
    for seed in range(3):
        chan = parse_channel(f"markov:N={n},balanced", seed=seed)
        m = chan.current_matrix
        assert np.allclose(m.sum(axis=0), 1.0, atol=1e-6)   # doubly stochastic
        rates += [chan.step()[1] for _ in range(20_000)]
    assert np.mean(rates) == pytest.approx(60.0, abs=1.0)


def test_trace_replay_quantises_and_scales(tmp_path) -> None:
    path = tmp_path / "trace.csv"
    rows = ["time_s,throughput_mbps"] + [f"{t * 0.5},{10 if (t // 4) % 2 == 0 else 30}"
                                         for t in range(40)]
    path.write_text("\n".join(rows) + "\n")
    chan = TraceChannel.from_csv(path, 2, (40.0, 80.0), slot_seconds=2.0)
    rates = [chan.step()[1] for _ in range(6)]
    assert rates == [40.0, 80.0, 40.0, 80.0, 40.0, 80.0]


@pytest.mark.parametrize(("content", "message"), [
    ("", "empty"),
    ("time_s,throughput_mbps\n", "no samples"),
    ("time_s,throughput_mbps\n0,10\n1,nan\n", ":3: NaN"),
    ("time_s,throughput_mbps\n0,10\n1,-5\n", ":3: negative"),
    ("time_s,throughput_mbps\n0,10\n0,5\n", ":3: time"),
    ("t,rate\n0,10\n", ":1: header"),
    ("time_s,throughput_mbps\n0,abc\n", ":2: not a number"),
])
def test_bad_trace_files_are_refused_naming_file_and_line(tmp_path, content, message) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(ChannelError, match=message) as err:
        TraceChannel.from_csv(path, 2)
    assert "bad.csv" in str(err.value)


def test_channel_specs() -> None:
    assert isinstance(parse_channel("markov:N=4,nonstationary,K=50"), MarkovChannel)
    with pytest.raises(ChannelError, match="unknown channel"):
        parse_channel("wifi:N=2")
    with pytest.raises(ChannelError, match="ratio"):
        parse_channel("markov:N=3,ratio=0.5")
    with pytest.raises(ChannelError, match="does not exist"):
        parse_channel("trace:/nonexistent.csv")
