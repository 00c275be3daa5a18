"""What a refusal of a command line must look like."""
from __future__ import annotations


def refused(code: int, err: str) -> str:
    """The one line of a refusal: exit status 2, one line naming the command, no traceback, no usage
    block, no line of libpng's or OpenCV's."""
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err and "libpng" not in err and "WARN" not in err and "usage:" not in err
    assert lines[0].startswith("btf-host")
    return lines[0]
