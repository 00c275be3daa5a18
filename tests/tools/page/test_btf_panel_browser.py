"""The page's BTF panel in a real browser (Debian's chromium, driven by Playwright), with a fake
robot and the station on a pty cable: the panel grows point by point as the sweep's captures
are stored, each further capture adds exactly one point, leave one out appears once angles have
neighbours on both sides, and choosing another region and band redraws it."""
import os
import shutil

import pytest

from tests.support.browser import answer_of, chromium, need_chromium, page_address
from tests.support.station_rig import Rig

PLAN = "90,10,80,20,70,30"  # long moves between poses: a capture about every half second

# Every point count the panel's title shows, in order.
WATCH = """() => {
  window.btfCounts = [];
  new MutationObserver(() => {
    const m = /(\\d+) points?$/.exec(document.getElementById("btf-title").textContent);
    const n = m ? Number(m[1]) : 0;
    if (window.btfCounts[window.btfCounts.length - 1] !== n) window.btfCounts.push(n);
  }).observe(document.getElementById("btf-title"), {childList: true, characterData: true, subtree: true});
}"""


@pytest.fixture
def rig(tmp_path):
    need_chromium()
    r = Rig(tmp_path)
    yield r
    r.close()


def points_shown(page, n):
    page.wait_for_function(f"() => document.getElementById('btf-title').textContent.endsWith(' {n} points') && "
                           f"document.querySelectorAll('#btf-plot circle.pt').length === {n}", timeout=60_000)


def capture_at(page, elevation):
    page.fill("form[data-command=GOTO] input[name=elevation]", str(elevation))
    page.click("form[data-command=GOTO] button")
    assert answer_of(page, "GOTO").startswith("ACK")
    page.evaluate("() => { document.querySelector('form[data-command=CAPTURE] output.answer').textContent = ''; }")
    page.click("form[data-command=CAPTURE] button")
    assert answer_of(page, "CAPTURE").startswith("ACK")


def test_the_btf_panel_grows_by_one_point_per_stored_capture_and_redraws_on_a_choice(rig, tmp_path):
    robot = rig.robot()
    station = rig.station("--http", "127.0.0.1:0")
    url = page_address(rig.where / f"station-{rig.stations}.err")
    with chromium() as page:
        page.goto(url)
        page.wait_for_function("() => document.getElementById('link-badge').textContent === 'link up'",
                               timeout=60_000)
        page.wait_for_selector("#btf-loo:has-text('no captures yet')", timeout=60_000)  # the worker answers
        page.evaluate(WATCH)
        page.fill("form[data-command=SWEEP] input[name=elevations]", PLAN)
        page.click("form[data-command=SWEEP] button")
        assert answer_of(page, "SWEEP").startswith("ACK: sweep=")
        points_shown(page, 6)
        counts = page.evaluate("window.btfCounts")
        assert counts == sorted(set(counts)) and counts[-1] == 6 and len(counts) >= 4, counts
        assert page.locator("#btf-plot polyline.curve").count() == 1  # the interpolated curve
        assert "view elevation (°)" in page.locator("#btf-plot").text_content()
        # each further capture at a new angle: exactly one point more, and leave one out
        for n, elevation in ((7, 45), (8, 55)):
            capture_at(page, elevation)
            points_shown(page, n)
            assert page.evaluate("window.btfCounts")[-2:] == [n - 1, n]
        page.wait_for_selector("#btf-loo table td.ok", timeout=30_000)
        loo = page.locator("#btf-loo").text_content()
        # 8 elevations: the 6 between the highest and the lowest are left out in turn
        assert "Interpolation beats the nearest angle at" in loo and " of 6 (mean L1" in loo
        assert page.locator("#btf-loo table td.ok, #btf-loo table td.bad").count() == 6
        # another region and band: the panel redraws for it
        first = page.locator("#btf-title").text_content()
        options = page.locator("#btf-region option")
        assert options.count() >= 2
        choice = options.nth(options.count() - 1)
        page.select_option("#btf-region", choice.get_attribute("value"))
        wanted = choice.text_content().split(", band ")[1]
        page.wait_for_function(f"() => document.getElementById('btf-title').textContent.includes('band {wanted}:')",
                               timeout=30_000)
        assert page.locator("#btf-title").text_content() != first
        points_shown(page, 8)
        page.select_option("#btf-stat", "sd")
        assert "standard deviation (levels)" in page.locator("#btf-plot").text_content()
        page.select_option("#btf-stat", "mean")
        page.locator("#btf-panel").screenshot(path=str(tmp_path / "btf-panel.png"))
        page.screenshot(path=str(tmp_path / "page.png"), full_page=True)
    if os.environ.get("BTF_PANEL_SCREENSHOT"):  # the picture docs and reviews look at
        shutil.copy(tmp_path / "btf-panel.png", os.environ["BTF_PANEL_SCREENSHOT"])
    assert rig.stop(station) == 0 and rig.stop(robot) == 0
