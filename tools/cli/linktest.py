"""`btf-host linktest`: a robot end and a host end through the seeded channel simulator
(`radio.linktest`)."""
from __future__ import annotations

import argparse
import dataclasses
import json

from onboard.cli.runner import SEED, bounded
from radio.channel import ChannelConfig
from radio.linktest import run_linktest
from tools.cli.options import CliError

MAX_PACKETS = 100_000  # the simulation keeps every message: a bound on its memory and time


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--loss", type=bounded(float, 0, 0.99), default=0.2, help="mean packet loss (0..0.99)")
    p.add_argument("--bursty", action="store_true", help="Gilbert-Elliott bursts, not independent loss")
    p.add_argument("--burst-len", type=bounded(float, 1, 1000, "packets"), default=4.0,
                   help="mean packets per loss burst (1..1000)")
    p.add_argument("--ber", type=bounded(float, 0, 0.1), default=1e-4, help="bit error rate (0..0.1)")
    p.add_argument("--dup", type=bounded(float, 0, 0.99), default=0.05, help="duplication probability (0..0.99)")
    p.add_argument("--reorder", type=bounded(float, 0, 0.99), default=0.05,
                   help="reordering probability (0..0.99)")
    p.add_argument("--latency", type=bounded(float, 0.0001, 60, "s"), default=0.01,
                   help="one-way latency, seconds (0.0001..60)")
    p.add_argument("--bandwidth", type=bounded(float, 100, 1e8, "bytes/s"), default=31250.0,
                   help="bytes per second (100..1e8)")
    p.add_argument("--mtu", type=bounded(int, 40, 4096, "bytes"), default=100,
                   help="bytes per frame on the wire (40..4096)")
    p.add_argument("--packets", type=bounded(int, 1, MAX_PACKETS, "messages"), default=500,
                   help=f"messages from robot to host (1..{MAX_PACKETS}; about a millisecond each)")
    p.add_argument("--forged", type=bounded(int, 0, MAX_PACKETS, "frames"), default=50,
                   help=f"forged frames to inject (0..{MAX_PACKETS})")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the simulated channel (the same seed, the same run)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    try:
        cfg = ChannelConfig(loss=args.loss, bursty=args.bursty, burst_len=args.burst_len,
                            ber=args.ber, dup=args.dup, reorder=args.reorder,
                            latency=args.latency, bandwidth=args.bandwidth,
                            packet_size=args.mtu, buffer=4 * args.mtu)
    except ValueError as exc:
        raise CliError(str(exc)) from None

    result = run_linktest(cfg, args.packets, args.seed, forged=args.forged, mtu=args.mtu)
    report = dataclasses.asdict(result)
    if args.json:
        print(json.dumps(report, sort_keys=True))
    else:
        for k, v in report.items():
            print(f"{k:20} {round(v, 4) if isinstance(v, float) else v}")
    ok = (result.delivered == result.sent and result.delivered_twice == 0
          and result.corrupted_accepted == 0 and result.forged_accepted == 0)
    return 0 if ok else 1
