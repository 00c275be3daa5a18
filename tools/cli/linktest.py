"""`btf-host linktest`: a robot end and a host end through the seeded channel simulator
(`radio.linktest`)."""
from __future__ import annotations

import argparse
import dataclasses
import json

from radio.channel import ChannelConfig
from radio.linktest import run_linktest
from tools.cli.options import CliError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--loss", type=float, default=0.2, help="mean packet loss (0..1)")
    p.add_argument("--bursty", action="store_true", help="Gilbert-Elliott bursts, not independent loss")
    p.add_argument("--burst-len", type=float, default=4.0, help="mean packets per loss burst")
    p.add_argument("--ber", type=float, default=1e-4, help="bit error rate")
    p.add_argument("--dup", type=float, default=0.05, help="duplication probability")
    p.add_argument("--reorder", type=float, default=0.05, help="reordering probability")
    p.add_argument("--latency", type=float, default=0.01, help="one-way latency, seconds")
    p.add_argument("--bandwidth", type=float, default=31250.0, help="bytes per second")
    p.add_argument("--mtu", type=int, default=100, help="bytes per frame on the wire")
    p.add_argument("--packets", type=int, default=500, help="messages from robot to host")
    p.add_argument("--forged", type=int, default=50, help="forged frames to inject")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    if args.packets < 1:
        raise CliError(f"--packets must be at least 1, not {args.packets}")
    if args.forged < 0:
        raise CliError(f"--forged must not be negative, not {args.forged}")
    if not 40 <= args.mtu <= 4096:
        raise CliError(f"--mtu must be in 40..4096, not {args.mtu}")
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
