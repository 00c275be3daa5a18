"""The fake camera benchmark's quick path: a frame, the robot's work on it and their ratio."""
from __future__ import annotations

import re

from benchmarks.__main__ import discover, run_one
from benchmarks.common import Context


def test_the_quick_run_times_a_frame_against_the_work_on_it(tmp_path):
    assert "fake_camera" in discover()
    (section,) = run_one("fake_camera", Context(quick=True, out=tmp_path))
    rows = [line for line in section.lines if line.startswith("| tiny")]
    assert len(rows) == 1
    frame, work, ratio, first = (float(v) for v in re.findall(r"(\d+(?:\.\d+)?)(?: ms)? \|", rows[0])[-4:])
    assert frame > 0 and work > 0 and first > 0
    # the ratio of the times the row shows rounded to whole ms
    assert (frame - 0.5) / (work + 0.5) - 0.005 <= ratio <= (frame + 0.5) / (work - 0.5) + 0.005
