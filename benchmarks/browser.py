"""Debian's chromium, driven from Python with Playwright (never a browser of Playwright's own),
for the operator page's benchmarks and tests; and the page's address a station printed."""
from __future__ import annotations

import re
import shutil
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--no-first-run"]


def available() -> bool:
    return Path(CHROMIUM).is_file() or shutil.which("chromium") is not None


@contextmanager
def chromium(width: int = 1400, height: int = 900) -> Iterator:
    """A new page of a headless chromium."""
    from playwright.sync_api import sync_playwright

    exe = CHROMIUM if Path(CHROMIUM).is_file() else shutil.which("chromium")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=FLAGS)
        try:
            yield browser.new_page(viewport={"width": width, "height": height})
        finally:
            browser.close()


def page_address(stderr: Path, limit_s: float = 60.0) -> str:
    """The `page: URL?token=T` line a station prints on stderr at start-up."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        m = re.search(r"^page: (\S+)$", stderr.read_text(errors="replace") if stderr.exists() else "", re.M)
        if m:
            return m.group(1)
        time.sleep(0.05)
    raise AssertionError(f"no page address on the station's stderr: {stderr.read_text(errors='replace')}")
