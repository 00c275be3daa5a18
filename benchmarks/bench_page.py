"""The operator's page in a real browser (Debian's chromium, driven by Playwright): page load to
first paint and to the chosen capture's pictures with 500 captures in the database (bar: under
1 s), and live-update latency, from a packet stored to the page showing it (bar: under 300 ms).

Load: each round starts a station on a database of 500 captures (10 sweeps of 50 poses) with its
page, and opens the address it prints, as an operator does: nothing drawn yet, nothing in the
browser's cache. First paint is the browser's first-contentful-paint; "data drawn" is when the
first pushed state (every pose's latest capture, the link, the robot, the sweep) is on the page;
"chosen capture's pictures" when the pictures of the capture the page selects (the newest: its
synthesis) have loaded, then its histograms (a plot, drawn after); "every card's picture" when all
50 cards' have; all from the navigation's start.

Latency: a fake robot sweeps over a pty cable to the station; for each capture, the station's
log gives the time it was stored (the turn's clock, taken just before the store: the latency
is if anything overstated) and the page the time its card was drawn (`window.btfPage.shown`);
one machine, one wall clock.
"""
from __future__ import annotations

import json
import signal
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.browser import available, chromium, page_address
from benchmarks.common import Context, Section, verdict

ROOT = Path(__file__).resolve().parents[1]
LOAD_BAR_S = 1.0
LATENCY_BAR_MS = 300.0
ROBOT = ('[hal]\nbody = "fake"\nscene = "mixed"\nsize = [60, 80]\n[link]\nkey_file = "robot.key"\n'
         'heartbeat_s = 0.2\nfailsafe_s = 30\n[segment]\nmethod = "scene"\n[skip]\nmin_pixels = 20\n'
         'skip_measured_pose = false\n[sweep]\nautostart = false\n')


def _python(module: str) -> list[str]:
    return [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())"]


def fill(db: Path, captures: int) -> None:
    """`captures` captures of one robot: sweeps of 50 poses (10 elevations x 5 azimuths), the
    models of a fake render, the label map with the first."""
    from btf.fit.fitter import FrameFitter
    from hal.interfaces import ViewAngles
    from hal.scene import render
    from tools.station.receiver import mask_key
    from tools.store.database import Store

    view = render("mixed", ViewAngles(60.0, 0.0), (60, 80), seed=0)
    fitter = FrameFitter(4, 3)
    fitter.add(view.image, view.mask)
    fits = fitter.fit()
    poses = [(90.0 - 6.0 * i, 72.0 * a) for a in range(5) for i in range(10)]
    with Store.open(db) as store, store.batch():
        store.add_mask(mask_key(1), view.mask, "1")
        for seq in range(1, captures + 1):
            el, az = poses[(seq - 1) % len(poses)]
            store.add_capture("1", seq, 1.7e9 + seq, (el, az), (el + 0.1, az + 0.2), "rgb", ("R", "G", "B"), fits,
                              scene="mixed")


class Station:
    """A station process with its page, on one end of a pty cable."""

    def __init__(self, where: Path, db: Path, *argv: str) -> None:
        from radio.keys import write_key
        from tools.demo.pty_cable import PtyCable

        self.where, self.cable = where, PtyCable()
        self.key = write_key(where / "robot.key") if not (where / "robot.key").exists() else where / "robot.key"
        self.err = where / "station.err"
        self.proc = subprocess.Popen([*_python("tools.cli"), "station", "--port", self.cable.paths[1], "--db", str(db),
                                      "--key", str(self.key), "--http", "127.0.0.1:0", *argv],
                                     cwd=ROOT, stdout=subprocess.DEVNULL, stderr=open(self.err, "wb"))
        self.url = page_address(self.err)
        self.base = self.url.split("?")[0]
        self.log = Path(str(db) + ".log")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=30)
        self.cable.close()


MARKS = ("first-contentful-paint", "btf-first-data", "btf-selected-views", "btf-selected-pictures",
         "btf-card-pictures")


def load_times(where: Path, captures: int, rounds: int) -> list[tuple[float, ...]]:
    """Seconds from navigation to each of MARKS, one tuple per round (a fresh station each)."""
    db = where / "load.db"
    fill(db, captures)
    out = []
    with chromium() as page:
        for _ in range(rounds):
            station = Station(where, db, "--status-every", "0")
            try:
                page.goto(station.url)  # the address the station printed: its token for the cookie, then the page
                page.wait_for_function("() => performance.getEntriesByName('btf-card-pictures').length > 0",
                                       timeout=60_000)
                t = page.evaluate(f"""() => [...{list(MARKS)!r}.map((m) => performance.getEntriesByName(m)[0].startTime),
                                             document.querySelectorAll('#cards .card').length]""")
            finally:
                station.close()
            assert t[-1] == min(captures, 50), t  # every pose's latest capture is on the page
            out.append(tuple(v / 1e3 for v in t[:-1]))
    return out


def latencies(where: Path, poses: int) -> list[float]:
    """Milliseconds from each capture stored to its card drawn, over a sweep of `poses` poses."""
    (where / "robot.toml").write_text(ROBOT)
    db = where / "live.db"
    station = Station(where, db, "--status-every", "1")
    with open(where / "robot.err", "wb") as err:
        robot = subprocess.Popen([*_python("onboard.cli"), "run", "--config", str(where / "robot.toml"), "--port",
                                  station.cable.paths[0], "--max-seconds", "300"], cwd=ROOT,
                                 stdout=subprocess.DEVNULL, stderr=err)
    try:
        with chromium() as page:
            page.goto(station.url)
            page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link up'",
                                   timeout=60_000)
            els = ",".join(f"{90.0 - i * 60.0 / max(1, poses - 1):.1f}" for i in range(poses))
            page.fill("form[data-command=SWEEP] input[name=elevations]", els)
            page.click("form[data-command=SWEEP] button")
            page.wait_for_function(f"() => Object.keys(window.btfPage.shown).length >= {poses}", timeout=120_000)
            shown = page.evaluate("window.btfPage.shown")
    finally:
        robot.send_signal(signal.SIGTERM)
        robot.wait(timeout=30)
        station.close()
    stored = {f"{e['robot']}:{e['seq']}": e["t"] for e in map(json.loads, station.log.read_text().splitlines())
              if e["kind"] == "capture" and e.get("stored")}
    return [(shown[k] / 1e3 - t) * 1e3 for k, t in stored.items() if k in shown]


def run(ctx: Context | None = None) -> Section:
    ctx = ctx or Context()
    if not available():
        return Section("Operator page", ["Not run: Debian's chromium is missing (`make browser` installs it)."])
    captures, rounds, poses = ctx.pick(500, 50), ctx.pick(7, 1), ctx.pick(30, 4)
    with tempfile.TemporaryDirectory(prefix="bench-page-") as tmp:
        load = load_times(Path(tmp), captures, rounds)
        lat = latencies(Path(tmp), poses)
    median = [statistics.median(t[i] for t in load) for i in range(len(MARKS))]
    worst = [max(t[i] for t in load) for i in range(len(MARKS))]
    p90 = float(np.percentile(lat, 90))
    lines = [f"Headless chromium{' (--quick: shrunk)' if ctx.quick else ''} on this machine; the station a "
             "separate process, the page served in its event loop.", "",
             f"**Page load with {captures} captures in the database** ({rounds} rounds, each a freshly started "
             "station's page opened at the address it printed):", "",
             "| from navigation start | median ms | worst ms |", "|---|---:|---:|",
             *(f"| {what} | {m * 1e3:.0f} | {w * 1e3:.0f} |" for what, m, w in zip(
                 ("first contentful paint", "every pose's latest capture, link, robot and sweep drawn",
                  "the chosen capture's pictures (its synthesis) loaded",
                  "... and its histograms with the Johnson curves (a plot)", "every card's picture loaded"),
                 median, worst)), "",
             f"**First paint {median[0] * 1e3:.0f} ms, data drawn {median[1] * 1e3:.0f} ms, the chosen capture's "
             f"pictures {median[2] * 1e3:.0f} ms (worst {worst[2] * 1e3:.0f} ms)** (bar < {LOAD_BAR_S * 1e3:.0f} ms: "
             f"{verdict(worst[2], LOAD_BAR_S)}); its histograms {median[3] * 1e3:.0f} ms (worst "
             f"{worst[3] * 1e3:.0f} ms), every card's picture {median[4] * 1e3:.0f} ms.", "",
             f"**Live update, packet stored to its capture on the page** ({len(lat)} captures of a {poses}-pose "
             "sweep):", "",
             "| median ms | 90th percentile ms | worst ms |", "|---:|---:|---:|",
             f"| {statistics.median(lat):.0f} | {p90:.0f} | {max(lat):.0f} |", "",
             f"**90th percentile {p90:.0f} ms** (bar < {LATENCY_BAR_MS:.0f} ms: {verdict(p90, LATENCY_BAR_MS)}).", ""]
    return Section("Operator page", lines)
