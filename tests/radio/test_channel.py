"""The channel simulator and the end-to-end bar through it."""
import pytest

from radio.channel import Channel, ChannelConfig
from radio.linktest import run_linktest

BAR = ChannelConfig(loss=0.2, bursty=True, ber=1e-4, dup=0.05, reorder=0.05)


@pytest.mark.parametrize("seed", range(5))
def test_bar_everything_once_in_order_nothing_forged_and_goodput(seed):
    r = run_linktest(BAR, packets=500, seed=seed)
    assert r.delivered == r.sent == 500
    assert r.delivered_twice == 0 and r.out_of_order == 0
    assert r.corrupted_accepted == 0 and r.forged_accepted == 0
    assert r.commands_delivered == r.commands_sent > 0
    assert r.rejected["tag"] >= r.forged_injected  # every forged frame counted
    assert r.rejected.get("replay", 0) + r.rejected.get("stale", 0) > 0
    assert r.rejected.get("crc", 0) > 0  # multi-bit errors were caught by the CRC
    assert r.repaired > 0  # single-bit errors were corrected
    assert r.goodput >= 0.65  # the bar is 0.6; seeds 0-19 measure 0.67-0.74


@pytest.mark.parametrize("bursty", [False, True])
def test_loss_rate_matches_the_configured_mean(bursty):
    ch = Channel(ChannelConfig(loss=0.3, bursty=bursty, latency=0.0), seed=1)
    for i in range(20000):
        ch.transmit(b"\x00" + bytes([1]) * 20 + b"\x00", i * 0.01)
    assert abs(ch.lost / ch.packets - 0.3) < 0.03


def test_bursty_loss_comes_in_runs():
    cfg = ChannelConfig(loss=0.2, bursty=True, burst_len=6.0, latency=0.0)
    ch = Channel(cfg, seed=2)
    lost = []
    for i in range(5000):
        before = ch.lost
        ch.transmit(b"\x00\x01\x00", i * 0.01)
        lost.append(ch.lost > before)
    runs = sum(1 for a, b in zip(lost, lost[1:]) if b and not a)
    assert sum(lost) / runs > 4.0  # mean run length near burst_len, far above 1.25


def test_bandwidth_and_latency_set_arrival_times():
    ch = Channel(ChannelConfig(latency=0.5, bandwidth=100.0), seed=0)
    ch.transmit(b"\x00" + b"\x01" * 48 + b"\x00", 0.0)  # 50 bytes: 0.5 s on the air
    assert ch.deliver(0.99) == b""
    assert len(ch.deliver(1.0)) == 50


def test_same_seed_same_channel():
    a, b = (Channel(ChannelConfig(loss=0.2, ber=1e-3, dup=0.1, reorder=0.1), seed=7) for _ in "ab")
    for ch in (a, b):
        for i in range(200):
            ch.transmit(b"\x00" + bytes(range(1, 90)) + b"\x00", i * 0.003)
    assert a.deliver(100.0) == b.deliver(100.0)


@pytest.mark.parametrize("kw", [dict(loss=1.0), dict(ber=0.7), dict(dup=-0.1), dict(bandwidth=0)])
def test_bad_configuration_is_refused(kw):
    with pytest.raises(ValueError):
        ChannelConfig(**kw)
