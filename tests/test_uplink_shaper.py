"""The uplink shaper: uploads take the time the slot's rate gives them, on virtual and on real
time."""

from __future__ import annotations

import time

import pytest

from twinslam.uplink.shaper import ShaperError, UplinkShaper
from twinslam.uplink.tc_shaper import NetemConfig, TcShaper, interface_tx_bytes, run_tc

ALPHA_BYTES = 5_000_000 // 8          # the paper's 5 Mbit keyframe payload


class VirtualTime:
    """A clock that only moves when slept on."""

    def __init__(self) -> None:
        self.now = 100.0

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_each_upload_takes_bytes_over_rate_and_queues_behind_the_last() -> None:
    t = VirtualTime()
    link = UplinkShaper(t.clock, t.sleep)
    link.start_slot(0, rate_mbps=40.0, rate_state=0)
    delivered: list[float] = []
    took = [link.send(ALPHA_BYTES, lambda: delivered.append(t.now)) for _ in range(4)]
    assert took == pytest.approx([0.125] * 4)               # 5 Mbit at 40 Mbit/s
    assert delivered == pytest.approx([100.125, 100.25, 100.375, 100.5])
    slot = link.end_slot()
    assert (slot.slot, slot.frames_sent, slot.bytes_sent) == (0, 4, 4 * ALPHA_BYTES)
    assert slot.achieved_mbps == pytest.approx(40.0)
    # the next slot is faster, and an idle link does not bank credit for a burst
    link.start_slot(1, rate_mbps=80.0, rate_state=1)
    t.sleep(1.0)
    assert link.send(ALPHA_BYTES, lambda: None) == pytest.approx(0.0625)
    slot = link.end_slot()
    assert slot.configured_rate_mbps == 80.0 and slot.rate_state == 1
    assert slot.achieved_mbps == pytest.approx(5.0 / 1.0625)   # idle second counts


def test_a_new_slot_rate_applies_to_the_next_payload_and_resets_the_counts() -> None:
    t = VirtualTime()
    link = UplinkShaper(t.clock, t.sleep)
    link.start_slot(0, rate_mbps=40.0)
    link.send(ALPHA_BYTES, lambda: None)
    link.start_slot(1, rate_mbps=80.0)
    assert link.send(ALPHA_BYTES, lambda: None) == pytest.approx(0.0625)
    assert link.end_slot().frames_sent == 1


def test_bad_rates_and_sizes_are_refused() -> None:
    link = UplinkShaper()
    with pytest.raises(ShaperError, match="start_slot"):
        link.send(10, lambda: None)
    for bad in (0.0, -5.0, float("nan"), float("inf")):
        with pytest.raises(ShaperError, match="slot 3"):
            link.start_slot(3, bad)
    link.start_slot(3, 10.0)
    with pytest.raises(ShaperError, match=">= 0 bytes"):
        link.send(-1, lambda: None)
    # a payload carried besides the keyframes is refused alike
    with pytest.raises(ShaperError, match="carried payload"):
        link.carry(10, lambda: None, 0.0)
    with pytest.raises(ShaperError, match=">= 0 bytes"):
        link.carry(-1, lambda: None, 10.0)


def test_real_time_uploads_are_paced() -> None:
    """On the real clock: ten 0.25 Mbit payloads at 50 Mbit/s take at least 50 ms (no upper
    bound: a loaded machine may take longer, and that is not the shaper's doing)."""
    link = UplinkShaper()
    link.start_slot(0, rate_mbps=50.0)
    start = time.monotonic()
    for _ in range(10):
        link.send(250_000 // 8, lambda: None)
    elapsed = time.monotonic() - start
    assert elapsed >= 0.05
    assert link.end_slot().achieved_mbps <= 50.0 * 1.0001


class FakeInterface:
    """``tc`` and the interface counter as a kernel would see them, without a kernel."""

    def __init__(self) -> None:
        self.commands: list[tuple[str, ...]] = []
        self.tx = 1000

    def tc(self, *args: str) -> None:
        self.commands.append(args)


def test_tc_shaper_sets_the_slots_rate_once_and_measures_the_interface() -> None:
    t = VirtualTime()
    nic = FakeInterface()
    acked: list[float] = []

    def flush() -> None:                # all keyframes acknowledged 0.5 s after the writes
        t.sleep(0.5)
        nic.tx += 5_000_000            # 40 Mbit went out meanwhile
        acked.append(t.now)

    shaper = TcShaper("eth0", NetemConfig(delay_ms=2, loss_percent=5), flush, nic.tc,
                      lambda: nic.tx, t.clock)
    shaper.start(40.0)
    assert nic.commands[0][:9] == ("qdisc", "replace", "dev", "eth0", "root", "handle", "1:",
                                   "tbf", "rate")
    assert nic.commands[0][9] == "40000kbit"
    assert nic.commands[1][-5:] == ("netem", "delay", "2ms", "loss", "5%")
    shaper.start_slot(0, 40.0, 0)                  # same rate: no tc call
    assert len(nic.commands) == 2
    shaper.send(625_000, lambda: None)
    shaper.send(625_000, lambda: None)
    out = shaper.end_slot()
    assert acked and out.frames_sent == 2 and out.bytes_sent == 5_000_000
    assert out.achieved_mbps == pytest.approx(80.0)   # 40 Mbit in 0.5 s
    shaper.start_slot(1, 80.0, 1)
    assert nic.commands[-1][1] == "change" and nic.commands[-1][9] == "80000kbit"
    empty = shaper.end_slot()                       # nothing asked for: nothing flushed
    assert empty.frames_sent == 0 and empty.bytes_sent == 0 and len(acked) == 1
    shaper.close()
    assert nic.commands[-1] == ("qdisc", "del", "dev", "eth0", "root")


def test_tc_shaper_refuses_bad_rates_impairments_and_interfaces(tmp_path) -> None:
    nic = FakeInterface()
    shaper = TcShaper("eth0", tc=nic.tc, tx_bytes=lambda: nic.tx)
    for bad in (0.0, -5.0, float("nan"), float("inf")):
        with pytest.raises(ShaperError, match="finite and > 0"):
            shaper.start_slot(3, bad)
    with pytest.raises(ShaperError, match="no slot started"):
        shaper.send(10, lambda: None)
    with pytest.raises(ShaperError, match="loss"):
        NetemConfig(loss_percent=100)
    with pytest.raises(ShaperError, match="delay"):
        NetemConfig(delay_ms=-1)
    dev = tmp_path / "dev"
    dev.write_text("Inter-|   Receive\n face |bytes\n    lo: 1 2 3 4 5 6 7 8 9 10 11 12 13 14 "
                   "15 16\n  eth0: 10 1 0 0 0 0 0 0 4242 7 0 0 0 0 0 0\n")
    assert interface_tx_bytes("eth0", dev) == 4242
    with pytest.raises(ShaperError, match="no interface 'wlan0'"):
        interface_tx_bytes("wlan0", dev)
    with pytest.raises(ShaperError, match="shaper:=token_bucket"):
        run_tc("qdisc", "replace", "dev", "no-such-interface-here", "root", "tbf", "rate",
               "1mbit", "burst", "10kb", "latency", "10ms")
