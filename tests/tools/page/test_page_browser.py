"""The operator's page in a real browser (Debian's chromium, driven by Playwright): a fake robot
and the station with its page on a real pty cable. The sweep advances pose by pose on the page;
"capture" is answered inline and its capture appears; the cable cut shows "link down", then the
failsafe; restored, the robot is heard again and reports the failsafe it went through."""
import os
import re
import shutil

import pytest

from tests.support.browser import answer_of, chromium, need_chromium, page_address
from tests.support.robots import IDLE
from tests.support.station_rig import Rig

# The robot holds the arm after 1.5 s without the base (the station calls the link down after 5 s).
QUICK_FAILSAFE = {"link": {"failsafe_s": 1.5}}
PLAN = "90,70,50,30,10"  # 20° apart (a sixth of a second for the fake servos), at azimuths 0 and 90

# What the capture detail said as the page built itself: (cards on the page, its text) at each change.
DETAIL_SEEN = """
window.detailSeen = [];
new MutationObserver(() => {
  const d = document.getElementById("detail");
  if (!d) return;
  const t = d.textContent.trim().slice(0, 60), cards = document.querySelectorAll("#cards .card").length;
  const last = window.detailSeen[window.detailSeen.length - 1];
  if (!last || last[0] !== cards || last[1] !== t) window.detailSeen.push([cards, t]);
}).observe(document, {childList: true, subtree: true, characterData: true});
"""

# Every value the progress text and the link and mode badges take, in order (the page's DOM).
WATCH = """() => {
  window.seen = {progress: [], link: [], mode: []};
  const watch = (id, list) => new MutationObserver(() => {
    const t = document.getElementById(id).textContent;
    if (list[list.length - 1] !== t) list.push(t);
  }).observe(document.getElementById(id), {childList: true, characterData: true, subtree: true});
  watch("progress-text", window.seen.progress);
  watch("link-badge", window.seen.link);
  watch("mode-badge", window.seen.mode);
}"""


@pytest.fixture
def rig(tmp_path):
    need_chromium()
    r = Rig(tmp_path, QUICK_FAILSAFE, IDLE)
    yield r
    r.close()


def test_the_page_follows_a_sweep_commands_the_robot_and_shows_the_link_lost_and_recovered(rig, tmp_path):
    robot = rig.robot()
    station = rig.station("--http", "127.0.0.1:0", "--robot-config", str(rig.where / "robot.toml"))
    url = page_address(rig.where / f"station-{rig.stations}.err")
    with chromium() as page:
        page.goto(url)
        page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link up'",
                               timeout=60_000)
        page.evaluate(WATCH)
        # the sweep, started from its form, advances pose by pose on the grid and the bar
        page.fill("form[data-command=SWEEP] input[name=elevations]", PLAN)
        page.fill("form[data-command=SWEEP] input[name=azimuths]", "0,90")
        page.click("form[data-command=SWEEP] button")
        assert answer_of(page, "SWEEP").startswith("ACK: sweep=")
        page.wait_for_function("() => document.getElementById('progress-text').textContent.includes('10 of 10')",
                               timeout=60_000)
        progress = page.evaluate("window.seen.progress")
        done = [int(t.split(": ")[1].split(" of ")[0]) for t in progress if " of 10" in t]
        assert done == sorted(done) and done[-1] == 10 and len({d for d in done if 0 < d < 10}) >= 5, progress
        assert page.locator("#grid td.cell.d").count() == 10 and page.locator("#grid td.cell.p").count() == 0
        assert page.locator("#cards .card").count() == 10
        # capture: the ACK inline, then its capture on the page, drawn as the report draws it
        page.click("form[data-command=CAPTURE] button")
        ack = answer_of(page, "CAPTURE")
        assert ack.startswith("ACK") and "seq=" in ack, ack
        seq = int(ack.split("seq=")[1].split()[0])
        page.wait_for_selector(f"#cards .card[data-seq='{seq}']", timeout=30_000)
        page.wait_for_selector(f"#detail h3:has-text('(seq {seq})')", timeout=60_000)
        for what in ("measured", "independent pixels", "grain and band correlation", "histograms"):
            page.wait_for_selector(f"#detail figcaption:has-text('{what}')", timeout=60_000)
        assert page.locator("#detail table.models tr").count() > 1
        assert "exposure us" in page.locator("#detail table.camera").text_content()
        # opened again with captures stored: the chosen capture is never "No capture yet.", and
        # every card's picture loads once the chosen capture's have
        page.add_init_script(DETAIL_SEEN)
        page.reload()
        page.wait_for_selector(f"#detail h3:has-text('(seq {seq})')", timeout=60_000)
        page.wait_for_function("() => [...document.querySelectorAll('#cards img')].every("
                               "(i) => i.complete && i.naturalWidth > 0)", timeout=60_000)
        seen = page.evaluate("window.detailSeen")
        assert not [t for cards, t in seen if cards and "No capture yet" in t], seen
        assert "360.0°" not in page.locator("#cards").text_content()
        # a STATUS answer says no empty field ("paused=")
        page.click("form[data-command=STATUS] button")
        said = answer_of(page, "STATUS")
        assert said.startswith("ACK") and not re.search(r"=(\s|,|$)", said), said
        page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link up'")
        page.evaluate(WATCH)
        # the cable cut: link down, and the robot's failsafe
        rig.cable.cut()
        page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link down'",
                               timeout=60_000)
        page.wait_for_function("() => document.getElementById('mode-badge').textContent === 'failsafe'",
                               timeout=30_000)
        page.screenshot(path=str(tmp_path / "link-down.png"))
        # restored: heard again, the robot's own failsafe report, and back to idle
        rig.cable.restore()
        page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link up'",
                               timeout=60_000)
        page.wait_for_selector("#log li:has-text('failsafe: link lost, arm held')", timeout=60_000)
        page.wait_for_function("() => document.getElementById('mode-badge').textContent.startsWith('idle')",
                               timeout=60_000)
        assert page.evaluate("window.seen.link")[-3:] == ["link up", "link down", "link up"]
        modes = page.evaluate("window.seen.mode")
        assert "failsafe" in modes and modes[-1].startswith("idle"), modes
        assert "for" in page.locator("#robot-table").text_content()  # the failsafe's duration, as reported
        # the chosen capture's histograms arrive after its pictures, and are shown at the size drawn
        page.wait_for_function("() => [...document.querySelectorAll('#detail img.hist')].some("
                               "(i) => i.complete && i.naturalWidth > 0)", timeout=60_000)
        shown, drawn, room = page.evaluate("() => { const i = document.querySelector('#detail img.hist'); "
                                           "return [i.width, i.naturalWidth, document.getElementById('detail').clientWidth]; }")
        assert shown >= min(drawn, room - 40), (shown, drawn, room)  # not squeezed below what fits
        page.screenshot(path=str(tmp_path / "page.png"), full_page=True)
    if os.environ.get("BTF_PAGE_SCREENSHOT"):  # the README's picture: docs/page.png
        shutil.copy(tmp_path / "page.png", os.environ["BTF_PAGE_SCREENSHOT"])
    assert rig.stop(station) == 0 and rig.stop(robot) == 0
