"""The operator page's tests drive Debian's chromium (`benchmarks.browser`): skipped where it is
missing, except in CI, where `make browser` installs it and the tests must run."""
from __future__ import annotations

import os

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
