"""Link goodput against loss through the seeded channel simulator (radio.linktest.run_linktest,
as `btf-host linktest` drives it): independent and bursty loss, 0 to 40%."""
from __future__ import annotations

from benchmarks.common import Context, Section, figure, save
from radio.channel import ChannelConfig
from radio.linktest import run_linktest

LOSSES = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4)


def run(ctx: Context) -> list[Section]:
    packets = ctx.pick(400, 10)
    losses = ctx.pick(LOSSES, (0.0, 0.2))
    rows = []
    for bursty in (False, True):
        for loss in losses:
            cfg = ChannelConfig(loss=loss, bursty=bursty, ber=1e-4, dup=0.02, reorder=0.02,
                                packet_size=100, buffer=400)
            r = run_linktest(cfg, packets, seed=1, forged=5, replays=5, commands=5)
            rows.append((bursty, loss, r))
    lines = [f"{packets} messages of 150-400 B robot to host, MTU 100, 250 kbit/s, BER 1e-4, 2% duplication "
             "and reordering. Goodput: payload bytes/s over the (1 - loss) share of the bandwidth "
             "(1.0 = every surviving byte was useful payload).", "",
             "| loss | bursty | delivered | goodput | retransmissions | simulated s | corrupted/forged accepted |",
             "|---:|---|---:|---:|---:|---:|---:|"]
    for bursty, loss, r in rows:
        lines.append(f"| {loss:.0%} | {'yes' if bursty else 'no'} | {r.delivered}/{r.sent} | {r.goodput:.3f} | "
                     f"{r.retransmissions} | {r.sim_seconds:.2f} | {r.corrupted_accepted}/{r.forged_accepted} |")
    lines += ["", _plot(rows, ctx)]
    return [Section("Link: goodput against loss rate", lines)]


def _plot(rows, ctx: Context) -> str:
    fig, ax = figure(1, 1, (6.0, 4.0))
    ax = ax[0][0]
    for bursty in (False, True):
        pts = [(loss, r.goodput) for b, loss, r in rows if b == bursty]
        ax.plot([p[0] * 100 for p in pts], [p[1] for p in pts], "o-", label="bursty" if bursty else "independent")
    ax.set_xlabel("packet loss (%)")
    ax.set_ylabel("goodput / ((1 - loss) x bandwidth)")
    ax.set_ylim(0, None)
    ax.legend()
    ax.set_title("Link goodput through the channel simulator")
    return save(fig, ctx, "link.png")
