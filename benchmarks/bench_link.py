"""Link goodput against loss (independent and bursty) through the seeded channel simulator."""
from __future__ import annotations

import time

from radio.channel import ChannelConfig, run_linktest


def run() -> list[str]:
    lines = ["## Link goodput against loss", "",
             "500 messages of 150-400 bytes robot to host, 20 commands back, MTU 100, "
             "250 kbit/s, 10 ms latency, BER 1e-4, 5% duplication, 5% reordering, seeds 0-2. "
             "Goodput is payload bytes/s over (1 - loss) x bandwidth.", "",
             "| loss | bursty | goodput (min..max) | delivered | twice | corrupted | forged | "
             "retransmissions | sim s | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for loss in (0.0, 0.1, 0.2, 0.3, 0.4):
        for bursty in (False, True):
            if loss == 0.0 and bursty:
                continue
            cfg = ChannelConfig(loss=loss, bursty=bursty, ber=1e-4, dup=0.05, reorder=0.05)
            t0 = time.perf_counter()
            rs = [run_linktest(cfg, 500, seed) for seed in range(3)]
            wall = (time.perf_counter() - t0) / len(rs)
            g = [r.goodput for r in rs]
            lines.append(
                f"| {loss:.1f} | {'yes' if bursty else 'no'} | {min(g):.3f}..{max(g):.3f} | "
                f"{min(r.delivered for r in rs)}/500 | {sum(r.delivered_twice for r in rs)} | "
                f"{sum(r.corrupted_accepted for r in rs)} | {sum(r.forged_accepted for r in rs)} | "
                f"{sum(r.retransmissions for r in rs) // len(rs)} | "
                f"{sum(r.sim_seconds for r in rs) / len(rs):.1f} | {wall:.2f} |")
    return lines


if __name__ == "__main__":
    print("\n".join(run()))
