"""The operator page's and the report's tests drive Debian's chromium (`benchmarks.browser`): skipped
where it is missing, except in CI, where `make browser` installs it and the tests must run."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from benchmarks.browser import CHROMIUM, available, chromium, page_address  # noqa: F401  (the tests' tools)


def need_chromium() -> None:
    if not available():
        if os.environ.get("CI"):
            pytest.fail(f"{CHROMIUM} is missing in CI: `make browser` installs Debian's chromium")
        pytest.skip("chromium not installed (make browser installs it)")


def answer_of(page, command):
    """The answer a command form shows once the robot answered (ACK or NACK)."""
    out = page.locator(f"form[data-command={command}] output.answer")
    page.wait_for_function(f"() => /^(ACK|NACK)/.test(document.querySelector("
                           f"'form[data-command={command}] output.answer').textContent)", timeout=60_000)
    return out.text_content()


# Where a report puts its summary's parts (viewport pixels), and each plot's drawn and shown widths.
REPORT_LAYOUT = """() => {
  const box = q => document.querySelector(q).getBoundingClientRect();
  const heads = [...document.querySelectorAll('#summary h3')]
    .map(h => [h.textContent, h.getBoundingClientRect().bottom]);
  const plots = [...document.querySelectorAll('img.hist, img.btf')].map(i => [i.naturalWidth, i.clientWidth]);
  return {summary: box('#summary h2').top, bars: box('ul.bars').bottom, heads, plots,
          toc: box('nav.toc').top, capture: box('div.capture').top};
}"""


def report_layout(page: Path, width: int = 1400, height: int = 900) -> dict:
    """`REPORT_LAYOUT` of the report at `page` opened in a headless chromium of that window size."""
    need_chromium()
    with chromium(width, height) as tab:
        tab.goto(page.as_uri())
        tab.wait_for_load_state("load")
        return tab.evaluate(REPORT_LAYOUT)
