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
