"""The in-process `btf-host` the CLI's tests share, and what a refusal must look like."""
from __future__ import annotations

import pytest

from tools.cli import main


@pytest.fixture
def run(capfd):
    """btf-host in this process, stderr caught at the file descriptor (native libraries' lines too)."""
    def call(*argv):
        code = main([str(a) for a in argv])
        out, err = capfd.readouterr()
        return code, out, err
    return call
