"""Uplink channel models: Markov statistics, interval changes, traces at their real rates
(outages, offsets per seed, header spellings, quantisation), the trace generator, bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from twinslam.policies.actions import MapAction
from twinslam.uplink.channels import (
    ChannelError,
    MarkovChannel,
    parse_channel,
    state_rates,
    two_state_matrix,
)
from twinslam.uplink.traces import TraceShape, generate_trace, read_trace, write_trace


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


def _trace(path, rows: list[str], header: str = "time_s,throughput_mbps") -> str:
    path.write_text("\n".join([header, *rows]) + "\n")
    return str(path)


def _constant(tmp_path, mbps: float, seconds: int = 120) -> str:
    return _trace(tmp_path / f"const{mbps:g}.csv", [f"{t},{mbps}" for t in range(seconds)])


@pytest.mark.parametrize(("mbps", "uploads"), [(10.0, 1), (80.0, 8), (0.0, 0)])
def test_a_trace_uploads_what_its_real_rate_carries(tmp_path, mbps: float, uploads: int) -> None:
    """|U_k| = ⌊d_k · D_req / α⌋ from the trace's own Mbit/s (α 5 Mbit, D_req 0.5 s), whatever
    the rate range of the Markov channels is."""
    from twinslam.covisibility.dataset import CovisibilityDataset
    from twinslam.policies.world_model import MapManagementEnv, SimConfig

    # frames up to two slots apart share points: the next slot stays tracked (uploadable)
    data = CovisibilityDataset.from_sets([set(range(i, i + 200)) for i in range(400)])
    env = MapManagementEnv(data, parse_channel(f"trace:{_constant(tmp_path, mbps)}", seed=3),
                           SimConfig(vmax=45, slots=6))
    obs, _ = env.reset(3)
    for _ in range(6):
        assert obs.rate_mbps == pytest.approx(mbps) and obs.n_upload == uploads
        obs, *_ = env.step(MapAction(obs.candidates[:obs.n_upload], obs.map_frames[:obs.n_evict]))


def test_a_10_s_outage_uploads_nothing_while_it_lasts(tmp_path) -> None:
    """40 Mbit/s, down from 20 s to 30 s: the slots inside the outage carry 0 frames, the
    slots that straddle its edges carry what their mean rate allows."""
    rows = [f"{t / 10:.1f},{0 if 200 <= t < 300 else 40}" for t in range(600)]
    chan = parse_channel(f"trace:{_trace(tmp_path / 'outage.csv', rows)},start=15", seed=0)
    rates = [chan.step()[1] for _ in range(10)]          # slots of 2 s from 15 s on
    assert rates[3:7] == [0.0] * 4                        # 21-29 s: inside the outage
    assert rates[2] == pytest.approx(20.0) and rates[7] == pytest.approx(20.0)   # 19-21, 29-31
    assert rates[0] == rates[1] == rates[8] == pytest.approx(40.0)
    from twinslam.uncertainty.map_uncertainty import theorem1_cardinalities
    assert [theorem1_cardinalities(r, 5.0, 0.5, 45, 45, 60)[0] for r in rates[3:7]] == [0] * 4


def test_seeds_start_at_their_own_offsets_unless_a_start_is_given(tmp_path) -> None:
    path = _trace(tmp_path / "ramp.csv", [f"{t},{t % 97}" for t in range(600)])
    firsts = {round(parse_channel(f"trace:{path}", seed=s).step()[1], 3) for s in range(6)}
    assert len(firsts) == 6
    fixed = {parse_channel(f"trace:{path},start=10", seed=s).step()[1] for s in range(3)}
    assert fixed == {10.5}                      # mean of 10 and 11 over 10-12 s
    chan = parse_channel(f"trace:{path}", seed=4)
    first = [chan.step() for _ in range(5)]
    chan.reset(4)
    assert [chan.step() for _ in range(5)] == first    # a seed replays its own stretch


def test_states_come_from_the_traces_quantiles_or_a_given_range(tmp_path) -> None:
    rows = [f"{t},{[0, 10, 20, 60][(t // 20) % 4]}" for t in range(400)]
    path = _trace(tmp_path / "levels.csv", rows)
    chan = parse_channel(f"trace:{path},N=4,start=0", seed=0)
    seen = {chan.step() for _ in range(40)}
    assert seen == {(0, 0.0), (1, 10.0), (2, 20.0), (3, 60.0)}
    assert chan.rates.tolist() == [0.0, 10.0, 20.0, 60.0]
    even = parse_channel(f"trace:{path},N=2,states=0-80,start=0", seed=0)
    assert {even.step() for _ in range(40)} == {(0, 0.0), (0, 10.0), (0, 20.0), (1, 60.0)}


def test_rescaling_into_a_range_happens_only_when_asked(tmp_path) -> None:
    path = _trace(tmp_path / "two.csv", [f"{t * 0.5},{10 if (t // 4) % 2 == 0 else 30}"
                                         for t in range(40)])
    real = parse_channel(f"trace:{path},start=0", seed=0)
    assert [real.step()[1] for _ in range(4)] == [10.0, 30.0, 10.0, 30.0]
    scaled = parse_channel(f"trace:{path},rescale,start=0", (40.0, 80.0), seed=0)
    assert [scaled.step()[1] for _ in range(4)] == [40.0, 80.0, 40.0, 80.0]


@pytest.mark.parametrize(("header", "row", "mbps"), [
    ("time_s,throughput_mbps", "{t},12", 12.0),
    ("Time (s),Throughput (Mbit/s)", "{t},12", 12.0),
    ("timestamp,bandwidth_kbps", "{t},12000", 12.0),
    ("time_ms,rate_mbps", "{t}000,12", 12.0),
    ("t,bw", "{t},12", 12.0),
    ("seconds,bitrate (bps)", "{t},12000000", 12.0),
    ("elapsed,cell_id,tput", "{t},7,12", 12.0),
])
def test_common_trace_header_spellings_are_read(tmp_path, header: str, row: str,
                                                mbps: float) -> None:
    path = _trace(tmp_path / "h.csv", [row.format(t=t) for t in range(20)], header)
    chan = parse_channel(f"trace:{path},start=0", seed=0)
    assert chan.step()[1] == pytest.approx(mbps)
    assert chan.duration_s == pytest.approx(20.0)


@pytest.mark.parametrize(("content", "message"), [
    ("", "empty"),
    ("time_s,throughput_mbps\n", "at least two samples"),
    ("time_s,throughput_mbps\n0,10\n1,nan\n", ":3: NaN"),
    ("time_s,throughput_mbps\n0,10\n1,-5\n", ":3: negative"),
    ("time_s,throughput_mbps\n0,10\n0,5\n", ":3: time"),
    ("when,what\n0,10\n", ":1: header .* names no time column"),
    ("time,cell\n0,10\n", ":1: header .* names no throughput column"),
    ("time_s,throughput_mbps\n0,abc\n", ":2: not a number"),
])
def test_bad_trace_files_are_refused_naming_file_and_line(tmp_path, content, message) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(ChannelError, match=message) as err:
        parse_channel(f"trace:{path}")
    assert "bad.csv" in str(err.value)


def test_generated_traces_have_regimes_and_outages_and_round_trip(tmp_path) -> None:
    shape = TraceShape(seconds=300, outages=((100.0, 10.0),), outage_every_s=60.0)
    times, mbps = generate_trace(shape, seed=2)
    assert np.all(mbps[(times >= 100) & (times < 110)] == 0.0)
    assert (mbps == 0).mean() > 10 / 300                  # the random outages too
    up = mbps[mbps > 0]
    assert up.min() >= 0 and np.percentile(up, 90) > 2 * np.percentile(up, 10)   # regimes
    write_trace(tmp_path / "g.csv", times, mbps)
    _times, back_v = read_trace(tmp_path / "g.csv")
    np.testing.assert_allclose(back_v, mbps, atol=1e-4)
    assert np.array_equal(generate_trace(shape, seed=2)[1], mbps)
    assert not np.array_equal(generate_trace(shape, seed=3)[1], mbps)


def test_channel_specs() -> None:
    assert isinstance(parse_channel("markov:N=4,nonstationary,K=50"), MarkovChannel)
    with pytest.raises(ChannelError, match="unknown channel"):
        parse_channel("wifi:N=2")
    with pytest.raises(ChannelError, match="ratio"):
        parse_channel("markov:N=3,ratio=0.5")
    with pytest.raises(ChannelError, match="does not exist"):
        parse_channel("trace:/nonexistent.csv")
    with pytest.raises(ChannelError, match="unknown option"):
        parse_channel("trace:/nonexistent.csv,scale")


def test_trace_cli_generates_describes_and_feeds_the_simulator(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    from twinslam.cli.main import main

    out = tmp_path / "gen.csv"
    assert main(["trace", "generate", "-o", str(out), "--seconds", "120", "--outage",
                 "30:10", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    assert f"wrote {out}" in text and "of slots down" in text and "thresholds" in text
    assert main(["trace", "info", str(tmp_path / "missing.csv")]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["trace", "generate", "-o", str(tmp_path / "x.csv"), "--outage", "30"])
    csv_out = tmp_path / "sim.csv"
    assert main(["sim", "--covis", "geometric:300", "--channel", f"trace:{out}", "--slots",
                 "4", "--seeds", "2", "--policy", "lff", "--csv", str(csv_out)]) == 0
    assert len(csv_out.read_text().splitlines()) == 3


def test_a_generated_trace_replays_real_rates_with_outages_drawn_from_the_seed() -> None:
    """generated:... draws regimes and outages from the seed and replays them like a trace file:
    the same seed the same rates, another seed others, an outage slot 0 Mbit/s (nothing
    uploads); a bad option is refused with the options there are."""
    spec = "generated:regime=30,outage_every=20,outage=3,range=5-80"
    first = [parse_channel(spec, seed=4).step()[1] for _ in range(1)]
    a = parse_channel(spec, seed=4)
    rates = [a.step()[1] for _ in range(200)]
    b = parse_channel(spec, seed=4)
    assert [b.step()[1] for _ in range(200)] == rates and rates[:1] == first
    c = parse_channel(spec, seed=5)
    assert [c.step()[1] for _ in range(200)] != rates
    assert 0.0 in rates, "no outage in 400 s at one every ~20 s"
    # the simulator re-seeds one channel per episode: reset(4) replays the device's seed 4
    c.reset(4)
    assert [c.step()[1] for _ in range(200)] == rates
    assert max(rates) <= 80 * 1.6 and np.mean(rates) > 5.0
    with pytest.raises(ChannelError, match=r"unknown option.*outage_every="):
        parse_channel("generated:every=20")
    with pytest.raises(ChannelError, match="range= takes MIN-MAX"):
        parse_channel("generated:range=80")
