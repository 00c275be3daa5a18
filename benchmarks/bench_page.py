"""The operator's page in a real browser (Debian's chromium, driven by Playwright): page load to
first paint with 500 captures in the database (bar: under 1 s), and live-update latency, from a
packet stored to the page showing it (bar: under 300 ms).

Load: a station serves a database of 500 captures (10 sweeps of 50 poses) with its page; each
round opens the page afresh (the token already traded for the cookie). First paint is the
browser's first-contentful-paint; "data drawn" is when the first pushed state (every pose's
latest capture, the link, the robot, the sweep) is on the page, both from the navigation's start.

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


def load_times(where: Path, captures: int, rounds: int) -> list[tuple[float, float]]:
    """(first paint, data drawn) in seconds, one per round."""
    db = where / "load.db"
    fill(db, captures)
    station = Station(where, db, "--status-every", "0")
    out = []
    try:
        with chromium() as page:
            page.goto(station.url)  # the token for the cookie
            page.wait_for_function("() => window.btfPage && window.btfPage.hello > 0")
            for _ in range(rounds):
                page.goto(station.base)
                page.wait_for_function("() => window.btfPage.hello > 0 && "
                                       "performance.getEntriesByType('paint').length > 0")
                t = page.evaluate("""() => {
                  const fcp = performance.getEntriesByName('first-contentful-paint')[0];
                  const data = performance.getEntriesByName('btf-first-data')[0];
                  return [fcp.startTime, data.startTime, document.querySelectorAll('#cards .card').length];
                }""")
                assert t[2] == min(captures, 50), t  # every pose's latest capture is on the page
                out.append((t[0] / 1e3, t[1] / 1e3))
    finally:
        station.close()
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
    captures, rounds, poses = ctx.pick(500, 50), ctx.pick(7, 2), ctx.pick(30, 4)
    with tempfile.TemporaryDirectory(prefix="bench-page-") as tmp:
        load = load_times(Path(tmp), captures, rounds)
        lat = latencies(Path(tmp), poses)
    paint = statistics.median(t for t, _ in load)
    data = statistics.median(d for _, d in load)
    worst_data = max(d for _, d in load)
    p90 = float(np.percentile(lat, 90))
    lines = [f"Headless chromium{' (--quick: shrunk)' if ctx.quick else ''} on this machine; the station a "
             "separate process, the page served in its event loop.", "",
             f"**Page load with {captures} captures in the database** ({rounds} fresh loads):", "",
             "| from navigation start | median ms | worst ms |", "|---|---:|---:|",
             f"| first contentful paint | {paint * 1e3:.0f} | {max(t for t, _ in load) * 1e3:.0f} |",
             f"| every pose's latest capture, link, robot and sweep drawn | {data * 1e3:.0f} | "
             f"{worst_data * 1e3:.0f} |", "",
             f"**First paint {paint * 1e3:.0f} ms, data drawn {data * 1e3:.0f} ms (worst {worst_data * 1e3:.0f} ms)** "
             f"(bar < {LOAD_BAR_S * 1e3:.0f} ms: {verdict(worst_data, LOAD_BAR_S)}).", "",
             f"**Live update, packet stored to its capture on the page** ({len(lat)} captures of a {poses}-pose "
             "sweep):", "",
             "| median ms | 90th percentile ms | worst ms |", "|---:|---:|---:|",
             f"| {statistics.median(lat):.0f} | {p90:.0f} | {max(lat):.0f} |", "",
             f"**90th percentile {p90:.0f} ms** (bar < {LATENCY_BAR_MS:.0f} ms: {verdict(p90, LATENCY_BAR_MS)}).", ""]
    return Section("Operator page", lines)
